"""Baselines: AWAC and PEX losses against NumPy, PEX's Boltzmann choice (statistical), learner initialization from
bundles, each method learning the point task, and the sweep's method registry and errors."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference as ref
from helpers import perturb, random_batch

from proto_brax import envs, sweep
from proto_brax.agents import awac, iql, pex
from proto_brax.agents import registry as methods
from proto_brax.agents.learner import Pretrained, init_learner
from proto_brax.agents.registry import agent
from proto_brax.config import FinetuneConfig, HParams
from proto_brax.data.dataset import Transition
from proto_brax.experiment.args import grid_axes
from proto_brax.experiment.plan import REPO_ROOT, finetune_config, load_checkpoint, resolve_checkpoint
from proto_brax.networks import NetworkConfig, make_networks
from proto_brax.train.online import make_finetune

OBS, ACT, B = 4, 2, 6
NET = NetworkConfig(hidden=(8, 8))
NETS = make_networks(NET, ACT)
HP_VALUES = dict(gamma=0.9, awac_lambda=0.7, awr_temperature=2.0, expectile=0.8, pex_inv_temperature=3.0)


def hp_for(algo: str, **values) -> HParams:
    """HP_VALUES (and ``values``) in the agent's own HParams class, each field it has."""
    cls = agent(algo).hparams
    return cls.create(**{k: v for k, v in {**HP_VALUES, **values}.items() if k in cls.names()})


def _batch(seed=0):
    return random_batch(OBS, ACT, seed)


def _learner(algo: str, pretrained=None, seed=1):
    lrn = init_learner(jax.random.PRNGKey(seed), NETS, agent(algo), hp_for(algo), OBS, ACT, pretrained)
    # Distinct, non-trivial parameters for every network (targets and π₀ differ from the online ones).
    fields = {f: getattr(lrn, f) for f in ("actor", "critic", "critic_target", "pi0", "value")
              if getattr(lrn, f) is not None}
    return lrn.replace(**{f: perturb(v, jax.random.PRNGKey(10 + i)) for i, (f, v) in enumerate(fields.items())})


CFG = FinetuneConfig(env="point", net=NET, algo="awac")


# ------------------------------------------------------------------------------------------------------------ AWAC


def test_awac_critic_loss_matches_numpy():
    lrn, batch, key = _learner("awac"), _batch(), jax.random.PRNGKey(3)
    loss, _ = awac.critic_loss(lrn.critic, lrn, batch, key, hp_for("awac"), NETS, CFG)
    eps = np.asarray(jax.random.normal(key, (B, ACT)), np.float64)
    expected = ref.awac_critic_loss(lrn.actor, lrn.critic, lrn.critic_target, batch, eps, 0.9)
    np.testing.assert_allclose(loss, expected, rtol=2e-5)


def test_awac_actor_loss_matches_numpy():
    """The update's actor loss: advantage-weighted likelihood with weights from the *updated* critic."""
    lrn, batch, key = _learner("awac"), _batch(1), jax.random.PRNGKey(4)
    new, info = awac.update(lrn, batch, key, jnp.zeros(()), hp_for("awac"), NETS, CFG, jnp.zeros((), jnp.int32))
    _, k_adv = jax.random.split(key)
    eps = np.asarray(jax.random.normal(k_adv, (B, ACT)), np.float64)
    expected = ref.awac_actor_loss(lrn.actor, new.critic, batch, eps, 0.7, 100.0)
    np.testing.assert_allclose(info["actor_loss"], expected, rtol=2e-5)
    # Weights are clipped: a tiny λ saturates every positive advantage at w_max.
    tiny = hp_for("awac").replace(awac_lambda=jnp.float32(1e-6))
    w = awac.advantage_weights(new.critic, lrn.actor, batch, k_adv, tiny, NETS, CFG)
    assert float(jnp.max(w)) == 100.0


# ------------------------------------------------------------------------------------------------------------- PEX


