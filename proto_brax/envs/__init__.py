"""Environment registry, time-limit/auto-reset stepping and normalized-score references.

Every task is a Brax ``Env``. We do our own time limit and auto-reset (instead of brax's ``EpisodeWrapper`` +
``AutoResetWrapper``) for two reasons:

* a time-limit truncation must not cut bootstrapping: the stored transition keeps the *true* next observation and
  ``terminal = 0``; only the environment's own termination (e.g. the hopper falling) sets ``terminal = 1``;
* brax's auto-reset restarts every episode from the same cached first state; we draw a fresh initial state per episode.

Default backends were chosen from control steps/s at batch 1 on the project's 2-core CPU: one env step must stay small
beside one SAC update (~6 ms), so the default is the most accurate backend that costs well under 10% of an update.
Columns: shared/FACTS.md's measurements (random actions, lax.scan); "ours" = measured here for the default backend with
our stepping (time limit + a fresh reset every step), 2000-step scan, 2026-11-22.

| env         | generalized | positional | spring | mjx  | default     | ours (plain / with reset) |
|-------------|-------------|------------|--------|------|-------------|---------------------------|
| hopper      | 3.7k        | 6.3k       | 21k    | 2.1k | generalized | 3.9k / 3.3k               |
| walker2d    | 1.8k        | 5.7k       | 16k    | 1.4k | generalized | (positional: 7.4k / 4.2k) |
| halfcheetah | 0.7k        | 1.1k       | 4.6k   | 0.6k | positional  | 1.2k / 1.2k               |
| ant         | 2.4k        | 2.4k       | 8.6k   | 2.4k | generalized | 2.2k / 1.7k               |

Spring is fastest but the crudest contact model; positional is used where generalized costs over ~0.5 ms a step, except
walker2d (see REGISTRY: SAC did not learn it on positional).
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State
from flax import struct

from proto_brax.data.dataset import Transition

BACKENDS = ("generalized", "positional", "spring", "mjx")


@dataclasses.dataclass(frozen=True)
class EnvSpec:
    """A registered task.

    ``ref_random`` / ``ref_expert`` are the reference returns of the normalized score
    ``100 * (R - R_random) / (R_expert - R_random)``; ``None`` until measured (then scores are reported as NaN).
    """

    name: str
    default_backend: str
    episode_length: int = 1000
    ref_random: float | None = None
    ref_expert: float | None = None
    kwargs: tuple[tuple[str, Any], ...] = ()
    # Training-time reward transform r' = scale · r + shift (evaluation always reports raw returns). "return-range":
    # scale = 1000 / (max − min episode return of the offline data), as IQL's, IVR's and PROTO's reference code
    # normalize D4RL locomotion, so that the temperatures α (EQL 2.0, PROTO α₀ 2.0) mean what they mean there;
    # "none": scale 1. reward_shift: AntMaze's r − 1 (the same codes).
    reward_scale_rule: str = "return-range"
    reward_shift: float = 0.0
    goal_task: bool = False  # episodes end at the goal with return 1: reports add success rate and steps to goal
    # Adroit's success rule (D4RL / mjrl ``evaluate_success``): an episode succeeds when ``state.metrics["success"]``
    # (D4RL's goal_achieved) held on more than this many of its steps; reports add the success rate.
    success_steps: int | None = None
    # LayerNorm in Q and V by default; the PROTO paper (and its code) turn it off for halfcheetah.
    critic_layer_norm: bool = True
    # Evaluation runs its episodes one after another, each unbatched, instead of side by side (run_episode_stats):
    # 2-3x faster for the MJX hands, 2x slower for Brax's locomotion (one thread, 10 episodes, a fixed noisy linear
    # policy; side-by-side / one-at-a-time seconds: pen 2.34 / 0.77, door 15.5 / 8.8, halfcheetah 3.00 / 5.71;
    # benchmarks/one_env.py, docs/MEASUREMENTS.md#one-env).
    eval_one_at_a_time: bool = False


def default_layer_norm(env: str) -> bool:
    """The paper's rule for the critics' LayerNorm: on, except halfcheetah (the one place it is written)."""
    return get_spec(env).critic_layer_norm


class PointReach(Env):
    """A tiny, fast 2-D point-mass task for tests and smoke runs.

    The agent starts uniformly in [-1, 1]^2 and moves by ``0.2 * action`` per step; the reward is
    ``1 - |x'|`` (highest at the origin). Leaving the box |x|_inf > 1.9 terminates the episode, so the task has true
    terminals as well as time-limit truncations. A good policy walks to the origin in ~5 steps and stays:
    return ≈ 49 of at most 50; the uniform random policy scores ≈ 0.34.
    """

    def __init__(self, backend: str = "generalized"):
        del backend  # no physics engine: the dynamics are the same under every name

    def reset(self, rng: jax.Array) -> State:
        x = jax.random.uniform(rng, (2,), minval=-1.0, maxval=1.0)
        zero = jnp.zeros(())
        return State(pipeline_state=x, obs=self._obs(x), reward=zero, done=zero, metrics={}, info={})

    def step(self, state: State, action: jax.Array) -> State:
        x = state.pipeline_state + 0.2 * jnp.clip(action, -1.0, 1.0)
        reward = 1.0 - jnp.linalg.norm(x)
        done = (jnp.max(jnp.abs(x)) > 1.9).astype(jnp.float32)
        return state.replace(pipeline_state=x, obs=self._obs(x), reward=reward, done=done)

    @staticmethod
    def _obs(x: jax.Array) -> jax.Array:
        return jnp.concatenate([x, jnp.sin(3.0 * x)])

    @property
    def observation_size(self) -> int:
        return 4

    @property
    def action_size(self) -> int:
        return 2

    @property
    def backend(self) -> str:
        return "none"


# Locomotion references: `python -m proto_brax.datasets references ENV` — mean return over 100 episodes (seed 0) of
# the uniform random policy and of the deterministic final behaviour snapshot (checkpoints/behavior/ENV, SAC from
# scratch, 3e5 steps; walker2d 5e5). Brax rewards differ from MuJoCo-gym's, so D4RL's numbers do not apply.
REGISTRY: dict[str, EnvSpec] = {
    # hopper: random 19.25 ± 18.99, expert 3117.85 ± 11.01 (snapshot step 300000)
    "hopper": EnvSpec("hopper", "generalized", ref_random=19.25, ref_expert=3117.85),
    # walker2d runs on generalized: SAC on positional plateaued at 450-580 eval return by 240k steps (2026-11-22) while
    # hopper on generalized passed 2000; generalized costs ~0.55 ms a step, under 10% of an update.
    # walker2d: random 2.58 ± 4.69, expert 2344.99 ± 766.06 (snapshot step 500000; it still falls in some episodes)
    "walker2d": EnvSpec("walker2d", "generalized", ref_random=2.58, ref_expert=2344.99),
    # halfcheetah: random -116.57 ± 46.52, expert 3218.41 ± 14.66 (snapshot step 300000)
    "halfcheetah": EnvSpec("halfcheetah", "positional", ref_random=-116.57, ref_expert=3218.41,
                           critic_layer_norm=False),
    # ant: random -6.85 ± 20.72, expert 5632.12 ± 969.93 (snapshot step 300000; its 10-episode training eval: 3962)
    "ant": EnvSpec("ant", "generalized", ref_random=-6.85, ref_expert=5632.12),
    # Point references: mean return over 100 episodes (seed 123) of the uniform policy and of the analytic controller
    # a = clip(-x / 0.2, -1, 1); re-measured by tests/test_engine.py::test_point_references.
    "point": EnvSpec("point", "generalized", episode_length=50, ref_random=0.34, ref_expert=49.0,
                     reward_scale_rule="none"),  # unit-size rewards already: keeps the test task raw
    # AntMaze (proto_brax/envs/antmaze.py): D4RL's sparse-reward eval mazes on MJX; time limits are D4RL's (700 umaze,
    # 1000 medium/large) and the references are D4RL's antmaze ones (0 / 1), so the score is 100 x success-return.
    # Goal reaching on AntMaze's physics (open floor): the low-level controller the AntMaze datasets steer.
    "ant-goal": EnvSpec("ant-goal", "mjx", episode_length=1000, reward_scale_rule="none"),
    "antmaze-umaze": EnvSpec("antmaze-umaze", "mjx", episode_length=700, ref_random=0.0, ref_expert=1.0,
                             reward_scale_rule="none", reward_shift=-1.0, goal_task=True),
    "antmaze-medium": EnvSpec("antmaze-medium", "mjx", episode_length=1000, ref_random=0.0, ref_expert=1.0,
                              reward_scale_rule="none", reward_shift=-1.0, goal_task=True),
    "antmaze-large": EnvSpec("antmaze-large", "mjx", episode_length=1000, ref_random=0.0, ref_expert=1.0,
                            reward_scale_rule="none", reward_shift=-1.0, goal_task=True),
    # Adroit (envs/adroit.py): gymnasium-robotics' AdroitHand{Pen,Door,Hammer}-v1 on MJX, with cylinders turned
    # into capsules (MJX has no cylinder-box collider; benchmarks/results/adroit_check.json measures the effect).
    # These are the D4RL tasks PROTO reports, so the registry builds them as D4RL's hand_dapg envs (d4rl_reward: the
    # palm-distance term of door / hammer is subtracted, as in D4RL and gymnasium-robotics <= 1.2.0, where 1.4.2 adds
    # it; D4RL's pen ends the episode when the pen drops) with D4RL's time limits (pen 100, door and hammer 200;
    # gymnasium-robotics registers all three at 200). References: D4RL's (d4rl/hand_manipulation_suite/__init__.py
    # PEN/DOOR/HAMMER_RANDOM_SCORE / _EXPERT_SCORE), measured on D4RL's own MuJoCo envs; the capsule geometry and MJX
    # may shift them (not re-measured here). No reward rescaling: IQL's and PROTO's reference code normalize the
    # rewards of D4RL locomotion only (return range) and AntMaze (r - 1); to our knowledge they feed Adroit rewards
    # raw, though we could not re-read PROTO's code here to confirm it. goal_task stays False: Adroit episodes run to
    # the time limit and their returns are dense; success counts D4RL's goal_achieved steps (mjrl's evaluate_success:
    # pen within 15° of its target on > 20 steps, door open / nail in on > 25).
    "pen": EnvSpec("pen", "mjx", episode_length=100, ref_random=96.262799, ref_expert=3076.8331,
                   reward_scale_rule="none", kwargs=(("d4rl_reward", True),), success_steps=20,
                   eval_one_at_a_time=True),
    "door": EnvSpec("door", "mjx", episode_length=200, ref_random=-56.512833, ref_expert=2880.5693,
                    reward_scale_rule="none", kwargs=(("d4rl_reward", True),), success_steps=25,
                    eval_one_at_a_time=True),
    "hammer": EnvSpec("hammer", "mjx", episode_length=200, ref_random=-274.856578, ref_expert=12794.1340,
                      reward_scale_rule="none", kwargs=(("d4rl_reward", True),), success_steps=25,
                      eval_one_at_a_time=True),
    # Gymnasium's MuJoCo v5 locomotion on MJX (proto_brax/envs/gym_v5.py; the dynamics of Minari's mujoco/* data),
    # gymnasium's 1000-step limits. References: D4RL's (d4rl/infos.py REF_MIN_SCORE / REF_MAX_SCORE, random / expert,
    # measured on the v2 envs: mujoco-py, Hopper-v3 etc.), so scores sit beside published D4RL ones; v5 differs
    # from v2 in small ways (e.g. walker2d's left-foot friction, ant's contact cost and 105-dim observation).
    "hopper-v5": EnvSpec("hopper-v5", "mjx", ref_random=-20.272305, ref_expert=3234.3),
    "walker2d-v5": EnvSpec("walker2d-v5", "mjx", ref_random=1.629008, ref_expert=4592.3),
    "halfcheetah-v5": EnvSpec("halfcheetah-v5", "mjx", ref_random=-280.178953, ref_expert=12135.0,
                              critic_layer_norm=False),
    "ant-v5": EnvSpec("ant-v5", "mjx", ref_random=-325.6, ref_expert=3879.7),
}


def get_spec(name: str) -> EnvSpec:
    if name not in REGISTRY:
        raise ValueError(f"Unknown env {name!r}: choose one of {sorted(REGISTRY)}.")
    return REGISTRY[name]


def check_backend(backend: str) -> None:
    if backend not in BACKENDS:
        raise ValueError(f"Unknown backend {backend!r}: choose one of {list(BACKENDS)}.")


def make_env(name: str, backend: str | None = None) -> Env:
    """Build the raw Brax env (no wrappers) for a registered task; validates name and backend."""
    spec = get_spec(name)
    backend = backend or spec.default_backend
    check_backend(backend)
    if name == "point":
        return PointReach(backend)
    if name == "ant-goal":
        from proto_brax.envs.antmaze import AntGoal  # imported lazily: brax's import is slow

        return AntGoal(backend=backend, **dict(spec.kwargs))
    if name.startswith("antmaze-"):
        from proto_brax.envs.antmaze import AntMaze  # imported lazily: brax's import is slow

        return AntMaze(maze=name.removeprefix("antmaze-"), backend=backend, **dict(spec.kwargs))
    if name in ("pen", "door", "hammer"):
        from proto_brax.envs.adroit import Adroit  # imported lazily: brax's import is slow

        return Adroit(name, backend=backend, **dict(spec.kwargs))
    if name.endswith("-v5"):
        from proto_brax.envs.gym_v5 import GymV5  # imported lazily: brax's import is slow

        return GymV5(name.removesuffix("-v5"), backend=backend, **dict(spec.kwargs))
    from brax import envs as brax_envs  # imported lazily: brax's import is slow

    return brax_envs.get_environment(name, backend=backend, **dict(spec.kwargs))



# One XLA thread (XLA's CPU client otherwise runs an Eigen pool and intra-op threads): one such process per core does
# more updates per second in total than one multi-threaded process on the 2-core machine (FACTS.md), and the MJX speed
# checks compare against native MuJoCo's one thread.
SINGLE_THREAD_XLA_FLAGS = ("--xla_cpu_multi_thread_eigen=false", "intra_op_parallelism_threads=1")


def _with_xla_flags(flags: str | None, *extra: str) -> str:
    """``flags`` (default: $XLA_FLAGS) with each of ``extra`` appended unless already present."""
    flags = os.environ.get("XLA_FLAGS", "") if flags is None else flags
    for flag in extra:
        flags = flags if flag in flags else f"{flags} {flag}".strip()
    return flags


def mjx_xla_flags(flags: str | None = None) -> str:
    """XLA_FLAGS with the CPU scheduler fix MJX needs (FACTS.md: batched MJX hangs on CPU without it).

    Pure: returns the new value for the caller (an entry point, before jax initializes) to set.
    """
    return _with_xla_flags(flags, "--xla_cpu_enable_concurrency_optimized_scheduler=false")


def single_thread_xla_flags(flags: str | None = None) -> str:
    """XLA_FLAGS plus ``SINGLE_THREAD_XLA_FLAGS`` (one process per core). Pure, as mjx_xla_flags."""
    return _with_xla_flags(flags, *SINGLE_THREAD_XLA_FLAGS)


def single_thread_mjx_xla_flags(flags: str | None = None) -> str:
    """``mjx_xla_flags`` plus ``SINGLE_THREAD_XLA_FLAGS``: the setting of the MJX-vs-native MuJoCo speed checks (so a
    shared machine's load hits both sides alike). Pure, as mjx_xla_flags."""
    return mjx_xla_flags(single_thread_xla_flags(flags))


# Widest vector extension first: the one XLA's CPU code generator targets (/proc/cpuinfo flag names; arm: Features).
_VECTOR_ISAS = ("avx512f", "avx2", "avx", "sse4_2", "sve2", "sve", "asimd")


def host_cpu(cpuinfo: str | None = None) -> str:
    """The CPU XLA compiles for, e.g. ``"AMD EPYC, x86_64 avx512f"``: model name, architecture, widest vector ISA.

    Why it is recorded: XLA generates code for the host CPU, and the same program rounds differently on another CPU.
    Measured: ant-random (10⁶ rows, one XLA thread) built on an AVX-512 AMD EPYC gave 27070 episodes (content
    83a9917a…) where two earlier machines (FACTS.md's kind: AVX2) both gave 27004 (71b80997…); capping XLA at AVX2 there
    (``--xla_cpu_max_isa=AVX2``) gave a third build (26722 episodes, 2cd6e7d4…). ``cpuinfo`` defaults to
    /proc/cpuinfo's text (absent off Linux: the model is then ``platform.processor()``)."""
    import platform

    if cpuinfo is None:
        try:
            with open("/proc/cpuinfo") as f:
                cpuinfo = f.read()
        except OSError:
            cpuinfo = ""
    fields: dict[str, str] = {}
    for line in cpuinfo.splitlines():  # the first processor's block is enough: the cores of one host match
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    model = fields.get("model name") or platform.processor()
    flags = set((fields.get("flags") or fields.get("Features") or "").split())
    isa = next((i for i in _VECTOR_ISAS if i in flags), "")
    return ", ".join(p for p in (model, f"{platform.machine()} {isa}".strip()) if p)


def machine_info() -> dict:
    """The header a benchmark records about where it ran (import after XLA_FLAGS is set: it initializes jax)."""
    import platform

    import jax
    import mujoco

    return {"python": platform.python_version(), "cpus": os.cpu_count(), "cpu": host_cpu(), "jax": jax.__version__,
            "mujoco": mujoco.__version__, "xla_flags": os.environ.get("XLA_FLAGS", ""),
            "xla_pool_threads": os.environ.get("NPROC"),  # $NPROC (grid.size_cpu_pool); None: XLA's default
            "loadavg_start": os.getloadavg()}


def reward_transform(name: str, dataset=None, scale: float | None = None, shift: float | None = None
                     ) -> tuple[float, float]:
    """(scale, shift) of the training-time rewards r' = scale · r + shift for env ``name`` (see ``EnvSpec``): the
    given values, else the env's rule. "return-range" envs take their scale from ``dataset`` (1 without offline
    data: online-only runs train on raw rewards)."""
    from proto_brax.data.dataset import return_range_scale

    spec = get_spec(name)
    if scale is None:
        scale = 1.0 if spec.reward_scale_rule == "none" or dataset is None else return_range_scale(dataset)
    return float(scale), float(spec.reward_shift if shift is None else shift)


def normalized_score(name: str, returns):
    """D4RL-style normalized score ``100 (R - R_random) / (R_expert - R_random)``; NaN where no reference exists."""
    spec = get_spec(name)
    if spec.ref_random is None or spec.ref_expert is None:
        return jnp.full_like(jnp.asarray(returns, jnp.float32), jnp.nan)
    return 100.0 * (jnp.asarray(returns) - spec.ref_random) / (spec.ref_expert - spec.ref_random)


@struct.dataclass
class EnvState:
    """Brax state plus our own episode bookkeeping."""

    brax_state: State
    t: jax.Array  # steps taken in the current episode
    episode_return: jax.Array


def env_reset(env: Env, key: jax.Array) -> EnvState:
    s = env.reset(key)
    return EnvState(brax_state=s, t=jnp.zeros((), jnp.int32), episode_return=jnp.zeros(()))


def env_step(
    env: Env, episode_length: int, state: EnvState, action: jax.Array, key: jax.Array
) -> tuple[EnvState, Transition, jax.Array, jax.Array]:
    """Step one env, auto-resetting at the end of an episode.

    Returns ``(state', transition, episode_done, finished_return)``; ``finished_return`` is the return of the
    episode that just ended (meaningful only where ``episode_done``).
    """
    nxt = env.step(state.brax_state, action)
    t = state.t + 1
    terminal = nxt.done.astype(jnp.float32)
    timeout = jnp.logical_and(t >= episode_length, terminal == 0).astype(jnp.float32)
    done = jnp.maximum(terminal, timeout)
    ret = state.episode_return + nxt.reward
    transition = Transition(
        observations=state.brax_state.obs,
        actions=action,
        rewards=nxt.reward,
        next_observations=nxt.obs,
        terminals=terminal,
        timeouts=timeout,
    )
    fresh = env.reset(key)
    brax_state = jax.tree.map(lambda a, b: jnp.where(done > 0, a, b), fresh, nxt)
    new = EnvState(brax_state=brax_state, t=jnp.where(done > 0, 0, t), episode_return=jnp.where(done > 0, 0.0, ret))
    return new, transition, done, ret
