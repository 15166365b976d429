"""The online engine: env stepping, replay, vmapped grids vs single runs, determinism, no re-trace, learning."""

from __future__ import annotations

import dataclasses
import functools
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from jax import lax

from proto_brax import envs
from proto_brax.agents.bc import bc_update
from proto_brax.agents.common import adam
from proto_brax.agents.learner import Pretrained
from proto_brax.agents.sac import SACHParams
from proto_brax.config import FinetuneConfig
from proto_brax.data.dataset import Transition
from proto_brax.data.generate import collect, flatten_env_major, uniform_policy
from proto_brax.data.replay import replay_init, replay_insert, replay_sample
from proto_brax.networks import NetworkConfig, make_networks
from proto_brax.train import online
from proto_brax.train.evaluate import run_episode_stats, run_episodes, run_episodes_with_lengths
from proto_brax.train.grid import grid_mesh, make_grid, run_grid

TINY = FinetuneConfig(
    env="point", net=NetworkConfig(hidden=(32, 32)), steps=1200, eval_every=400, eval_episodes=4,
    batch_size=32, learning_starts=64, sampling="online",
)
SCRATCH = dict(alpha0=0.0, alpha_sac_init=1.0, target_entropy_scale=-1.0, lr_actor=1e-3, lr_critic=1e-3)


@functools.lru_cache(maxsize=None)
def finetune_fn(cfg: FinetuneConfig):
    """One compiled single-run program per config, shared by every test."""
    ft = online.make_finetune(cfg)
    return ft, jax.jit(ft.finetune)


def expert_policy(obs, key):
    del key
    return jnp.clip(-obs[:, :2] / 0.2, -1.0, 1.0)


@functools.lru_cache(maxsize=None)
def point_dataset(noise: float = 0.3, num_envs: int = 20, steps: int = 100) -> Transition:
    env = envs.make_env("point")
    pol = lambda obs, key: jnp.clip(expert_policy(obs, key) + noise * jax.random.normal(key, (obs.shape[0], 2)),  # noqa: E731
                                    -1, 1)
    tr, _, _, _ = jax.jit(lambda k: collect(env, 50, pol, k, num_envs, steps))(jax.random.PRNGKey(42))
    return flatten_env_major(tr)


# ----------------------------------------------------------------------------------------------------- env stepping


def test_time_limit_truncation_keeps_true_next_obs_and_bootstraps():
    env = envs.make_env("point")
    s = envs.env_reset(env, jax.random.PRNGKey(0))
    a = jnp.array([0.1, -0.1])
    for i in range(3):
        prev = s
        s, tr, done, ret = envs.env_step(env, 3, s, a, jax.random.PRNGKey(i + 1))
    expected_next = env.step(prev.brax_state, a).obs
    np.testing.assert_allclose(tr.next_observations, expected_next)  # the true successor, not the reset obs
    assert float(tr.timeouts) == 1.0 and float(tr.terminals) == 0.0  # bootstrapping continues through a timeout
    assert float(done) == 1.0 and int(s.t) == 0 and float(s.episode_return) == 0.0
    assert not np.allclose(s.brax_state.obs, expected_next)  # auto-reset to a fresh initial state


def test_true_termination_sets_terminal():
    env = envs.make_env("point")
    s = envs.env_reset(env, jax.random.PRNGKey(0))
    for i in range(30):
        s, tr, done, _ = envs.env_step(env, 1000, s, jnp.ones(2), jax.random.PRNGKey(i))
        if float(done):
            break
    assert float(tr.terminals) == 1.0 and float(tr.timeouts) == 0.0


def test_point_references():
    """The registered reference returns of the point task are what the two reference policies score."""
    env = envs.make_env("point")
    spec = envs.get_spec("point")
    for pol, ref in ((uniform_policy(2), spec.ref_random), (expert_policy, spec.ref_expert)):
        ret = jax.jit(lambda k, pol=pol: run_episodes(env, 50, pol, k, 100))(jax.random.PRNGKey(123))
        assert abs(float(ret.mean()) - ref) < 0.05
    np.testing.assert_allclose(envs.normalized_score("point", [spec.ref_random, spec.ref_expert]), [0.0, 100.0])