def test_pex_init_keeps_pi0_frozen_and_trains_a_fresh_policy():
    base = _learner("iql")
    pre = Pretrained(actor=base.actor, critic=base.critic, value=base.value)
    lrn = init_learner(jax.random.PRNGKey(0), NETS, agent("pex"), hp_for("pex"), OBS, ACT, pre)
    same = lambda a, b: all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))  # noqa
    assert same(lrn.pi0, pre.actor) and same(lrn.critic, pre.critic) and same(lrn.value, pre.value)
    assert not same(lrn.actor, pre.actor)  # the new policy starts from a random init
    new, _ = pex.update(lrn, _batch(), jax.random.PRNGKey(2), jnp.zeros(()), hp_for("pex"), NETS, CFG,
                        jnp.zeros((), jnp.int32))
    assert same(new.pi0, pre.actor) and not same(new.actor, lrn.actor)


def test_pex_choice_follows_its_boltzmann_distribution():
    """Over 4096 states, the number of times π's action is chosen matches Σ softmax(β Q)₁ within 4 σ."""
    lrn = _learner("pex")
    obs = jax.random.normal(jax.random.PRNGKey(5), (4096, OBS))
    key = jax.random.PRNGKey(6)
    action = pex.act(NETS, lrn, obs, key, hp_for("pex"), deterministic=False)
    k_pi, _ = jax.random.split(key)
    a0, a1, q = pex.candidates(NETS, lrn, obs, k_pi, deterministic=False)
    p1 = np.asarray(jax.nn.softmax(3.0 * q, axis=-1)[:, 1], np.float64)
    chose1 = np.all(np.asarray(action) == np.asarray(a1), -1)
    chose0 = np.all(np.asarray(action) == np.asarray(a0), -1)
    assert np.all(chose0 | chose1)  # every action is one of the two candidates
    assert 0.1 < p1.mean() < 0.9  # the test is not degenerate
    assert abs(chose1.sum() - p1.sum()) < 4 * np.sqrt(np.sum(p1 * (1 - p1))), (chose1.sum(), p1.sum())
    greedy = pex.act(NETS, lrn, obs, key, hp_for("pex"), deterministic=True)
    a0d, a1d, qd = pex.candidates(NETS, lrn, obs, k_pi, deterministic=True)
    np.testing.assert_array_equal(greedy, jnp.where((qd[:, 1] > qd[:, 0])[:, None], a1d, a0d))


def test_pex_actor_loss_matches_numpy():
    lrn, batch, key = _learner("pex"), _batch(2), jax.random.PRNGKey(7)
    new, info = pex.update(lrn, batch, key, jnp.zeros(()), hp_for("pex"), NETS, CFG, jnp.zeros((), jnp.int32))
    chosen = pex.act(NETS, lrn, batch.observations, key, hp_for("pex"), deterministic=False)
    expected = ref.pex_actor_loss(lrn.actor, lrn.critic_target, new.value, batch.observations, chosen, 2.0, 100.0)
    np.testing.assert_allclose(info["actor_loss"], expected, rtol=2e-5)


def test_iql_online_update_is_the_offline_update():
    lrn, batch = _learner("iql"), _batch(3)
    new, info = iql.online_update(lrn, batch, jax.random.PRNGKey(0), jnp.zeros(()), hp_for("iql"), NETS, CFG,
                                  jnp.int32(0))
    off, off_info = iql.update(iql.offline_view(lrn), batch, NETS, iql.offline_hparams(hp_for("iql")))
    for a, b in zip(jax.tree.leaves(iql.offline_view(new)), jax.tree.leaves(off)):
        np.testing.assert_array_equal(a, b)
    # expectile 0.8 enters the value loss: recompute it by hand on the batch
    s, a = batch.observations, batch.actions
    u = ref.critics(lrn.critic_target, s, a).min(0) - ref.value_net(lrn.value, s)
    np.testing.assert_allclose(info["value_loss"], np.mean(np.abs(0.8 - (u < 0)) * u**2), rtol=2e-5)


# --------------------------------------------------------------------------------------------- learning on `point`

POINT = FinetuneConfig(env="point", net=NetworkConfig(hidden=(32, 32)), steps=1600, eval_every=400, eval_episodes=4,
                       batch_size=32, learning_starts=64)


@functools.lru_cache(maxsize=None)
def poor_data() -> Transition:
    """Point-task data from a near-random behaviour policy (expert action + N(0, 2²) noise, clipped)."""
    from test_engine import point_dataset

    return point_dataset(noise=2.0)


