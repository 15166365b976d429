"""Vectorized rollouts: run a policy on many envs side by side and collect D4RL-style transitions."""

from __future__ import annotations

import dataclasses
import functools
import hashlib
from pathlib import Path
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from proto_brax import envs
from proto_brax.data.dataset import Transition
from proto_brax.data.partial import run_segments

Policy = Callable[[jax.Array, jax.Array], jax.Array]  # (obs [n, obs], key) -> actions [n, act]
ParamPolicy = Callable[[object, jax.Array, jax.Array], jax.Array]  # (params, obs, key) -> actions


def uniform_policy(action_size: int) -> Policy:
    return lambda obs, key: jax.random.uniform(key, (obs.shape[0], action_size), minval=-1.0, maxval=1.0)


@functools.lru_cache(maxsize=None)
def uniform_param_policy(action_size: int) -> ParamPolicy:
    """The uniform policy with the (ignored) parameters argument of :func:`rollouts`; cached so its rollout program
    is compiled once."""
    policy = uniform_policy(action_size)
    return lambda params, obs, key: policy(obs, key)


def collect(env, episode_length: int, policy: Policy, key: jax.Array, num_envs: int, steps: int, state=None):
    """Run ``num_envs`` envs for ``steps`` steps each (auto-reset; time-limit truncation recorded as ``timeouts``).

    Returns (transitions [steps, num_envs, ...] step-major, finished-episode returns [steps, num_envs] with a
    ``done`` mask, final env state). Pass the returned state back to continue in segments (for progress bars).
    Jit it with ``policy``, ``num_envs`` and ``steps`` static.
    """
    k_reset, k_run = jax.random.split(key)
    if state is None:
        state = jax.vmap(lambda k: envs.env_reset(env, k))(jax.random.split(k_reset, num_envs))

    def body(state, k):
        k_act, k_env = jax.random.split(k)
        action = policy(state.brax_state.obs, k_act)
        state, tr, done, ret = jax.vmap(lambda s, a, kk: envs.env_step(env, episode_length, s, a, kk))(
            state, action, jax.random.split(k_env, num_envs)
        )
        return state, (tr, done, ret)

    state, (tr, done, ret) = lax.scan(body, state, jax.random.split(k_run, steps))
    return tr, ret, done > 0, state


def flatten_env_major(tr: Transition) -> Transition:
    """[steps, envs, ...] -> [envs * steps, ...] so that each env's episodes stay contiguous (as in D4RL files).

    The last transition of every env is cut by the end of collection: it becomes a timeout unless it is a true
    terminal, so no episode runs across the boundary between two envs.
    """
    last_cut = jnp.where(tr.terminals[-1] > 0, 0.0, 1.0)
    tr = tr.replace(timeouts=tr.timeouts.at[-1].set(jnp.maximum(tr.timeouts[-1], last_cut)))
    return jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1).reshape((-1,) + x.shape[2:]), tr)


# ------------------------------------------------------------------------------------------------------------------
# D4RL-style datasets from the suite's own behaviour policies

KINDS = ("random", "medium", "medium-replay", "expert", "medium-expert")
LOCOMOTION = ("hopper", "walker2d", "halfcheetah", "ant")
DATASET_ENVS = LOCOMOTION + ("point",)
# D4RL's sizes: 10⁶ transitions, except pen's expert/cloned (5000 episodes of 100 steps); point is the test task.
DEFAULT_SIZE = {"point": 100_000, "pen": 500_000}
BEHAVIOR_ROOT = Path(__file__).resolve().parents[2] / "checkpoints" / "behavior"


def default_size(env: str, kind: str | None = None) -> int:
    if kind == "human":  # one episode per demonstration (an early termination starts another in its slot)
        return HUMAN_EPISODES * envs.get_spec(env).episode_length
    return DEFAULT_SIZE.get(env, 1_000_000)


# AntMaze (proto_brax.data.antmaze_data): D4RL's play / diverse navigation data in each maze.
ANTMAZE_ENVS = ("antmaze-umaze", "antmaze-medium", "antmaze-large")
ANTMAZE_KINDS = ("play", "diverse")
# Adroit: D4RL's expert and cloned data, made from D4RL's own DAPG expert (``data.dapg``) on the capsule model (D4RL's
# human demonstrations cannot be recorded here: ``--dataset D4RL/pen/human-v2`` loads them from a user's Minari
# cache). point-cloned is the same recipe on the test task.
ADROIT_ENVS = ("pen", "door", "hammer")
ADROIT_KINDS = ("expert", "cloned", "human")
# ``human``: the size of D4RL's human data (25 demonstrations), recorded from the suite's expert with Gaussian action
# noise standing in for a human's imprecision (a suite choice: D4RL's demonstrations came from people in VR).
HUMAN_EPISODES, HUMAN_NOISE = 25, 0.2
# Gymnasium's MuJoCo v5 locomotion (proto_brax.envs.gym_v5, the dynamics of Minari's mujoco/* data): the same kinds,
# from behaviour policies trained on gymnasium's own env (``python -m proto_brax.data.native_behavior --env
# hopper-v5``) and rolled out there (:func:`native_rollouts`), as Farama recorded mujoco/*; the sweeps run the MJX port.
GYM_V5_ENVS = tuple(f"{env}-v5" for env in LOCOMOTION)
FAMILIES = ((DATASET_ENVS, KINDS), (ANTMAZE_ENVS, ANTMAZE_KINDS), (ADROIT_ENVS, ADROIT_KINDS),
            (("point",), ("cloned", "human")), (GYM_V5_ENVS, KINDS))