def test_episode_lengths_count_steps_to_termination():
    """Pushing right ends each point episode when |x| > 1.9; its length and return follow from the start by hand.
    Standing still runs to the horizon."""
    env = envs.make_env("point")
    key = jax.random.PRNGKey(5)
    fn = jax.jit(lambda k, pol: run_episodes_with_lengths(env, 30, pol, k, 6), static_argnums=1)
    push = lambda obs, k: jnp.ones((obs.shape[0], 2))  # noqa: E731
    ret, length = fn(key, push)
    starts = jax.vmap(env.reset)(jax.random.split(jax.random.split(key)[0], 6)).pipeline_state
    for x0, r, n in zip(np.asarray(starts), np.asarray(ret), np.asarray(length)):
        x, steps, total = x0.astype(np.float32), 0, 0.0
        while True:  # the env's float32 arithmetic, step by step
            x = x + np.float32(0.2) * np.float32(1.0)
            steps, total = steps + 1, total + 1.0 - float(np.linalg.norm(x))
            if np.max(np.abs(x)) > 1.9:
                break
        assert n == steps and 5 <= n <= 15
        np.testing.assert_allclose(r, total, rtol=1e-5)
    still = lambda obs, k: jnp.zeros((obs.shape[0], 2))  # noqa: E731
    np.testing.assert_array_equal(fn(key, still)[1], 30)


def test_success_steps_count_the_alive_steps_flagged_success():
    """A point env flagging success within 0.5 of the origin: pushing right, the count follows from the start by
    hand (steps up to and including the terminating one); standing still counts every step or none. Without a
    success metric (the plain point env) the count is 0."""

    class PointNearOrigin(envs.PointReach):  # reset and step carry the metric, as Brax envs' metrics must
        def reset(self, rng):
            return self._flag(super().reset(rng))

        def step(self, state, action):
            return self._flag(super().step(state, action))

        @staticmethod
        def _flag(s):
            return s.replace(metrics={"success": (jnp.linalg.norm(s.pipeline_state) < 0.5).astype(jnp.float32)})

    env = PointNearOrigin()
    key = jax.random.PRNGKey(7)
    fn = jax.jit(lambda k, pol, e: run_episode_stats(e, 30, pol, k, 16), static_argnums=(1, 2))
    push = lambda obs, k: jnp.ones((obs.shape[0], 2))  # noqa: E731
    still = lambda obs, k: jnp.zeros((obs.shape[0], 2))  # noqa: E731
    starts = np.asarray(jax.vmap(env.reset)(jax.random.split(jax.random.split(key)[0], 16)).pipeline_state)
    pushed = np.asarray(fn(key, push, env).success_steps)
    for x0, n in zip(starts, pushed):
        x, wins = x0.astype(np.float32), 0
        while True:
            x = x + np.float32(0.2) * np.float32(1.0)
            wins += int(np.linalg.norm(x) < 0.5)
            if np.max(np.abs(x)) > 1.9:
                break
        assert n == wins
    assert pushed.max() > 0  # some start passes near the origin: the check above is not all zeros
    near = np.linalg.norm(starts, axis=1) < 0.5
    assert 0 < near.sum() < 16
    np.testing.assert_array_equal(fn(key, still, env).success_steps, np.where(near, 30, 0))
    np.testing.assert_array_equal(fn(key, still, envs.PointReach()).success_steps, 0)


def test_goal_task_episode_stats():
    from proto_brax.experiment.summary import episode_stats

    stats = episode_stats("antmaze-umaze", [1.0, 0.0, 1.0], [100, 700, 300])
    assert stats == pytest.approx({"eval_length": 1100 / 3, "success_rate": 2 / 3, "steps_to_goal": 200.0})
    assert np.isnan(episode_stats("antmaze-umaze", [0.0, 0.0], [700, 700])["steps_to_goal"])
    assert episode_stats("hopper", [10.0, 20.0], [50, 150], [0, 0]) == {"eval_length": 100.0}
    # Adroit (D4RL's rule): pen succeeds on more than 20 goal-achieved steps, hammer on more than 25.
    assert episode_stats("pen", [1.0] * 3, [100] * 3, [20, 21, 100])["success_rate"] == pytest.approx(2 / 3)
    assert episode_stats("hammer", [1.0] * 2, [200] * 2, [25, 26])["success_rate"] == 0.5


# ----------------------------------------------------------------------------------------------------------- replay


def _rows(n, value, obs=2, act=1):
    return Transition(
        observations=jnp.full((n, obs), value), actions=jnp.zeros((n, act)), rewards=jnp.full((n,), value),
        next_observations=jnp.zeros((n, obs)), terminals=jnp.zeros(n), timeouts=jnp.zeros(n),
    )