@functools.lru_cache(maxsize=None)
def bundle(algo: str, steps: int = 2000) -> Pretrained:
    """An offline bundle pretrained on the poor data: a weak π₀ that online learning must improve."""
    from proto_brax.agents.insample import OfflineHParams
    from proto_brax.data.dataset import with_returns_to_go
    from proto_brax.train.offline import PretrainConfig, make_pretrain, run_pretrain

    pre = make_pretrain(PretrainConfig(algo=algo, env="point", net=POINT.net, steps=steps, log_every=steps,
                                       batch_size=64))
    data = with_returns_to_go(poor_data(), 0.99) if algo == "calql" else poor_data()
    hp = OfflineHParams.create(lr_actor=1e-3, lr_critic=1e-3, lr_value=1e-3, cql_alpha=1.0)
    state, _, _ = run_pretrain(pre, hp, [0], data)
    state = jax.tree.map(lambda x: x[0], state)
    return Pretrained(actor=state.actor, critic=state.critic, value=state.value, log_alpha_sac=state.log_alpha_sac)


@pytest.mark.parametrize("name, kind", [("iql", "iql"), ("awac", "bc"), ("pex", "iql")])
def test_baseline_improves_a_weak_bundle_online(name, kind):
    """From a π₀ below 50 normalized (measured: IQL −31, AWAC 39, PEX 37) to ≥ 80 after 1600 steps (measured 86–88)."""
    m_def = methods.METHODS[name]
    cfg = dataclasses.replace(POINT, algo=m_def.algo, sampling=m_def.defaults["sampling"], regularizer=False)
    ft = make_finetune(cfg)
    hp = ft.hparams.create(lr_actor=1e-3, lr_critic=1e-3)
    start = ft.init(hp, jax.random.PRNGKey(0), bundle(kind), poor_data())
    returns0 = jax.jit(ft.evaluate)(start.learner, jax.random.PRNGKey(1)).returns
    score0 = envs.normalized_score("point", float(jnp.mean(returns0)))
    final, m = jax.jit(ft.finetune)(hp, jax.random.PRNGKey(0), bundle(kind), poor_data())
    score = np.asarray(envs.normalized_score("point", m["eval_return"]))
    assert np.all(np.isfinite(m["critic_loss"])) and score0 < 50.0 and score[-1] >= 80.0, (name, score0, score)
    if name == "pex":  # the new policy, on its own, learned too (it starts from a random init)
        alone = make_finetune(dataclasses.replace(cfg, algo="sac")).evaluate(final.learner, jax.random.PRNGKey(1))[0]
        assert envs.normalized_score("point", float(jnp.mean(alone))) >= 80.0


def test_td3_scratch_learns_point():
    from test_engine import finetune_fn

    cfg = dataclasses.replace(POINT, algo="td3", sampling="online", regularizer=False)
    ft, single = finetune_fn(cfg)
    _, m = single(ft.hparams.create(alpha0=0.0, lr_actor=1e-3, lr_critic=1e-3), jax.random.PRNGKey(0), None, None)
    score = np.asarray(envs.normalized_score("point", m["eval_return"]))
    assert score[-1] >= 80.0, score


# ---------------------------------------------------------------------------------------------- sweep integration


@pytest.mark.parametrize("name", sorted(methods.METHODS))
def test_every_method_parses_with_its_defaults(name):
    args = sweep.parse_args(["--algo", name, "--env", "point"])
    m = methods.METHODS[name]
    assert args.algo == name
    for field, value in m.defaults.items():
        assert getattr(args, field) == value, field
    assert sweep.sweep_args(name, env="point").algo == name


def test_method_help_shows_its_summary(capsys):
    with pytest.raises(SystemExit):
        sweep.parse_args(["--algo", "pex", "--help"])
    out = capsys.readouterr().out
    assert "Boltzmann" in out and "--grid" in out