# Each kind's index folds into the generation key; new kinds are appended so existing datasets keep their keys.
KEY_KINDS = KINDS + ("cloned", "human")


def dataset_key(seed: int, kind: str) -> jax.Array:
    """The generation key of a (seed, kind) dataset: its rollouts fold further indices into it."""
    return jax.random.fold_in(jax.random.PRNGKey(seed), KEY_KINDS.index(kind))


def segment_for(steps: int) -> int:
    """The largest of the usual segment lengths (≤ 1000 steps per env) that divides ``steps``: one compiled
    :func:`rollouts` segment per progress-bar update."""
    return next(d for d in (1000, 500, 250, 200, 100, 50, 25, 10, 5, 2, 1) if steps % d == 0)


def dataset_names() -> list[str]:
    return [f"{env}-{kind}" for envs_, kinds in FAMILIES for env in envs_ for kind in kinds]


def parse_name(name: str) -> tuple[str, str]:
    for envs_, kinds in FAMILIES:
        for env in envs_:
            for kind in kinds:
                if name == f"{env}-{kind}":
                    return env, kind
    raise ValueError(f"Unknown dataset {name!r}: valid names are {', '.join(dataset_names())}.")


@dataclasses.dataclass(frozen=True)
class Snapshot:
    step: int
    path: Path
    eval_return: float
    metadata: dict


def list_snapshots(env: str, root: Path | None = None) -> list[Snapshot]:
    """Behaviour-policy snapshots of ``env`` (complete ones only: an interrupted save has no metadata.json)."""
    from proto_brax.checkpoints import read_metadata

    root = Path(root or BEHAVIOR_ROOT) / env
    snaps = []
    for d in sorted(root.glob("step_*")):
        if (d / "metadata.json").exists():
            meta = read_metadata(d)
            snaps.append(Snapshot(int(meta["step"]), d, float(meta["eval_return_mean"]), meta))
    if not snaps:
        raise FileNotFoundError(
            f"No behaviour-policy snapshots for {env!r} under {root}: train them with "
            f"`python -m proto_brax.data.behavior --env {env}`."
        )
    return sorted(snaps, key=lambda s: s.step)


def pick_expert_medium(snaps: list[Snapshot], reference: tuple[float, float] | None = None
                       ) -> tuple[Snapshot, Snapshot]:
    """D4RL's convention: expert = the final snapshot; medium = the snapshot that performs at about one third of the
    expert (ties go to the earlier snapshot).

    With ``reference = (R_random, R_expert)`` (the env's registered 100-episode references) and every snapshot's
    ``behavior_return`` measured (``python -m proto_brax.datasets measure ENV``: mean return of the *stochastic*
    policy that generates the data, over 100 episodes), medium is the snapshot whose behaviour return is closest to
    R_random + (R_expert − R_random) / 3, i.e. the dataset's expected normalized score is closest to 33. Without the
    measurements, the snapshots' 10-episode deterministic training evaluations stand in, which is what D4RL did but
    is noisy and optimistic: ant's chosen that way scored 16.5 (then 22.4) normalized instead of D4RL's 25–45, as its
    sampled actions fall far more often than its mean actions. Without references: a third of the expert's
    evaluation.
    """
    expert = snaps[-1]
    candidates = snaps[:-1] or snaps
    if reference is None:
        target, value = expert.eval_return / 3.0, lambda s: s.eval_return
    else:
        target = reference[0] + (reference[1] - reference[0]) / 3.0
        measured = all("behavior_return" in s.metadata for s in candidates)
        value = (lambda s: s.metadata["behavior_return"]["mean"]) if measured else (lambda s: s.eval_return)
    medium = min(candidates, key=lambda s: (abs(value(s) - target), s.step))
    return expert, medium


