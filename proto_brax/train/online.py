"""Online (fine)tuning: one jitted step = env step + buffer insert + sample + update + π̄/targets + α schedule.

``make_finetune(cfg)`` returns a ``Finetune`` of pure functions of one run:

* ``init(hp, key, pretrained, dataset) -> TrainState``
* ``chunk(state, hp, dataset, start) -> (state, metrics)``: ``cfg.eval_every`` steps in ``lax.scan``, then one
  vectorized deterministic evaluation. ``start`` (the global step at which the chunk begins) is *unbatched*: under
  ``vmap`` it stays a scalar, so the warm-up test ``t >= learning_starts`` and TD3's delay are real ``lax.cond``
  branches, not both-sides selects.
* ``finetune(hp, key, pretrained, dataset) -> (state, metrics)``: the whole run (init + scan over chunks).

None of them knows about grids: a sweep is ``jit(vmap(fn, in_axes=(0, 0, None, None)))`` at the call site
(``proto_brax.train.grid``), the dataset and the pretrained bundle shared with ``in_axes=None``.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import jax
import jax.numpy as jnp
from flax import struct
from jax import lax

from proto_brax import envs
from proto_brax.agents import registry
from proto_brax.agents.learner import Learner, Pretrained, init_learner
from proto_brax.agents.proto import alpha_schedule
from proto_brax.config import FinetuneConfig, HParams
from proto_brax.data.dataset import OfflineDataset
from proto_brax.data.replay import ReplayBuffer, replay_accumulate_returns, replay_init, replay_insert, replay_sample
from proto_brax.networks import make_networks
from proto_brax.train.evaluate import EpisodeStats, run_episode_stats
from proto_brax.train.grid import run_batched

ACTOR_METRICS = ("actor_loss", "kl_pibar", "lambda", "entropy", "weight_mean", "log_prob")

# Incremented each time a chunk function is traced (tests assert that chunks do not re-trace).
TRACE_COUNT = {"chunk": 0}


@struct.dataclass
class TrainState:
    learner: Learner
    buffer: ReplayBuffer
    env: envs.EnvState  # leading axis num_envs
    key: jax.Array
    step: jax.Array  # env steps taken (per env)


@dataclasses.dataclass(frozen=True)
class Finetune:
    cfg: FinetuneConfig
    init: Callable
    chunk: Callable
    finetune: Callable
    evaluate: Callable
    hparams: type[HParams]  # its agent's traced hyper-parameters: grids are built with make_grid(..., hparams=…)


def make_finetune(cfg: FinetuneConfig) -> Finetune:
    env, spec = envs.make_env(cfg.env, cfg.backend), envs.get_spec(cfg.env)
    obs_size, act_size = env.observation_size, env.action_size
    algo = registry.agent(cfg.algo)
    algo = algo.configure(cfg) if algo.configure is not None else algo
    nets = make_networks(cfg.net, act_size, deterministic=algo.deterministic)
    horizon = cfg.horizon
    if cfg.fidelity.carry_critic_state and algo.init is not None:
        raise ValueError(f"carry_critic_state is implemented for the learners built by init_learner, not for "
                         f"{cfg.algo!r}'s own; turn it off.")
    if cfg.net.policy not in algo.policies:
        raise ValueError(f"policy {cfg.net.policy!r} is not implemented for {cfg.algo!r}: use one of "
                         f"{list(algo.policies)}.")
    if algo.mc_returns and cfg.capacity < horizon * cfg.num_envs:
        raise ValueError(f"algo {cfg.algo!r} keeps Monte-Carlo returns in the buffer: buffer_capacity must be >= "
                         f"episode length × num_envs = {horizon * cfg.num_envs}; got {cfg.capacity}.")

    def expect(hp) -> None:  # (at trace time: a grid built for another agent fails here, not deep in its update)
        if not isinstance(hp, algo.hparams):
            raise TypeError(f"algo {cfg.algo!r} takes {algo.hparams.__name__}, got {type(hp).__name__}: build the "
                            f"grid with make_grid(..., hparams=finetune.hparams) or {algo.hparams.__name__}.create().")

    def init(hp: HParams, key: jax.Array, pretrained: Pretrained | None, dataset: OfflineDataset | None):
        expect(hp)
        if algo.mc_returns and dataset is not None and dataset.mc_returns is None:
            raise ValueError(f"algo {cfg.algo!r} needs Monte-Carlo returns in the dataset: pass "
                             "proto_brax.data.dataset.with_returns_to_go(dataset, gamma).")
        if dataset is not None and dataset.observations.shape[-1] != obs_size:
            raise ValueError(
                f"Dataset observations have size {dataset.observations.shape[-1]} but env {cfg.env!r} has "
                f"{obs_size}: use a dataset made for {cfg.env!r}."
            )
        preload = cfg.fidelity.online_preload
        if preload and (dataset is None or algo.mc_returns):
            raise ValueError("fidelity.online_preload copies offline rows into the online buffer: it needs a dataset "
                             "and an algo without Monte-Carlo returns (not calql); use online_preload 0.")
        k_learner, k_env, k_run = jax.random.split(key, 3)
        if algo.init is not None:
            learner = algo.init(k_learner, nets, cfg, hp, obs_size, act_size, pretrained, dataset)
        else:
            learner = init_learner(k_learner, nets, algo, hp, obs_size, act_size, pretrained,
                                   cfg.fidelity.carry_critic_state)
        env_state = jax.vmap(lambda k: envs.env_reset(env, k))(jax.random.split(k_env, cfg.num_envs))
        buffer = replay_init(cfg.capacity, obs_size, act_size, mc_returns=algo.mc_returns)
        if preload:  # fold_in: the default runs' keys stay as they were
            rows = jax.random.choice(jax.random.fold_in(key, 0x9E10AD), dataset.rewards.shape[0], (preload,),
                                     replace=preload > dataset.rewards.shape[0])
            buffer = replay_insert(buffer, jax.tree.map(lambda x: x[rows], dataset.replace(mc_returns=None)))
        return TrainState(
            learner=learner,
            buffer=buffer,
            env=env_state,
            key=k_run,
            step=jnp.zeros((), jnp.int32),
        )

    def train_step(state: TrainState, t: jax.Array, hp: HParams, dataset):
        key, k_act, k_env, k_update = jax.random.split(state.key, 4)
        obs = state.env.brax_state.obs
        action = algo.act(nets, state.learner, obs, k_act, hp, deterministic=False)
        # run_batched steps one env unbatched: XLA:CPU runs a batch-of-one vmap of the physics up to 2x slower (ms per
        # step, one thread, unbatched vs vmapped: pen 2.93 vs 5.61, door 5.94 vs 10.12, hopper-v5 2.85 vs 4.30,
        # halfcheetah 0.82 vs 0.88; benchmarks/one_env.py, docs/MEASUREMENTS.md#one-env). Same keys: only rounding
        # moves.
        step = run_batched(lambda s, a, k: envs.env_step(env, horizon, s, a, k), (0, 0, 0))
        env_state, transition, done, ret = step(state.env, action, jax.random.split(k_env, cfg.num_envs))
        # Training rewards in the offline data's units; ``ret`` (reported returns) stays raw.
        transition = transition.replace(rewards=cfg.reward_scale * transition.rewards + cfg.reward_shift)
        if algo.mc_returns:  # the new rows start at 0 and collect their episode's rewards as they come
            transition = transition.replace(mc_returns=jnp.zeros_like(transition.rewards))
            buffer = replay_accumulate_returns(replay_insert(state.buffer, transition), state.buffer.position,
                                               transition.rewards, state.env.t, hp.gamma, horizon)
        else:
            buffer = replay_insert(state.buffer, transition)
        samples = (t + 1) * cfg.num_envs
        alpha = alpha_schedule(hp.alpha0, hp.eta, hp.anneal_horizon, hp.alpha_min, samples.astype(jnp.float32))

        def learn(learner):
            def one(learner, x):
                i, k = x
                k_sample, k_upd = jax.random.split(k)
                if algo.sample is not None:
                    batch = algo.sample(k_sample, learner, buffer, dataset, cfg)
                else:
                    batch = replay_sample(k_sample, buffer, dataset, cfg.batch_size, cfg.sampling,
                                          cfg.offline_fraction)
                return algo.update(learner, batch, k_upd, alpha, hp, nets, cfg, t * cfg.updates_per_step + i)

            xs = (jnp.arange(cfg.updates_per_step), jax.random.split(k_update, cfg.updates_per_step))
            learner, m = lax.scan(one, learner, xs)
            return learner, jax.tree.map(jnp.mean, m), jnp.ones(())

        def wait(learner):
            metrics = jax.eval_shape(learn, learner)[1]
            return learner, jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), metrics), jnp.zeros(())

        learner, metrics, updated = lax.cond(samples >= cfg.learning_starts, learn, wait, state.learner)
        stats = {
            **metrics,
            "alpha": alpha,
            "episodes": jnp.sum(done),
            "episode_return_sum": jnp.sum(jnp.where(done > 0, ret, 0.0)),
        }
        new = TrainState(learner=learner, buffer=buffer, env=env_state, key=key, step=state.step + 1)
        return new, (stats, updated)

    def evaluate(learner: Learner, key: jax.Array, hp: HParams | None = None) -> EpisodeStats:
        """Returns, lengths and success steps of ``eval_episodes`` deterministic episodes run side by side (each to
        termination or horizon; on a goal task the length is the steps to the goal). With ``Fidelity.eval_mode =
        'behaviour'`` the episodes act as in training (the official code's AntMaze evaluation); TD3's exploration
        noise then comes from ``hp`` (the agent's defaults when None)."""
        deterministic = cfg.fidelity.eval_mode == "deterministic"
        hp = algo.hparams.create() if hp is None and not deterministic else hp
        policy = lambda obs, k: algo.act(nets, learner, obs, k, hp, deterministic=deterministic)  # noqa: E731
        return run_episode_stats(env, horizon, policy, key, cfg.eval_episodes, spec.eval_one_at_a_time)

    def chunk(state: TrainState, hp: HParams, dataset, start: jax.Array):
        expect(hp)
        TRACE_COUNT["chunk"] += 1
        ts = start + jnp.arange(cfg.eval_every)
        state, (stats, updated) = lax.scan(lambda s, t: train_step(s, t, hp, dataset), state, ts)
        # Means over the steps that updated; actor metrics over the steps that updated the actor (TD3's delay).
        n_upd = jnp.maximum(jnp.sum(updated), 1.0)
        n_act = jnp.maximum(jnp.sum(stats["actor_updates"]), 1.0)
        host_keys = ("alpha", "episodes", "episode_return_sum", "actor_updates")
        metrics = {k: jnp.sum(v) / (n_act if k in ACTOR_METRICS else n_upd) for k, v in stats.items()
                   if k not in host_keys}
        episodes = jnp.sum(stats["episodes"])
        key, k_eval, k_batch, k_dev1, k_dev2 = jax.random.split(state.key, 5)
        returns, lengths, success_steps = evaluate(state.learner, k_eval, hp)
        # Policy drift diagnostics on a fresh training batch: KL(π‖π̄) and KL(π‖π₀) (TD3: mean squared distance).
        batch = replay_sample(k_batch, state.buffer, dataset, cfg.batch_size, cfg.sampling, cfg.offline_fraction)
        lrn = state.learner
        metrics.update(
            step=(start + cfg.eval_every) * cfg.num_envs,
            alpha=stats["alpha"][-1],
            updates=jnp.sum(updated) * cfg.updates_per_step,
            train_episodes=episodes,
            train_return=jnp.where(episodes > 0, jnp.sum(stats["episode_return_sum"]) / jnp.maximum(episodes, 1),
                                   jnp.nan),
            eval_return=jnp.mean(returns),
            eval_returns=returns,
            eval_lengths=lengths,
            eval_success_steps=success_steps,
            dev_pibar=algo.deviation(nets, lrn.actor, lrn.pibar, batch.observations, k_dev1),
            dev_pi0=algo.deviation(nets, lrn.actor, lrn.pi0, batch.observations, k_dev2),
        )
        return state.replace(key=key), metrics

    def finetune(hp: HParams, key: jax.Array, pretrained: Pretrained | None, dataset: OfflineDataset | None):
        state = init(hp, key, pretrained, dataset)
        starts = jnp.arange(cfg.num_chunks) * cfg.eval_every
        return lax.scan(lambda s, start: chunk(s, hp, dataset, start), state, starts)

    return Finetune(cfg=cfg, init=init, chunk=chunk, finetune=finetune, evaluate=evaluate, hparams=algo.hparams)