def test_method_errors_name_the_fix(tmp_path):
    with pytest.raises(SystemExit, match="--algo needs one of"):
        sweep.parse_args(["--algo", "cql-magic"])
    with pytest.raises(ValueError, match="does not use tau"):
        grid_axes(sweep.sweep_args("iql", tau=(0.0, 0.1)))
    with pytest.raises(ValueError, match="NAME=V1,V2"):
        grid_axes(sweep.sweep_args("iql", grid=("expectile",)))
    assert grid_axes(sweep.sweep_args("iql", grid=("expectile=0.7,0.9",)))["expectile"] == [0.7, 0.9]
    with pytest.raises(ValueError, match="starts from a random init"):
        resolve_checkpoint(sweep.sweep_args("sac-scratch", checkpoint=str(tmp_path)))
    # a dataset without a committed IQL bundle (walker2d-medium has one since the results runs)
    assert not (REPO_ROOT / "checkpoints" / "pretrained" / "point-medium" / "iql").exists()
    with pytest.raises(FileNotFoundError, match="python -m proto_brax.pretrain --dataset point-medium --algo iql"):
        resolve_checkpoint(sweep.sweep_args("iql", env="point"))


def test_bundle_kind_must_match_the_method():
    committed = REPO_ROOT / "checkpoints" / "pretrained" / "hopper-medium" / "eql"
    args = sweep.sweep_args("iql", checkpoint=str(committed))
    cfg = finetune_config(dataclasses.replace(args, dataset="none", sampling="online"))
    with pytest.raises(ValueError, match="pretrained with iql, but .* holds 'eql'"):
        load_checkpoint(committed, cfg, None, "iql")


# ------------------------------------------------------------------------------------------------------ CQL/Cal-QL


@pytest.mark.parametrize("calibrated", [False, True])
def test_cql_penalty_matches_numpy(calibrated):
    from proto_brax.agents import cql

    lrn, key, n = _learner("calql"), jax.random.PRNGKey(8), 3
    batch = _batch(4).replace(mc_returns=jnp.array([0.5, -3.0, 2.0, 0.0, 10.0, -1.0]))
    value, info = cql.conservative_penalty(lrn.critic, lrn.actor, batch, key, NETS, n, calibrated)
    k_unif, k_cur, k_next = jax.random.split(key, 3)
    a_unif = np.asarray(jax.random.uniform(k_unif, (n, B, ACT), minval=-1.0, maxval=1.0))
    eps = [np.stack([np.asarray(jax.random.normal(k, (B, ACT))) for k in jax.random.split(kk, n)])
           for kk in (k_cur, k_next)]
    expected = ref.cql_penalty(lrn.critic, lrn.actor, batch, a_unif, eps[0], eps[1], calibrated)
    np.testing.assert_allclose(value, expected, rtol=2e-5)
    if calibrated:  # the bound of 10 on row 4 is above every Q there: it binds, and changes the value
        assert float(info["cql_bound_rate"]) > 0
        unbound = ref.cql_penalty(lrn.critic, lrn.actor, batch, a_unif, eps[0], eps[1], False)
        assert abs(expected - unbound) > 1e-3


def test_returns_to_go_by_hand():
    from proto_brax.data.dataset import returns_to_go

    obs = np.arange(7, dtype=np.float32)[:, None]
    nxt = obs + 1
    nxt[4] = 99.0  # row 5 does not continue row 4: an episode boundary without a flag
    data = Transition(observations=obs, actions=np.zeros((7, 1)), rewards=np.array([1, 2, 3, 4, 5, 6, 7.0]),
                      next_observations=nxt, terminals=np.array([0, 1, 0, 0, 0, 0, 0.0]),
                      timeouts=np.array([0, 0, 0, 1, 0, 0, 0.0]))
    g = 0.5
    expected = [1 + g * 2, 2, 3 + g * 4, 4, 5, 6 + g * 7, 7]  # episodes [0,1] [2,3] [4] [5,6]
    np.testing.assert_allclose(returns_to_go(data, g), expected)