def behavior_returns(env_name: str, snaps: list[Snapshot], episodes: int, seed: int):
    """Yield (snapshot, episode returns [episodes]) of each snapshot's stochastic policy over the registered time
    limit: on the env's native twin where it has one (the dynamics its datasets are recorded on, at native speed:
    ``envs.native.native_episodes``, one jitted policy call per step), else vmapped on Brax/MJX, one compiled program
    for all snapshots (the parameters are an argument). One env serves every snapshot (each episode resets from its
    key); the native twin's sizes stand in for the MJX env's, which need not be built."""
    from proto_brax.envs.native import NATIVE_ENVS, native_env

    native = env_name in NATIVE_ENVS
    env, horizon = (native_env if native else envs.make_env)(env_name), envs.get_spec(env_name).episode_length
    for snap in snaps:
        policy, params = snapshot_policy(snap, env)
        key = jax.random.PRNGKey(seed)
        yield snap, (native_returns(env, policy, params, key, episodes) if native
                     else np.asarray(_episode_returns(env, horizon, policy, params, key, episodes)))


def native_returns(env, policy: ParamPolicy, params, key: jax.Array, episodes: int) -> np.ndarray:
    """Episode returns [episodes] of ``policy`` on a native twin ``env`` (``envs.native.native_env``), one episode
    per key of ``key``'s split; the policy's key at step t is the episode's key folded with t + 1."""
    from proto_brax.envs.native import native_episodes

    act = jax.jit(policy)

    def sample(obs, k, t):
        return np.asarray(act(params, obs[None], jax.random.fold_in(k, t + 1)))[0]

    return np.asarray(native_episodes(env, sample, jax.random.split(key, episodes))["returns"])


@functools.partial(jax.jit, static_argnums=(0, 1, 2, 5))
def _episode_returns(env, horizon, policy, params, key, episodes):
    from proto_brax.train.evaluate import run_episodes

    return run_episodes(env, horizon, functools.partial(policy, params), key, episodes)


def snapshot_policy(snap: Snapshot, env, sampled: bool = True) -> tuple[ParamPolicy, object]:
    """(policy, params) of a behaviour snapshot: the suite's SAC actor (tanh-Gaussian samples, or tanh of the mean)
    or a DAPG expert (``data.dapg``: Gaussian samples or the mean, clipped to the action box)."""
    from proto_brax.data import dapg

    if snap.metadata.get("policy_class") == dapg.POLICY_CLASS:
        from proto_brax.checkpoints import restore

        params, _ = restore(snap.path, dapg.template(snap.metadata))
        return dapg.param_policy(snap.metadata["dapg"]["nonlinearity"], sampled), params
    nets, params = load_snapshot_actor(snap, env)
    return (stochastic_policy(nets) if sampled else mean_policy(nets)), params


@functools.lru_cache(maxsize=None)
def mean_policy(nets) -> ParamPolicy:
    """The SAC actor's deterministic action, tanh of its mean."""
    return lambda params, obs, key: jnp.tanh(nets.actor.apply(params, obs)[0])


def load_snapshot_actor(snap: Snapshot, env):
    """(nets, actor params) of a snapshot, with the network shapes recorded in its metadata."""
    from proto_brax.checkpoints import restore
    from proto_brax.networks import NetworkConfig, make_networks

    net = snap.metadata["config"]["finetune"]["net"]
    nets = make_networks(NetworkConfig(hidden=tuple(net["hidden"]), actor_layer_norm=net["actor_layer_norm"]),
                         env.action_size)
    template = nets.actor.init(jax.random.PRNGKey(0), jnp.zeros((1, env.observation_size)))
    params, _ = restore(snap.path, template)
    return nets, params


def params_hash(params) -> str:
    h = hashlib.sha256()
    for leaf in jax.tree.leaves(params):
        h.update(np.asarray(leaf).tobytes())
    return h.hexdigest()[:16]


@functools.lru_cache(maxsize=None)
def stochastic_policy(nets) -> ParamPolicy:
    """The behaviour policy as D4RL used it: actions sampled from the (tanh-Gaussian) SAC actor. The parameters
    are an argument and the function is cached per (structurally equal) networks, so one compiled rollout program
    serves every snapshot of a training run."""
    from proto_brax.networks import sample_tanh_gaussian

    def policy(params, obs, key):
        mean, log_std = nets.actor.apply(params, obs)
        return sample_tanh_gaussian(key, mean, log_std)[0]

    return policy


def noisy_policy(policy: ParamPolicy, sigma: float) -> ParamPolicy:
    """``policy`` with N(0, σ²) added to each action, clipped to the action box."""

    def noisy(params, obs, key):
        k_act, k_noise = jax.random.split(key)
        action = policy(params, obs, k_act)
        return jnp.clip(action + sigma * jax.random.normal(k_noise, action.shape), -1.0, 1.0)

    return noisy


