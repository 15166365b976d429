"""Offline pretraining: EQL, SQL, IQL (in-sample) or BC + FQE, as ``lax.scan`` inside one jit, vmapped over seeds."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable, Literal

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from proto_brax import checkpoints, envs
from proto_brax.agents import cql, eql, iql, sql
from proto_brax.agents.fqe import bc_fqe_update
from proto_brax.agents.insample import OfflineHParams, OfflineState, init_offline_state
from proto_brax.agents.registry import GAUSSIAN_POLICY_ALGOS, PRETRAIN_ALGOS, TEMPERATURE_ALGOS, VALUE_ALGOS
from proto_brax.config import FinetuneConfig
from proto_brax.data.dataset import OfflineDataset
from proto_brax.files import nan_for_null, strict_json
from proto_brax.networks import NetworkConfig, make_networks
from proto_brax.train.evaluate import run_episodes


@dataclasses.dataclass(frozen=True)
class PretrainConfig:
    """Static pretraining configuration (paper: 10⁵ steps MuJoCo/Adroit, 2·10⁵ AntMaze; batch 256; 2×256)."""

    algo: Literal[PRETRAIN_ALGOS] = "eql"
    env: str = "hopper"
    net: NetworkConfig = NetworkConfig()
    steps: int = 100_000
    log_every: int = 10_000  # steps per compiled chunk (metrics are averaged over it)
    batch_size: int = 256
    eval_episodes: int = 10

    def __post_init__(self):
        if self.algo not in PRETRAIN_ALGOS:
            raise ValueError(f"Unknown pretraining algo {self.algo!r}: choose one of {list(PRETRAIN_ALGOS)}.")
        if self.net.policy != "tanh_gaussian" and self.algo not in GAUSSIAN_POLICY_ALGOS:
            raise ValueError(f"--policy {self.net.policy} is implemented for {list(GAUSSIAN_POLICY_ALGOS)}; "
                             f"pretrain {self.algo} with --policy tanh_gaussian.")
        envs.get_spec(self.env)
        for name in ("steps", "log_every", "batch_size", "eval_episodes"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1; got {getattr(self, name)}.")
        if self.steps % self.log_every:
            raise ValueError(f"steps ({self.steps}) must be a multiple of log_every ({self.log_every}).")


@dataclasses.dataclass(frozen=True)
class Pretrain:
    cfg: PretrainConfig
    init: Callable  # (hp, key) -> OfflineState
    chunk: Callable  # (state, hp, dataset, key) -> (state, metrics)
    evaluate: Callable  # (actor, key) -> returns [eval_episodes]
    nets: object
    obs_size: int
    act_size: int


def make_pretrain(cfg: PretrainConfig) -> Pretrain:
    env = envs.make_env(cfg.env)
    obs_size, act_size = env.observation_size, env.action_size
    nets = make_networks(cfg.net, act_size)
    spec = envs.get_spec(cfg.env)
    horizon = spec.episode_length
    insample = {"eql": eql.update, "sql": sql.update, "iql": iql.update}
    cql_cfg = FinetuneConfig(env=cfg.env, algo=cfg.algo if cfg.algo in TEMPERATURE_ALGOS else "cql", net=cfg.net,
                             regularizer=False)

    def init(hp: OfflineHParams, key: jax.Array) -> OfflineState:
        return init_offline_state(key, nets, obs_size, act_size, hp, with_value=cfg.algo in VALUE_ALGOS,
                                  with_temperature=cfg.algo in TEMPERATURE_ALGOS)

    def step(state, key, hp, dataset):
        k_idx, k_upd = jax.random.split(key)
        idx = jax.random.randint(k_idx, (cfg.batch_size,), 0, dataset.rewards.shape[0])
        batch = jax.tree.map(lambda x: jnp.take(x, idx, axis=0), dataset)
        if cfg.algo == "bc":
            return bc_fqe_update(state, batch, k_upd, nets, hp)
        if cfg.algo in TEMPERATURE_ALGOS:
            return cql.offline_update(state, batch, k_upd, nets, hp, cql_cfg, calibrated=cfg.algo == "calql")
        return insample[cfg.algo](state, batch, nets, hp)

    def chunk(state: OfflineState, hp: OfflineHParams, dataset: OfflineDataset, key: jax.Array):
        state, m = lax.scan(lambda s, k: step(s, k, hp, dataset), state, jax.random.split(key, cfg.log_every))
        return state, jax.tree.map(jnp.mean, m)

    def evaluate(actor, key):
        policy = lambda obs, k: nets.policy.mode(nets.actor.apply(actor, obs)[0])  # noqa: E731
        return run_episodes(env, horizon, policy, key, cfg.eval_episodes, spec.eval_one_at_a_time)

    return Pretrain(cfg=cfg, init=init, chunk=chunk, evaluate=evaluate, nets=nets, obs_size=obs_size,
                    act_size=act_size)


def run_pretrain(pre: Pretrain, hp: OfflineHParams, seeds, dataset: OfflineDataset, callback=None,
                 resume: Path | None = None):
    """All seeds in one vmapped program. Returns (state with a leading seed axis, per-chunk metrics, eval returns).

    With ``resume``, the state and the metrics so far are saved there after each chunk (the newest kept), and a
    rerun continues after the last saved chunk. Chunk c's keys depend on c alone, so a resumed run ends with the
    state of an uninterrupted one."""
    keys = jax.vmap(jax.random.PRNGKey)(jnp.asarray(seeds, jnp.uint32))
    init = jax.jit(jax.vmap(pre.init, in_axes=(None, 0)))
    chunk = jax.jit(jax.vmap(pre.chunk, in_axes=(0, None, None, 0)), donate_argnums=(0,))
    state = init(hp, keys)
    history, start = [], 0
    if resume is not None and (latest := checkpoints.latest_step(resume)) is not None:
        state, meta = checkpoints.restore(latest, state)
        start = meta["chunks_done"]
        history = [{k: np.asarray(nan_for_null(v), np.float32) for k, v in h.items()} for h in meta["history"]]
    for c in range(start, pre.cfg.steps // pre.cfg.log_every):
        ck = jax.vmap(jax.random.fold_in, in_axes=(0, None))(keys, c + 1)
        state, m = chunk(state, hp, dataset, ck)
        m = jax.device_get(m)
        history.append(m)
        if resume is not None:
            record = [{k: np.asarray(v).tolist() for k, v in h.items()} for h in history]
            checkpoints.save_step(resume, c + 1, state, {"chunks_done": c + 1, "history": strict_json(record)}, keep=1)
        if callback is not None:
            callback(c, m)
    ek = jax.vmap(lambda k: jax.random.fold_in(k, 0))(keys)
    returns = jax.device_get(jax.jit(jax.vmap(pre.evaluate))(state.actor, ek))
    return state, jax.tree.map(lambda *xs: jnp.stack(xs), *history), returns