def test_buffer_returns_accumulate_to_the_episode_returns_to_go():
    """Two envs inserting side by side with different episode lengths: after every step each stored row holds the
    discounted return of its episode so far, i.e. returns_to_go of that env's stream cut at the present."""
    from proto_brax.data.dataset import returns_to_go
    from proto_brax.data.replay import replay_accumulate_returns, replay_init, replay_insert

    n, steps, horizon, gamma = 2, 23, 7, 0.9
    rng = np.random.default_rng(0)
    rewards = rng.normal(size=(steps, n)).astype(np.float32)
    lengths = (5, 7)  # env 0 terminates every 5 steps, env 1 hits the 7-step time limit
    buf = replay_init(64, 1, 1, mc_returns=True)
    acc = jax.jit(replay_accumulate_returns, static_argnums=(5,))
    for t in range(steps):
        ep_t = jnp.array([t % lengths[0], t % lengths[1]])
        tr = Transition(observations=jnp.zeros((n, 1)), actions=jnp.zeros((n, 1)), rewards=jnp.asarray(rewards[t]),
                        next_observations=jnp.zeros((n, 1)), terminals=jnp.zeros(n), timeouts=jnp.zeros(n),
                        mc_returns=jnp.zeros(n))
        buf = acc(replay_insert(buf, tr), buf.position, jnp.asarray(rewards[t]), ep_t, jnp.float32(gamma), horizon)
    mc = np.asarray(buf.data.mc_returns[: steps * n]).reshape(steps, n)
    for e in range(n):
        ends = np.array([(t + 1) % lengths[e] == 0 for t in range(steps)], np.float32)
        stream = Transition(observations=np.zeros((steps, 1)), actions=np.zeros((steps, 1)), rewards=rewards[:, e],
                            next_observations=np.zeros((steps, 1)), terminals=ends, timeouts=np.zeros(steps))
        np.testing.assert_allclose(mc[:, e], returns_to_go(stream, gamma), rtol=1e-5, atol=1e-6)


def test_calql_finetunes_point_and_keeps_buffer_returns_exact():
    """Cal-QL from a weak Cal-QL bundle improves online; the buffer's Monte-Carlo column equals returns-to-go of the
    buffer's own rewards (one env, no wrap-around: the running episode counts as cut at the present)."""
    from proto_brax.data.dataset import returns_to_go, with_returns_to_go

    data = with_returns_to_go(poor_data(), 0.99)
    cfg = dataclasses.replace(POINT, algo="calql", sampling="symmetric", regularizer=False, cql_n_actions=4)
    ft = make_finetune(cfg)
    b = bundle("calql", steps=100)  # CQL extracts a good policy even from the poor data: stop it early
    hp = ft.hparams.create(lr_actor=1e-3, lr_critic=1e-3, alpha_sac_init=1.0, target_entropy_scale=-1.0, cql_alpha=1.0)
    start = ft.init(hp, jax.random.PRNGKey(0), b, data)
    returns0 = jax.jit(ft.evaluate)(start.learner, jax.random.PRNGKey(1)).returns
    score0 = envs.normalized_score("point", float(jnp.mean(returns0)))
    final, m = jax.jit(ft.finetune)(hp, jax.random.PRNGKey(0), b, data)
    score = np.asarray(envs.normalized_score("point", m["eval_return"]))
    assert score0 < 50.0 and score[-1] >= 80.0, (score0, score)
    np.testing.assert_allclose(final.learner.log_alpha_sac != b.log_alpha_sac, True)  # it was restored, then tuned
    stored = jax.tree.map(lambda x: np.asarray(x[: cfg.steps]), final.buffer.data)
    np.testing.assert_allclose(stored.mc_returns, returns_to_go(stored, 0.99), rtol=1e-4, atol=1e-4)


# ---------------------------------------------------------------------------------------------------------- Off2On