def test_replay_insert_wraps_around():
    buf = replay_init(5, 2, 1)
    buf = replay_insert(buf, _rows(3, 1.0))
    buf = replay_insert(buf, _rows(4, 2.0))
    assert int(buf.size) == 5 and int(buf.position) == 2
    np.testing.assert_array_equal(buf.data.rewards, [2, 2, 1, 2, 2])


def test_symmetric_sampling_takes_exact_offline_share():
    buf = replay_insert(replay_init(10, 2, 1), _rows(4, 0.0))
    data = _rows(50, 1.0)
    batch = replay_sample(jax.random.PRNGKey(0), buf, data, 16, "symmetric", 0.25)
    np.testing.assert_array_equal(batch.rewards, [1.0] * 4 + [0.0] * 12)


def test_union_sampling_is_uniform_over_both_sources():
    buf = replay_insert(replay_init(100, 2, 1), _rows(30, 0.0))
    data = _rows(90, 1.0)
    batch = replay_sample(jax.random.PRNGKey(0), buf, data, 20_000, "union")
    share = float(batch.rewards.mean())  # expected 90 / 120 = 0.75; binomial std ≈ 0.003
    assert abs(share - 0.75) < 0.015
    online_only = replay_sample(jax.random.PRNGKey(1), buf, data, 1000, "online")
    assert float(online_only.rewards.max()) == 0.0  # never reads the dataset nor the empty rows


# ---------------------------------------------------------------------------------------------------- grids and runs


def test_vmapped_grid_run_equals_single_run():
    """Run i of a sharded, vmapped grid equals the same run alone.

    Tolerance: 1e-4 on every metric of the first chunk (400 steps); batched and unbatched matmuls round differently
    and RL amplifies such differences over time, so later evaluations are held to 2% (measured drift: ~0.5%).
    """
    ft, single = finetune_fn(TINY)
    grid = make_grid({"tau": [0.0, 0.01], "lr_actor": [1e-3]}, seeds=[0, 1], base={**SCRATCH, "alpha0": 0.5},
                     hparams=SACHParams)
    state, metrics = run_grid(ft, grid)
    assert metrics["eval_return"].shape == (TINY.num_chunks, 4)
    for i in (0, 3):
        point = grid.points[i]
        hp = SACHParams.create(**{k: v for k, v in point.items() if k != "seed"})
        _, m = single(hp, jax.random.PRNGKey(point["seed"]), None, None)
        for k in ("eval_return", "critic_loss", "actor_loss", "dev_pi0", "q_mean"):
            np.testing.assert_allclose(metrics[k][0, i], np.asarray(m[k])[0], rtol=1e-4, atol=1e-4, err_msg=k)
        np.testing.assert_allclose(metrics["eval_return"][:, i], np.asarray(m["eval_return"]), rtol=2e-2, atol=0.2)


def test_a_grid_of_one_run_per_device_runs_the_unbatched_program_bit_for_bit():
    """A device's block of one run is not vmapped (``grid.run_batched``: a batch-of-one vmap runs the LayerNorm
    critics at half speed on XLA:CPU): a one-run grid gives exactly the numbers of the same run's jitted chunks, where
    a batch-of-one vmap rounds differently."""
    cfg = dataclasses.replace(TINY, net=dataclasses.replace(TINY.net, critic_layer_norm=True))
    ft = online.make_finetune(cfg)
    grid = make_grid({"tau": [0.01]}, seeds=[5], base={**SCRATCH, "alpha0": 0.5},
                     hparams=SACHParams)
    _, metrics = run_grid(ft, grid)
    hp = SACHParams.create(**{k: v for k, v in grid.points[0].items() if k != "seed"})
    state = jax.jit(ft.init)(hp, jax.random.PRNGKey(5), None, None)
    chunk = jax.jit(ft.chunk)
    for c in range(cfg.num_chunks):
        state, m = chunk(state, hp, None, jnp.asarray(c * cfg.eval_every, jnp.int32))
        for k in ("eval_return", "critic_loss", "actor_loss", "q_mean", "dev_pibar"):
            np.testing.assert_array_equal(metrics[k][c, 0], np.asarray(m[k]), err_msg=f"chunk {c} {k}")