def rollouts(env, horizon: int, policy: ParamPolicy, params, key, num_envs: int, steps: int, segment: int, bar=None):
    """``num_envs × steps`` transitions (numpy, env-major) of ``policy(params, ·)``, collected in jitted segments of
    ``segment`` steps so a progress bar can follow; the env state is threaded through segments, so the result does
    not depend on ``segment`` boundaries except through the keys. The segment program is compiled once per (env,
    policy, shapes), not once per ``params``."""
    if steps % segment:
        raise ValueError(f"steps ({steps}) must be a multiple of segment ({segment}).")
    tr = run_segments(
        steps // segment,
        lambda: jax.vmap(lambda k: envs.env_reset(env, k))(jax.random.split(jax.random.fold_in(key, 0), num_envs)),
        lambda i, state: _segment(env, horizon, policy, params, jax.random.fold_in(key, i + 1), num_envs, segment,
                                  state),
        tick=None if bar is None else lambda: bar.update(segment * num_envs))
    return jax.device_get(flatten_env_major(jax.tree.map(jnp.asarray, tr)))


@functools.partial(jax.jit, static_argnums=(0, 1, 2, 5, 6))
def _segment(env, horizon, policy, params, key, num_envs, steps, state):
    tr, _, _, state = collect(env, horizon, functools.partial(policy, params), key, num_envs, steps, state)
    return tr, state


def native_rollouts(env_name: str, horizon: int, policy: ParamPolicy, params, key, num_envs: int, steps: int,
                    bar=None):
    """:func:`rollouts` on the env's native twin (``envs.native_env``: gymnasium's own v5 env, Adroit's capsule model
    on MuJoCo): ``num_envs`` native envs stepped in lockstep on the host, one jitted ``policy`` call for all of them
    per step (its key: ``key`` folded with 1 + the step; env ``j``'s ``k``-th episode resets from ``key`` folded with
    0, ``j``, ``k``). The same rows' layout (env-major numpy, the time limit a timeout, each env's last row cut as a
    timeout unless terminal), so the v5 datasets are recorded on Gymnasium's MuJoCo, the dynamics of Farama's
    ``mujoco/*`` data, and the Adroit ones at native speed (MJX steps a hand ~100 times a second here)."""
    from proto_brax.envs.native import native_env

    sims = [native_env(env_name) for _ in range(num_envs)]
    reset_key = jax.random.fold_in(key, 0)
    episode, t = np.zeros(num_envs, int), np.zeros(num_envs, int)
    obs = np.stack([sim.reset(jax.random.fold_in(jax.random.fold_in(reset_key, j), 0)) for j, sim in enumerate(sims)])
    act = jax.jit(policy)
    out = {k: [] for k in ("observations", "actions", "rewards", "next_observations", "terminals", "timeouts")}
    for i in range(steps):
        actions = np.asarray(act(params, obs, jax.random.fold_in(key, i + 1)), np.float32)
        rows = [sim.step(a) for sim, a in zip(sims, actions)]
        next_obs = np.stack([r[0] for r in rows])
        terminal = np.array([r[2] for r in rows], np.float32)
        t += 1
        timeout = ((t >= horizon) & (terminal == 0)).astype(np.float32)
        for k, v in (("observations", obs), ("actions", actions), ("rewards", np.array([r[1] for r in rows])),
                     ("next_observations", next_obs), ("terminals", terminal), ("timeouts", timeout)):
            out[k].append(np.asarray(v, np.float32))
        obs = next_obs.copy()  # (not a view: the resets below must not write into the stored next_observations)
        for j in np.flatnonzero((terminal > 0) | (timeout > 0)):
            episode[j] += 1
            t[j] = 0
            obs[j] = sims[j].reset(jax.random.fold_in(jax.random.fold_in(reset_key, j), episode[j]))
        if bar is not None:
            bar.update(num_envs)
    tr = Transition(**{k: np.stack(v) for k, v in out.items()})  # [steps, envs, ...]
    return jax.device_get(flatten_env_major(jax.tree.map(jnp.asarray, tr)))


def dataset_rollouts(env_name: str, horizon: int, policy: ParamPolicy, params, key, num_envs: int, steps: int,
                     bar=None, env=None):
    """A dataset's rollouts: on the env's native twin where it has one (:func:`native_rollouts`: gymnasium's own v5
    envs, Adroit's MuJoCo model), else jitted on Brax/MJX (:func:`rollouts`, on ``env`` or the registered env)."""
    from proto_brax.envs.native import NATIVE_ENVS

    if env_name in NATIVE_ENVS:
        return native_rollouts(env_name, horizon, policy, params, key, num_envs, steps, bar)
    return rollouts(env if env is not None else envs.make_env(env_name), horizon, policy, params, key, num_envs,
                    steps, segment_for(steps), bar)