def _off2on(n=3, rows=50):
    from proto_brax.agents import off2on

    cfg = FinetuneConfig(env="point", net=NET, algo="off2on", ensemble_size=n, steps=64, eval_every=64)
    data = _batch(5)
    data = jax.tree.map(lambda x: jnp.concatenate([x] * (rows // B + 1))[:rows], data)
    lrn = off2on.init(jax.random.PRNGKey(3), NETS, cfg, hp_for("off2on"), OBS, ACT, None, data)
    lrn = lrn.replace(actor=perturb(lrn.actor, jax.random.PRNGKey(4)),
                      critic=perturb(lrn.critic, jax.random.PRNGKey(5)),
                      critic_target=perturb(lrn.critic, jax.random.PRNGKey(6)),
                      extra={**lrn.extra, "density": perturb(lrn.extra["density"], jax.random.PRNGKey(7))})
    return off2on, cfg, lrn, data


def test_off2on_mixture_and_density_loss_match_numpy():
    off2on, cfg, lrn, _ = _off2on()
    obs = _batch(6).observations
    mean, log_std = off2on.mixture(NETS, lrn.actor, obs)
    actors = [jax.tree.map(lambda x, i=i: x[i], lrn.actor) for i in range(cfg.ensemble_size)]
    e_mean, e_log_std = ref.mixture(actors, obs)
    np.testing.assert_allclose(mean, e_mean, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(log_std, e_log_std, rtol=1e-4, atol=1e-5)
    off, on = _batch(7), _batch(8)
    loss, _ = off2on.density_loss(lrn.extra["density"], NETS, off, on)
    np.testing.assert_allclose(loss, ref.off2on_density_loss(lrn.extra["density"], off, on), rtol=2e-5)


def test_off2on_critic_loss_matches_numpy():
    off2on, cfg, lrn, _ = _off2on()
    batch, key = _batch(9), jax.random.PRNGKey(10)
    loss, _ = off2on.critic_loss(lrn.critic, lrn, batch, key, hp_for("off2on"), NETS)
    actors = [jax.tree.map(lambda x, i=i: x[i], lrn.actor) for i in range(cfg.ensemble_size)]
    mean, log_std = ref.mixture(actors, batch.next_observations)
    u = mean + np.exp(log_std) * np.asarray(jax.random.normal(key, (B, ACT)), np.float64)
    logp = ref.tanh_gaussian_logp(u, mean, log_std)
    alpha_sac = float(np.exp(np.asarray(lrn.log_alpha_sac, np.float64)))
    expected = 0.0
    for i in range(cfg.ensemble_size):
        member = lambda tree, i=i: jax.tree.map(lambda x: x[i], tree)  # noqa: E731
        q_next = ref.critics(member(lrn.critic_target), batch.next_observations, np.tanh(u)).min(0)
        y = np.asarray(batch.rewards) + 0.9 * (1 - np.asarray(batch.terminals)) * (q_next - alpha_sac * logp)
        q = ref.critics(member(lrn.critic), batch.observations, batch.actions)
        expected += np.mean(np.sum((q - y[None]) ** 2, 0))
    np.testing.assert_allclose(loss, expected, rtol=2e-5)


def test_off2on_balanced_replay_samples_by_priority_and_updates_the_sampled_rows():
    from proto_brax.data.replay import replay_init, replay_insert

    off2on, cfg, lrn, data = _off2on(rows=4)
    cfg = dataclasses.replace(cfg, batch_size=20000)
    buf = replay_insert(replay_init(cfg.capacity, OBS, ACT), jax.tree.map(lambda x: x[:2], data))
    prio = jnp.array([1.0, 2.0, 3.0, 4.0])  # offline rows; the two online rows have none yet: they get the max (4)
    lrn = lrn.replace(extra={**lrn.extra, "priority_offline": prio})
    rl, off, on, rows = off2on.sample(jax.random.PRNGKey(0), lrn, buf, data, cfg)
    freq = np.bincount(np.asarray(rows), minlength=cfg.capacity + 4)[:6] / cfg.batch_size
    np.testing.assert_allclose(freq, np.array([1, 2, 3, 4, 4, 4]) / 18, atol=0.01)
    assert np.all(np.asarray(rows) < 6)  # rows beyond the buffer's size are never drawn
    small = dataclasses.replace(cfg, batch_size=B)
    batch = off2on.sample(jax.random.PRNGKey(1), lrn, buf, data, small)
    new, info = off2on.update(lrn, batch, jax.random.PRNGKey(2), jnp.zeros(()), hp_for("off2on"), NETS, small,
                              jnp.int32(0))
    drawn = set(np.asarray(batch[3]).tolist())
    p_all = np.concatenate([np.asarray(new.extra["priority_offline"]), np.asarray(new.extra["priority_online"])])
    old = np.concatenate([np.asarray(prio), np.zeros(cfg.capacity)])
    changed = set(np.nonzero(p_all != old)[0].tolist())
    assert changed <= drawn and changed  # only sampled rows changed
    assert np.all((p_all[sorted(drawn)] >= 1e-3) & (p_all[sorted(drawn)] <= 1e3))
    assert np.isfinite(float(info["density_loss"])) and np.isfinite(float(info["critic_loss"]))


def test_off2on_finetunes_point_from_a_cql_ensemble():
    """Five weak CQL agents (20 pretraining steps each) → Off2On improves them online (100 steps gave 50 → 95)."""
    from proto_brax.agents.insample import OfflineHParams
    from proto_brax.train.offline import PretrainConfig, make_pretrain, run_pretrain

    pre = make_pretrain(PretrainConfig(algo="cql", env="point", net=POINT.net, steps=20, log_every=20,
                                       batch_size=64))
    state, _, _ = run_pretrain(pre, OfflineHParams.create(lr_actor=1e-3, lr_critic=1e-3, cql_alpha=1.0),
                               list(range(5)), poor_data())
    b = Pretrained(actor=state.actor, critic=state.critic)
    cfg = dataclasses.replace(POINT, algo="off2on", sampling="union", regularizer=False)
    ft = make_finetune(cfg)
    hp = ft.hparams.create(lr_actor=1e-3, lr_critic=1e-3, alpha_sac_init=1.0, target_entropy_scale=-1.0)
    start = ft.init(hp, jax.random.PRNGKey(0), b, poor_data())
    returns0 = jax.jit(ft.evaluate)(start.learner, jax.random.PRNGKey(1)).returns
    score0 = envs.normalized_score("point", float(jnp.mean(returns0)))
    _, m = jax.jit(ft.finetune)(hp, jax.random.PRNGKey(0), b, poor_data())
    score = np.asarray(envs.normalized_score("point", m["eval_return"]))
    assert score0 < 50.0 and score[-1] >= 80.0, (score0, score)


def test_locomotion_runner_commands_parse(tmp_path):
    """benchmarks/locomotion.py builds one sweep command per (dataset, method) (``locomotion_plan.sweep_command``):
    each parses, with the stated budget and α annealed over the same fraction of the run (horizon = budget)."""
    from proto_brax.analysis import locomotion_plan as plan

    def command(dataset, method, resume, single_core=False):  # the runner's defaults, a 20k budget
        return plan.sweep_command(dataset, method, tmp_path / dataset / method, seeds=(0, 1, 2, 3, 4), steps=20_000,
                                  eval_every=2_500, single_core=single_core, resume=resume)

    for method in plan.PAPER_METHODS:
        cmd = command("walker2d-medium-replay", method, resume=True)
        parsed = sweep.parse_args(cmd[3:])
        assert parsed.algo == method and parsed.env == "walker2d" and parsed.steps == 20_000
        assert parsed.anneal_horizon == 20_000 and parsed.seeds == (0, 1, 2, 3, 4) and parsed.resume
        want = "none" if method == "sac-scratch" else "walker2d-medium-replay"
        assert parsed.dataset == want
    # the ablations: PROTO-SAC over the two non-default values of one axis (0.5 and 2 × τ₀; η 0.8 and 1.0)
    tau = sweep.parse_args(command("hopper-medium", "ablate-tau", resume=False)[3:])
    eta = sweep.parse_args(command("hopper-medium", "ablate-eta", resume=False)[3:])
    assert tau.algo == eta.algo == "proto-sac" and tau.dataset == "hopper-medium" and not tau.resume
    assert tau.tau == (0.0025, 0.01) and tau.eta == (0.9,) and eta.eta == (0.8, 1.0) and eta.tau == (0.005,)
    # the fidelity ablations: proto-official with one choice put back to ours, the official code's others kept
    official = sweep.parse_args(command("halfcheetah-medium", "proto-official", resume=False)[3:])
    temp = sweep.parse_args(command("halfcheetah-medium", "official-but-temperature", resume=False)[3:])
    start = sweep.parse_args(command("halfcheetah-medium", "official-but-start", resume=False)[3:])
    state = sweep.parse_args(command("halfcheetah-medium", "official-but-critic-state", resume=False)[3:])
    actor = sweep.parse_args(command("halfcheetah-medium", "official-but-actor-q", resume=False)[3:])
    assert temp.algo == start.algo == state.algo == actor.algo == "proto-official" and temp.policy == "gaussian"
    assert temp.fidelity == dataclasses.replace(official.fidelity, temperature_loss="log_alpha")
    assert official.fidelity.temperature_loss == "alpha" and official.learning_starts == 1
    assert start.fidelity == dataclasses.replace(official.fidelity, online_preload=0) and start.learning_starts == 1000
    assert state.fidelity == dataclasses.replace(official.fidelity, carry_critic_state=False)
    assert actor.fidelity == dataclasses.replace(official.fidelity, actor_q="backup")
    # rows 13-14 put back: the official code's every choice, from a Gaussian-policy bundle with this suite's EQL
    extraction = sweep.parse_args(command("halfcheetah-medium", "official-but-extraction", resume=False)[3:])
    assert extraction.fidelity == official.fidelity and extraction.policy == "gaussian"
    assert official.checkpoint == "auto"
    assert extraction.checkpoint == "checkpoints/pretrained/halfcheetah-medium/eql-gaussian"
    assert plan.missing_bundle("halfcheetah-medium", "official-but-extraction", tmp_path) == (
        "python -m proto_brax.pretrain --dataset halfcheetah-medium --algo eql --policy gaussian --out "
        "checkpoints/pretrained/halfcheetah-medium/eql-gaussian")
    assert "--hp eql_weight_scale 1 eql_z_clip 7" in plan.missing_bundle("halfcheetah-medium", "proto-official",
                                                                         tmp_path)
    # and the fourth cell of rows 6 × 13-14: our policy class from the official EQL
    policy = sweep.parse_args(command("halfcheetah-medium", "official-but-policy-class", resume=False)[3:])
    assert policy.fidelity == official.fidelity and policy.policy == "tanh_gaussian" and policy.learning_starts == 1
    assert policy.checkpoint == "checkpoints/pretrained/halfcheetah-medium/eql-official-tanh"
    assert plan.missing_bundle("halfcheetah-medium", "official-but-policy-class", tmp_path) == (
        "python -m proto_brax.pretrain --dataset halfcheetah-medium --algo eql --hp eql_weight_scale 1 eql_z_clip 7 "
        "--out checkpoints/pretrained/halfcheetah-medium/eql-official-tanh")
    assert "official-but-temperature" not in plan.LOCOMOTION.methods  # run only when named
    # single_core: one device (5 seeds, no padding run) and one XLA thread for the child
    one = command("hopper-medium", "direct", resume=False, single_core=True)
    assert sweep.parse_args(one[3:]).devices == 1 and sweep.parse_args(one[3:]).block == "map"
    assert "--xla_cpu_multi_thread_eigen=false" in plan.sweep_env(single_core=True)["XLA_FLAGS"]
    default = sweep.parse_args(command("hopper-medium", "direct", resume=False)[3:])
    assert default.devices is None and default.block == "vmap"
    # Adroit and AntMaze (--domain): their preset, env and dataset; α over the paper's 10⁶ horizon, not the budget
    pen = sweep.parse_args(plan.sweep_command("pen-human", "frozen", tmp_path / "p", (0, 1), 50_000, 5_000, False,
                                              False, domain=plan.ADROIT)[3:])
    assert (pen.env, pen.dataset, pen.algo, pen.tau, pen.alpha0) == ("pen", "pen-human", "frozen", (0.0,), (2.0,))
    assert pen.anneal_horizon == 1e6 and pen.steps == 50_000 and pen.eval_every == 5_000 and not pen.value_reg_backup
    maze = sweep.parse_args(plan.sweep_command("antmaze-large-diverse", "proto-sac", tmp_path / "m", (0,), 50_000,
                                               5_000, False, False, domain=plan.ANTMAZE)[3:])
    assert (maze.env, maze.dataset, maze.eval_episodes, maze.anneal_horizon) == ("antmaze-large", "antmaze-large-"
                                                                                "diverse", 20, 1e6)
    assert maze.dataset_size == 1_000_000 and maze.alpha0 == (0.5,)
    assert "--hp expectile 0.9 temperature 10" in plan.missing_bundle("antmaze-umaze", "iql", tmp_path, plan.ANTMAZE)
    # FIDELITY.md's AntMaze rows: PROTO-SAC with one of the official code's choices, under the AntMaze preset
    rand, beh = (sweep.parse_args(plan.sweep_command("antmaze-umaze-diverse", m, tmp_path / m, (0,), 50_000, 5_000,
                                                     False, False, domain=plan.ANTMAZE)[3:])
                 for m in ("ours-but-random-target", "ours-but-behaviour-eval"))
    assert rand.algo == beh.algo == "proto-sac" and not rand.clipped_double_q and rand.tau == (5e-5,)
    assert rand.fidelity == dataclasses.replace(maze.fidelity, unclipped_target="random")
    assert beh.fidelity == dataclasses.replace(maze.fidelity, eval_mode="behaviour")