def test_a_mapped_block_runs_each_run_through_the_unbatched_program_bit_for_bit():
    """``--block map`` (``grid.run_batched`` with ``lax.map``): a device's three runs with three distinct points go
    one after another through the single-run program, each giving exactly its own single run's numbers; the same
    grid vmapped agrees only to rounding."""
    cfg = dataclasses.replace(TINY, net=dataclasses.replace(TINY.net, critic_layer_norm=True))
    ft = online.make_finetune(cfg)
    grid = make_grid({"tau": [0.0, 0.01, 0.05]}, seeds=[7], base={**SCRATCH, "alpha0": 0.5}, hparams=SACHParams)
    _, mapped = run_grid(ft, grid, mesh=grid_mesh(jax.devices()[:1]), block="map")
    _, vmapped = run_grid(ft, grid, mesh=grid_mesh(jax.devices()[:1]))
    chunk = jax.jit(ft.chunk)
    for i, point in enumerate(grid.points):
        hp = SACHParams.create(**{k: v for k, v in point.items() if k != "seed"})
        state = jax.jit(ft.init)(hp, jax.random.PRNGKey(point["seed"]), None, None)
        for c in range(cfg.num_chunks):
            state, m = chunk(state, hp, None, jnp.asarray(c * cfg.eval_every, jnp.int32))
            for k in ("eval_return", "critic_loss", "actor_loss", "q_mean", "dev_pibar"):
                np.testing.assert_array_equal(mapped[k][c, i], np.asarray(m[k]), err_msg=f"run {i} chunk {c} {k}")
    assert len({float(x) for x in mapped["critic_loss"][-1]}) == 3  # three distinct runs, not one run thrice
    np.testing.assert_allclose(vmapped["critic_loss"][0], mapped["critic_loss"][0], rtol=1e-4)
    with pytest.raises(ValueError, match="block 'pmap'"):
        run_grid(ft, grid, block="pmap")


def test_same_seed_same_result_and_no_retrace():
    ft, single = finetune_fn(TINY)
    hp = SACHParams.create(**SCRATCH)
    chunk = jax.jit(ft.chunk)
    before = online.TRACE_COUNT["chunk"]
    results = []
    for _ in range(2):
        state = ft.init(hp, jax.random.PRNGKey(3), None, None)
        for c in range(TINY.num_chunks):
            state, m = chunk(state, hp, None, jnp.asarray(c * TINY.eval_every, jnp.int32))
        results.append(jax.device_get((state.learner.actor, m)))
    assert online.TRACE_COUNT["chunk"] - before == 1  # 3 chunk calls, one trace
    jax.tree.map(np.testing.assert_array_equal, results[0], results[1])
    other = jax.device_get(single(hp, jax.random.PRNGKey(4), None, None)[1]["eval_return"])
    assert not np.array_equal(other, np.asarray(jax.device_get(single(hp, jax.random.PRNGKey(3), None, None)[1][
        "eval_return"])))


def test_frozen_keeps_pibar_equal_to_pi0_bit_exactly():
    cfg = dataclasses.replace(TINY, sampling="symmetric")
    ft, single = finetune_fn(cfg)
    hp = SACHParams.create(**{**SCRATCH, "tau": 0.0, "alpha0": 1.0})
    state, _ = single(hp, jax.random.PRNGKey(0), None, point_dataset())
    jax.tree.map(np.testing.assert_array_equal, state.learner.pibar, state.learner.pi0)
    assert not np.array_equal(*jax.tree.leaves((state.learner.actor, state.learner.pi0))[:2])  # the actor moved


def test_td3_grid_runs_and_is_finite():
    cfg = dataclasses.replace(TINY, algo="td3", steps=400)
    ft, _ = finetune_fn(cfg)
    grid = make_grid({"alpha0": [0.0, 1.0]}, seeds=[0], base={"lr_actor": 1e-3, "lr_critic": 1e-3},
                     hparams=ft.hparams)
    _, metrics = run_grid(ft, grid)
    assert np.all(np.isfinite(metrics["critic_loss"])) and np.all(np.isfinite(metrics["eval_return"]))


# -------------------------------------------------------------------------------------------------------- learning


def test_sac_from_scratch_learns_point():
    """SAC (α₀ = 0, random init) goes from the random policy's score (≈ 0 normalized) to ≥ 80 normalized."""
    ft, single = finetune_fn(TINY)
    _, m = single(SACHParams.create(**SCRATCH), jax.random.PRNGKey(0), None, None)
    score = np.asarray(envs.normalized_score("point", m["eval_return"]))
    assert score[-1] >= 80.0, score


def bc_pretrain(dataset: Transition, hidden=(32, 32), steps=1500, seed=0):
    nets = make_networks(NetworkConfig(hidden=hidden), 2)
    actor = nets.actor.init(jax.random.PRNGKey(seed), jnp.zeros((1, 4)))
    opt = adam(1e-3).init(actor)

    def body(carry, key):
        actor, opt = carry
        idx = jax.random.randint(key, (64,), 0, dataset.rewards.shape[0])
        actor, opt, info = bc_update(actor, opt, nets, jax.tree.map(lambda x: x[idx], dataset))
        return (actor, opt), info["bc_loss"]

    (actor, _), losses = jax.lax.scan(body, (actor, opt), jax.random.split(jax.random.PRNGKey(seed), steps))
    return actor, losses


def test_proto_from_bc_pretrained_policy_starts_high_and_stays_high():
    """BC on noisy expert data gives a good π₀; PROTO finetuning from it stays ≥ 80 normalized from the first eval."""
    data = point_dataset()
    actor, losses = jax.jit(bc_pretrain)(data)
    losses = np.asarray(losses)
    assert losses[-100:].mean() < losses[:100].mean() - 1.0  # BC learned
    cfg = dataclasses.replace(TINY, sampling="symmetric")
    ft, single = finetune_fn(cfg)
    pre = Pretrained(actor=actor)
    hp = SACHParams.create(**{**SCRATCH, "alpha0": 1.0, "alpha_sac_init": 0.01, "target_entropy_scale": -0.5})
    learner0 = ft.init(hp, jax.random.PRNGKey(0), pre, data).learner
    pi0_return = float(jnp.mean(jax.jit(ft.evaluate)(learner0, jax.random.PRNGKey(9))[0]))
    assert envs.normalized_score("point", pi0_return) >= 80.0
    _, m = single(hp, jax.random.PRNGKey(0), pre, data)
    score = np.asarray(envs.normalized_score("point", m["eval_return"]))
    assert score.min() >= 80.0, score


# ------------------------------------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(env="hoppr"), "Unknown env 'hoppr'"),
        (dict(backend="warp"), "Unknown backend 'warp'"),
        (dict(steps=0), "steps must be >= 1"),
        (dict(steps=1000, eval_every=300), "multiple of eval_every"),
        (dict(algo="ppo"), "Unknown algo"),
    ],
)
def test_bad_config_fails_with_a_clear_message(kwargs, match):
    with pytest.raises(ValueError, match=match):
        FinetuneConfig(**kwargs)


@pytest.mark.parametrize(
    "axes, seeds, match",
    [
        ({"tau": [1.5]}, [0], "tau must lie in"),
        ({"tau": [-0.1]}, [0], "tau must lie in"),
        ({"eta": [-1.0]}, [0], "eta must be >= 0"),
        ({"alpha0": [-2.0]}, [0], "alpha0 must be >= 0"),
        ({"tau": []}, [0], "grid is empty"),
        ({"tau": [0.1]}, [], "grid is empty"),
        ({"tau": [0.1, 0.1]}, [0], "Duplicate values"),
        ({"taus": [0.1]}, [0], "Unknown hyper-parameter"),
    ],
)
def test_bad_grid_fails_before_compiling(axes, seeds, match):
    with pytest.raises(ValueError, match=match):
        make_grid(axes, seeds)


def test_dataset_of_wrong_env_is_rejected():
    ft, _ = finetune_fn(TINY)
    bad = _rows(10, 0.0, obs=11, act=3)
    with pytest.raises(ValueError, match="observations have size 11"):
        ft.init(SACHParams.create(), jax.random.PRNGKey(0), None, bad)


def test_optax_injected_learning_rate_is_traced():
    """Learning rates live in the optimizer state, so two grid points with different rates share one program."""
    st = adam(jnp.asarray(0.5)).init({"w": jnp.ones(2)})
    assert float(st.hyperparams["learning_rate"]) == 0.5
    upd, _ = adam(0.0).update({"w": jnp.ones(2)}, st, {"w": jnp.ones(2)})
    np.testing.assert_allclose(optax.apply_updates({"w": jnp.ones(2)}, upd)["w"], 0.5, atol=1e-3)


def test_regularizer_off_equals_alpha0_zero():
    """The static switch that skips π̄ work changes cost, not results: it equals α₀ = 0 with the term on."""
    ft_on, on = finetune_fn(TINY)
    ft_off, off = finetune_fn(dataclasses.replace(TINY, regularizer=False))
    hp = SACHParams.create(**SCRATCH)
    s_on, m_on = on(hp, jax.random.PRNGKey(5), None, None)
    s_off, m_off = off(hp, jax.random.PRNGKey(5), None, None)
    # The two programs fuse differently, so float round-off differs and training amplifies it: elementwise equality
    # held on earlier installs but not on 2026-12-01's fresh venv (single weights apart by up to 0.08). Compare each
    # weight matrix's relative distance instead; a skipped or extra loss term moves whole layers, not single weights.
    def close(a, b):
        assert np.linalg.norm(np.asarray(a) - np.asarray(b)) <= 0.1 * np.linalg.norm(np.asarray(b)) + 1e-6

    jax.tree.map(close, s_on.learner.actor, s_off.learner.actor)
    np.testing.assert_allclose(m_on["eval_return"], m_off["eval_return"], rtol=0.1)


def test_online_rewards_enter_the_buffer_transformed_and_returns_stay_raw():
    """reward_scale · r + reward_shift in the buffer (the offline data's units); reported returns are raw.
    No updates (learning_starts > steps), so both runs collect the same trajectories."""
    base = dataclasses.replace(TINY, steps=100, eval_every=100, eval_episodes=1, learning_starts=10_000)
    hp = SACHParams.create(**SCRATCH)
    runs = []
    for cfg in (base, dataclasses.replace(base, reward_scale=3.0, reward_shift=-1.0)):
        ft = online.make_finetune(cfg)
        state = ft.init(hp, jax.random.PRNGKey(0), None, None)
        state, m = jax.jit(ft.chunk)(state, hp, None, jnp.asarray(0, jnp.int32))
        runs.append((np.asarray(state.buffer.data.rewards[:100]), m))
    (raw, m1), (scaled, m3) = runs
    assert np.ptp(raw) > 0.1
    np.testing.assert_allclose(scaled, 3.0 * raw - 1.0, rtol=1e-6, atol=1e-6)
    for k in ("train_return", "eval_return"):
        np.testing.assert_allclose(np.asarray(m3[k]), np.asarray(m1[k]), rtol=1e-6, err_msg=k)


def _full_horizon_stats(env, horizon, policy, key, episodes):
    """The evaluation as a scan over the whole horizon (the code before the early exit): the reference."""
    k_reset, k_run = jax.random.split(key)
    s = jax.vmap(env.reset)(jax.random.split(k_reset, episodes))

    def body(carry, k):
        s, ret, alive, length = carry
        s = jax.vmap(env.step)(s, policy(s.obs, k))
        ret = ret + jnp.where(alive, s.reward, 0.0)
        return (s, ret, jnp.logical_and(alive, s.done == 0), length + alive.astype(jnp.int32)), None

    init = (s, jnp.zeros(episodes), jnp.ones(episodes, bool), jnp.zeros(episodes, jnp.int32))
    (_, ret, _, length), _ = lax.scan(body, init, jax.random.split(k_run, horizon))
    return ret, length


def test_one_at_a_time_evaluation_runs_the_side_by_side_episodes():
    """``one_at_a_time`` (the MJX hands' evaluation) runs the same episodes as side by side: the same starts and, for
    a deterministic policy, the same returns, lengths and success counts, alone and under a grid's vmap; each episode
    stops at its own end. A noisy policy sees the same step keys but batch-of-one noise: other returns, same starts."""
    env = envs.make_env("point")
    toward = lambda obs, k: jnp.clip(0.7 - 2.0 * obs[:, :2] + 0.3 * obs[:, 2:], -1.0, 1.0)  # noqa: E731
    away = lambda obs, k: jnp.clip(1.5 * obs[:, :2] + 0.2, -1.0, 1.0)  # noqa: E731  (leaves the box: terminals)
    noisy = lambda obs, k: jax.random.normal(k, obs[:, :2].shape)  # noqa: E731
    keys = jax.random.split(jax.random.PRNGKey(5), 3)
    for pol in (toward, away):
        both = [jax.jit(lambda k, m=m, pol=pol: run_episode_stats(env, 40, pol, k, 7, one_at_a_time=m))
                for m in (False, True)]
        for k in keys:
            side, one = both[0](k), both[1](k)
            np.testing.assert_allclose(one.returns, side.returns, rtol=1e-6, atol=1e-6)
            np.testing.assert_array_equal(one.lengths, side.lengths)
            np.testing.assert_array_equal(one.success_steps, side.success_steps)
        grid = jax.jit(jax.vmap(lambda k, pol=pol: run_episode_stats(env, 40, pol, k, 7, one_at_a_time=True)))(keys)
        np.testing.assert_allclose(grid.returns, np.stack([both[0](k).returns for k in keys]), rtol=1e-6, atol=1e-6)
    lengths = jax.jit(lambda k: run_episode_stats(env, 40, away, k, 7, one_at_a_time=True).lengths)(keys[0])
    assert 1 <= int(lengths.min()) < int(lengths.max()) < 40  # episodes end at their own steps, early
    first = lambda obs, k: obs[:, :2] * 0.0  # noqa: E731  (stands still: the return is 40 rewards of the start)
    a, b = (run_episode_stats(env, 40, first, keys[1], 7, one_at_a_time=m).returns for m in (False, True))
    np.testing.assert_allclose(a, b, rtol=1e-6)  # the same starts
    n1, n2 = (run_episode_stats(env, 40, noisy, keys[1], 7, one_at_a_time=m).returns for m in (False, True))
    assert not np.allclose(n1, n2)
    assert [n for n, s in envs.REGISTRY.items() if s.eval_one_at_a_time] == ["pen", "door", "hammer"]


def test_evaluation_stops_when_every_episode_has_ended_with_the_full_horizons_result():
    """Episodes that all end early cost their own steps, not the horizon's (counted by a host callback in the
    policy), and the returns and lengths equal a full-horizon scan's bit for bit, alone and under a grid's vmap
    (where the loop runs to the grid's longest episode)."""
    env = envs.make_env("point")
    calls = []

    def noisy_push(obs, k):  # pushes right with per-step noise (the step keys matter), counting its calls
        jax.debug.callback(lambda: calls.append(1))
        return jnp.clip(0.6 + 0.5 * jax.random.normal(k, (obs.shape[0], 2)), -1.0, 1.0)

    horizon = 500
    fn = jax.jit(lambda k: run_episode_stats(env, horizon, noisy_push, k, 8))
    keys = jax.random.split(jax.random.PRNGKey(11), 3)
    stats = jax.block_until_ready(fn(keys[0]))
    assert 0 < int(stats.lengths.max()) < horizon  # every episode ended early
    assert len(calls) == int(stats.lengths.max())  # ... and the loop ran that many steps, not the horizon
    ref = jax.jit(lambda k: _full_horizon_stats(env, horizon, noisy_push, k, 8))
    for k in keys:
        got, want = fn(k), ref(k)
        np.testing.assert_array_equal(got.returns, want[0])
        np.testing.assert_array_equal(got.lengths, want[1])
    grid = jax.jit(jax.vmap(lambda k: run_episode_stats(env, horizon, noisy_push, k, 8)))(keys)
    for i, k in enumerate(keys):
        np.testing.assert_array_equal(grid.returns[i], ref(k)[0])
        np.testing.assert_array_equal(grid.lengths[i], ref(k)[1])


# A sharded batched Cholesky, as MJX's hands factor their 30-dof matrices in a multi-seed sweep: 64 matrices per device
# is worth ~6·10⁵ flops, over jaxlib's ~2·10⁵ threshold for splitting the batch onto XLA's CPU pool.
_POOL_PROGRAM = """
import collections, os, sys
from proto_brax.train.grid import use_host_devices
n_dev = use_host_devices(int(sys.argv[1]), spare_worker=True)
import jax, jax.numpy as jnp
from jax.sharding import NamedSharding, PartitionSpec as P
def f(x):
    def body(c, _):
        a = c @ jnp.swapaxes(c, -1, -2) + 30 * jnp.eye(30)
        return c * 0.999 + 1e-3 * jnp.linalg.cholesky(a), None
    return jax.lax.scan(body, x, None, length=100)[0]
x = jax.random.normal(jax.random.key(0), (64 * n_dev, 30, 30)) * 0.1
x = jax.device_put(x, NamedSharding(jax.make_mesh((n_dev,), ("d",)), P("d")))
g = jax.jit(f)
for _ in range(5):
    x = g(x)
assert bool(jnp.isfinite(x).all())
names = collections.Counter(open(f"/proc/self/task/{t}/comm").read().strip() for t in os.listdir("/proc/self/task"))
print(n_dev, names["tf_XLAEigen"])
"""


@pytest.mark.parametrize("devices, pool", [(1, 1), (2, 3)])
def test_batched_lapack_kernels_finish_on_the_host_devices_the_sweep_uses(devices, pool):
    """Regression for the Adroit sweep's deadlock: jaxlib's batched Cholesky, run on an XLA pool worker, splits its
    batch onto the same pool and waits; with two devices and XLA's default pool (one worker per device, both blocked
    so) this program hung in 3 runs of 3 before ``use_host_devices`` sized the pool (``grid.cpu_pool_threads``)."""
    env = {k: v for k, v in os.environ.items() if k not in ("NPROC", "XLA_FLAGS")}
    try:
        out = subprocess.run([sys.executable, "-c", _POOL_PROGRAM, str(devices)], env=env, capture_output=True,
                             text=True, timeout=120)
    except subprocess.TimeoutExpired:
        pytest.fail(f"a batched Cholesky on {devices} host device(s) hung (jaxlib's ParallelBatchMap deadlock)")
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.splitlines()[-1].split() == [str(devices), str(pool)]  # devices, XLA pool workers


def test_pretraining_on_mjx_gets_a_one_thread_pool():
    """``python -m proto_brax.pretrain`` evaluates batched MJX episodes on one device: it asks for one pool thread
    (``cpu_pool_threads(1)``) exactly when the bundle's env steps on MJX, known before JAX starts."""
    from proto_brax.cli.pretrain import _runs_mjx
    from proto_brax.experiment.pretrain import PretrainArgs

    cases = {("pen-human", None): True, ("hopper-v5-medium", None): True, ("antmaze-umaze-diverse", None): True,
             ("hopper-medium", None): False, ("/data/x.npz", None): False, ("/data/x.npz", "door"): True,
             ("/data/x.npz", "walker2d"): False}
    assert {k: _runs_mjx(PretrainArgs(dataset=k[0], env=k[1])) for k in cases} == cases


def test_pretraining_reads_the_env_a_dataset_file_names_for_the_pool(tmp_path, monkeypatch):
    """A dataset given as a file names its env inside: an .npz's metadata entry and an exported Minari dataset's
    metadata.json are read (without their rows, before JAX starts), so pretraining on a pen .npz or a door Minari
    export also gets the one-thread pool; a Brax env's file and an unreadable file do not."""
    from proto_brax.cli.pretrain import _runs_mjx
    from proto_brax.data import minari_io
    from proto_brax.data.dataset import Transition, save_npz
    from proto_brax.experiment.pretrain import PretrainArgs

    rng = np.random.default_rng(0)
    n = 6
    obs = rng.normal(size=(n, 3)).astype(np.float32)
    data = Transition(observations=obs, actions=rng.uniform(-1, 1, (n, 2)).astype(np.float32),
                      rewards=rng.normal(size=n).astype(np.float32), next_observations=obs + 1.0,
                      terminals=np.zeros(n, np.float32), timeouts=np.ones(n, np.float32))
    save_npz(tmp_path / "pen.npz", data, {"env": "pen"})
    save_npz(tmp_path / "hop.npz", data, {"env": "hopper"})
    (tmp_path / "garbled.npz").write_bytes(b"not a zip")
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    door = minari_io.export_minari(data, {}, "toy/door-v0", env="door")
    walker = minari_io.export_minari(data, {}, "toy/walker-v0", env="walker2d")
    cases = {str(tmp_path / "pen.npz"): True, str(tmp_path / "hop.npz"): False, str(tmp_path / "garbled.npz"): False,
             str(door): True, str(door / "data"): True, "toy/door-v0": True, str(walker): False, "toy/none-v0": False}
    assert {d: _runs_mjx(PretrainArgs(dataset=d)) for d in cases} == cases


@pytest.mark.parametrize("argv, nproc", [("--env pen --dataset pen-human --devices 2", "3"),
                                         ("--env pen --dataset pen-human --devices 1", "1"),
                                         ("--devices 2", "None")])
def test_the_sweep_sizes_the_pool_for_its_env_and_devices(argv, nproc):
    """``python -m proto_brax.sweep`` wires ``cpu_pool_threads`` before JAX starts: MJX on two devices gets a spare
    worker, one device one thread, Brax (the default hopper) XLA's default (no $NPROC). The sweep itself is replaced
    by a print of $NPROC."""
    program = ("import os, sys\nimport proto_brax.cli.sweep as s\n"
               "s.run_sweep = lambda a: print('NPROC', os.environ.get('NPROC'))\ns.main(sys.argv[1:])\n")
    env = {k: v for k, v in os.environ.items() if k != "NPROC"}
    out = subprocess.run([sys.executable, "-c", program, *argv.split()], env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.splitlines()[-1] == f"NPROC {nproc}"
