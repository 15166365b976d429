"""Gymnasium's MuJoCo v5 locomotion (``Hopper-v5``, ``Walker2d-v5``, ``HalfCheetah-v5``, ``Ant-v5``) on MJX.

The field's offline data (D4RL, Minari ``mujoco/*``) comes from these dynamics, so an agent pretrained on it can only
be finetuned online with matching physics and rewards on these envs, not on Brax's own hopper etc. What is reproduced,
and from where (``gymnasium/envs/mujoco/{hopper,walker2d,half_cheetah,ant}_v5.py`` and ``mujoco_env.py``, gymnasium
1.4.0, the package installed here):

* **Model**: the package's own XML (``assets/{hopper,walker2d_v5,half_cheetah,ant}.xml``), loaded by
  ``mujoco.MjModel.from_xml_path`` exactly as ``MujocoEnv`` does, then ``mjx.put_model`` (float32). Nothing is
  edited: all four need only plane / sphere / capsule colliders, which MJX has.
* **Step** (``MujocoEnv.do_simulation``): ``ctrl = action`` (unclipped; the physics clamps it to ``ctrlrange``, in MJX
  as in MuJoCo), ``frame_skip`` calls of ``mjx.step`` (= ``mj_step``: forward, then the XML's integrator: RK4 for
  hopper, walker2d and ant, Euler for halfcheetah), then ``mjx.rne_postconstraint`` (= ``mj_rnePostConstraint``,
  which gymnasium calls after every step for ``cfrc_ext``; only ant reads it, so only ant pays for it). As in
  MuJoCo, body positions after ``mj_step`` are those of the last forward pass (before the last integration); ant's
  forward velocity is measured on them (``data.body(1).xpos``), exactly as gymnasium does, and ours does the same.
* **Observation** (``_get_obs``, ``exclude_current_positions_from_observation=True``): hopper and walker2d
  ``qpos[1:] ++ clip(qvel, ±10)`` (11, 17); halfcheetah ``qpos[1:] ++ qvel`` (17); ant
  ``qpos[2:] ++ qvel ++ clip(cfrc_ext[1:], ±1).flatten()`` (13 + 14 + 78 = 105: v5 includes the contact forces by
  default). At reset gymnasium's ``cfrc_ext`` is zero (``mj_resetData`` then ``mj_forward``, which does not compute
  it), so ant's first observation ends in 78 zeros; ours too.
* **Reward** ``forward_reward_weight · Δx / dt + healthy_reward · healthy − ctrl_cost_weight · ‖a‖² −
  contact_cost_weight · ‖clip(cfrc_ext, ±1)‖²`` (the last term ant only, over all bodies), with ``Δx`` of ``qpos[0]``
  (ant: the torso's ``xpos[0]``); halfcheetah has no healthy reward. Weights: hopper / walker2d 1, 1, 1e-3;
  halfcheetah 1, –, 0.1; ant 1, 1, 0.5, 5e-4.
* **Health and termination** (``is_healthy``, ``terminate_when_unhealthy=True``): hopper
  ``all(|state_vector()[2:]| < 100)`` and ``0.7 < z`` and ``|angle| < 0.2``; walker2d ``0.8 < z < 2`` and
  ``|angle| < 1``; ant ``isfinite(state_vector())`` and ``0.2 ≤ z ≤ 1``; halfcheetah never terminates. The time limit
  (1000 steps for all four, gymnasium's ``max_episode_steps``) is the registry's (``proto_brax/envs/__init__.py``).
* **Reset** (``reset_model``): ``qpos = init_qpos + U(±c)``; ``qvel = init_qvel + U(±c)`` (hopper, walker2d) or
  ``init_qvel + c · N(0, 1)`` (halfcheetah, ant); ``c = reset_noise_scale`` = 5e-3 (hopper, walker2d), 0.1
  (halfcheetah, ant); ``init_qpos = qpos0`` of the model, ``init_qvel = 0``. Then ``mj_forward`` (``mjx.forward``).

**Deviations**: MJX solves in float32 (native MuJoCo float64), so trajectories from one state agree closely until
contacts amplify the difference (``tests/test_gym_v5.py`` measures for how long, ``benchmarks/gym_v5_check.py`` that
return statistics still agree). ``done`` is also 1 when the physics state stops being finite, with a zeroed
observation and reward (as ``antmaze.py``): gymnasium's ant and hopper terminate then too, its halfcheetah would
carry NaNs on. Every constructor argument of gymnasium's v5 envs that changes dynamics or rewards can be overridden
by keyword (``TaskSpec`` fields), e.g. ``GymV5("ant", include_cfrc_ext_in_observation=False)`` gives the 27-dim
observation; ``solver_iterations`` / ``ls_iterations`` cap MJX's Newton solver (default: the XML's 100 / 50; on
hopper, 4 / 8 changed neither the trajectory nor the speed, so the defaults stay).

**Measured** (``benchmarks/results/gym_v5_check.json``, 2026-12-06, the 2-core CPU shared with other jobs, load
average 5-10, so speeds are ±50%; ``tests/test_gym_v5.py`` for the fixed-seed windows):

* *Formulas and model*: every array field of our ``MjModel`` and its physics options equal gymnasium's; on the states
  gymnasium's own env steps through, our observation, reward terms, health and forward velocity equal its values
  exactly in numpy (within 2e-5 in float32 jnp); reset draws pass per-coordinate two-sample KS tests against 1000
  gymnasium resets; the reset observation matches (1e-6).
* *Lockstep* (same state, same random actions, float32 MJX vs float64 MuJoCo; 4 starts x 100 steps; max over starts):
  hopper |Δqpos| 9e-8 after 1 step, 5e-7 after 10, 2e-6 after 50, never above 1e-3 in 100 steps; walker2d 2e-7,
  4e-6, 3e-5, never above 1e-3; both terminate on the same step in every run. halfcheetah 3e-7 after 1 step, 9e-4
  after 10, then float32 chaos: above 1e-3 from step 13-35, above 0.1 from step 37-64 — in float64 MJX the same run
  stays within 2e-10 for 40 steps (the slow test), so the env is MuJoCo's and only the precision differs. ant 2e-6
  after 1 step but above 1e-3 from step 3-6 and 0.1 from step 7-22, *also in float64* (3.5e-7 after 1 step, 0.04
  after 10): MJX 3.17's contacts differ from MuJoCo 4.0's here (``antmaze.py`` notes the plane-capsule friction
  pyramid's orientation; not isolated further), so ant trajectories are statistically, not pointwise, the same.
* *Return statistics* of the uniform random policy, 64 episodes each, ours vs gymnasium (mean ± s.e.): hopper
  18.8 ± 2.6 vs 16.8 ± 2.1 (z 0.58); walker2d 1.46 ± 0.71 vs 1.35 ± 0.87 (z 0.10); halfcheetah −297.8 ± 9.4 vs
  −283.5 ± 9.9 (z −1.05); ant −57.2 ± 12.4 vs −35.8 ± 7.9 (z −1.46). All four differences lie within their 95%
  CIs, but ant's random episodes last longer on MJX (mean 166 vs 108 steps; they end when the torso leaves
  0.2 <= z <= 1, which the contact difference above moves), a sign its dynamics differ beyond what 64 returns show.
* *Speed* (env steps/s after compile, ``lax.scan``; batch 1 / batch 64 all envs together): hopper 107 / 137 (Brax
  generalized 698 / 5189), walker2d 195 / 103 (Brax generalized 957 / 4088), halfcheetah 871 / 683 (Brax
  positional 770 / 2488), ant 91 / 103 (Brax generalized 1878 / 4902); native gymnasium, one env: 2.3k / 7.8k /
  18k / 2.4k. RK4 (hopper, walker2d, ant) costs four
  forward passes per substep and 4-5 substeps per step; MJX gains nothing from batching on this CPU. At batch 1 the
  env step is 1.1 ms (halfcheetah) to 5-11 ms (hopper, walker2d, ant) beside ~5.1 ms for one SAC update, i.e. 18%
  to 50-68% of an online step: cheap for halfcheetah, not for the RK4 walkers on this CPU (a GPU is where MJX pays).
"""

from __future__ import annotations

import dataclasses
import os

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from brax.envs.base import Env, State
from mujoco import mjx


@dataclasses.dataclass(frozen=True)
class TaskSpec:
    """One v5 env: its gymnasium id and XML, and the constructor defaults of its ``__init__`` (gymnasium 1.4.0)."""

    gym_id: str
    xml_file: str
    frame_skip: int
    forward_reward_weight: float = 1.0
    ctrl_cost_weight: float = 1e-3
    healthy_reward: float = 1.0  # 0 for halfcheetah (it has none)
    terminate_when_unhealthy: bool = True
    healthy_z_range: tuple[float, float] = (-np.inf, np.inf)
    healthy_angle_range: tuple[float, float] = (-np.inf, np.inf)
    healthy_state_range: tuple[float, float] = (-np.inf, np.inf)  # hopper's bound on state_vector()[2:]
    reset_noise_scale: float = 5e-3
    qvel_noise: str = "uniform"  # "uniform": U(±c) (hopper, walker2d); "normal": c · N(0, 1) (halfcheetah, ant)
    skipped_qpos: int = 1  # exclude_current_positions_from_observation: x (2-D walkers) or x, y (ant)
    clip_qvel: float | None = None  # hopper and walker2d clip the observed velocities to ±10
    contact_cost_weight: float = 0.0  # ant
    contact_force_range: tuple[float, float] = (-1.0, 1.0)  # ant
    include_cfrc_ext_in_observation: bool = False  # ant: True in v5
    main_body: int = 0  # ant: forward velocity from xpos[main_body]; 0 = from qpos[0] (the 2-D walkers)


TASKS: dict[str, TaskSpec] = {
    "hopper": TaskSpec("Hopper-v5", "hopper.xml", frame_skip=4, healthy_z_range=(0.7, np.inf),
                       healthy_angle_range=(-0.2, 0.2), healthy_state_range=(-100.0, 100.0), clip_qvel=10.0),
    "walker2d": TaskSpec("Walker2d-v5", "walker2d_v5.xml", frame_skip=4, healthy_z_range=(0.8, 2.0),
                         healthy_angle_range=(-1.0, 1.0), clip_qvel=10.0),
    "halfcheetah": TaskSpec("HalfCheetah-v5", "half_cheetah.xml", frame_skip=5, ctrl_cost_weight=0.1,
                            healthy_reward=0.0, terminate_when_unhealthy=False, reset_noise_scale=0.1,
                            qvel_noise="normal"),
    "ant": TaskSpec("Ant-v5", "ant.xml", frame_skip=5, ctrl_cost_weight=0.5, healthy_z_range=(0.2, 1.0),
                    reset_noise_scale=0.1, qvel_noise="normal", skipped_qpos=2, contact_cost_weight=5e-4,
                    include_cfrc_ext_in_observation=True, main_body=1),
}


def get_task(task: str, **overrides) -> TaskSpec:
    if task not in TASKS:
        raise ValueError(f"Unknown v5 task {task!r}: choose one of {sorted(TASKS)}.")
    return dataclasses.replace(TASKS[task], **overrides)


def xml_path(task: str) -> str:
    """Path of the XML gymnasium's v5 env loads (inside the installed gymnasium package)."""
    import gymnasium

    return os.path.join(os.path.dirname(gymnasium.__file__), "envs", "mujoco", "assets", get_task(task).xml_file)


def load_model(task: str) -> mujoco.MjModel:
    """The native MuJoCo model, loaded as ``MujocoEnv._initialize_simulation`` does."""
    return mujoco.MjModel.from_xml_path(xml_path(task))


# ------------------------------------------------------------------------------------------------------------------
# gymnasium's formulas on any MuJoCo-like data; ``xp`` is ``jnp`` (the jitted env) or ``np`` (tests, checks)
# ------------------------------------------------------------------------------------------------------------------


def observation(spec: TaskSpec, qpos, qvel, cfrc_ext, xp=jnp):
    """``_get_obs`` of gymnasium's v5 env."""
    velocity = qvel if spec.clip_qvel is None else xp.clip(qvel, -spec.clip_qvel, spec.clip_qvel)
    parts = [qpos[spec.skipped_qpos:], velocity]
    if spec.include_cfrc_ext_in_observation:
        parts.append(xp.clip(cfrc_ext[1:], *spec.contact_force_range).reshape(-1))
    return xp.concatenate(parts)


def is_healthy(spec: TaskSpec, qpos, qvel, xp=jnp):
    """``is_healthy`` of gymnasium's v5 env (strict bounds for hopper / walker2d, inclusive z for ant, as there)."""
    if spec.main_body:  # ant: finite state and min_z <= z <= max_z
        state = xp.concatenate([qpos, qvel])
        z = qpos[2]
        return xp.all(xp.isfinite(state)) & (spec.healthy_z_range[0] <= z) & (z <= spec.healthy_z_range[1])
    z, angle = qpos[1], qpos[2]
    state = xp.concatenate([qpos, qvel])[2:]
    lo, hi = spec.healthy_state_range
    return (xp.all((lo < state) & (state < hi)) & (spec.healthy_z_range[0] < z) & (z < spec.healthy_z_range[1])
            & (spec.healthy_angle_range[0] < angle) & (angle < spec.healthy_angle_range[1]))


def reward_terms(spec: TaskSpec, x_velocity, action, healthy, cfrc_ext, xp=jnp) -> dict:
    """gymnasium's ``_get_rew``: the reward and its terms (``reward_info`` names)."""
    forward = spec.forward_reward_weight * x_velocity
    survive = spec.healthy_reward * healthy
    ctrl = spec.ctrl_cost_weight * xp.sum(xp.square(action))
    contact = spec.contact_cost_weight * xp.sum(xp.square(xp.clip(cfrc_ext, *spec.contact_force_range)))
    return {"reward": forward + survive - ctrl - contact, "reward_forward": forward, "reward_ctrl": -ctrl,
            "reward_survive": survive, "reward_contact": -contact}


def x_position(spec: TaskSpec, qpos, xpos):
    """What gymnasium differences for the forward velocity: ``qpos[0]``, or ant's ``data.body(1).xpos[0]``."""
    return xpos[spec.main_body, 0] if spec.main_body else qpos[0]


class GymV5(Env):
    """One of gymnasium's v5 locomotion envs (``"hopper"``, ``"walker2d"``, ``"halfcheetah"``, ``"ant"``) on MJX.

    ``state.pipeline_state`` is the ``mjx.Data``; ``state.metrics`` holds gymnasium's ``x_velocity`` and reward terms.
    Keyword arguments override ``TaskSpec`` fields (gymnasium's constructor arguments); ``solver_iterations`` and
    ``ls_iterations`` set MJX's solver caps (module docstring).
    """

    def __init__(self, task: str = "hopper", backend: str = "mjx", solver_iterations: int | None = None,
                 ls_iterations: int | None = None, **overrides):
        if backend != "mjx":
            raise ValueError(f"The gymnasium v5 envs run on the mjx backend only, not {backend!r}.")
        self.task = task
        self.spec = get_task(task, **overrides)
        self.mj_model = load_model(task)
        if solver_iterations is not None:
            self.mj_model.opt.iterations = int(solver_iterations)
        if ls_iterations is not None:
            self.mj_model.opt.ls_iterations = int(ls_iterations)
        self.mjx_model = mjx.put_model(self.mj_model)
        self.init_qpos = np.array(self.mj_model.qpos0)
        self.init_qvel = np.zeros(self.mj_model.nv)
        self.dt = float(self.mj_model.opt.timestep) * self.spec.frame_skip

    def reset(self, rng: jax.Array) -> State:
        """``reset_model``: the initial state with gymnasium's reset noise."""
        return self.reset_to(*self.sample_initial_state(rng))

    def sample_initial_state(self, rng: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``(qpos, qvel)`` as ``reset_model`` draws them: ``init + U(±c)``, velocities ``U(±c)`` or ``c · N(0, 1)``."""
        key_qpos, key_qvel = jax.random.split(rng)
        c = self.spec.reset_noise_scale
        nq, nv = self.mj_model.nq, self.mj_model.nv
        qpos = jnp.asarray(self.init_qpos, float) + jax.random.uniform(key_qpos, (nq,), minval=-c, maxval=c)
        if self.spec.qvel_noise == "uniform":
            noise = jax.random.uniform(key_qvel, (nv,), minval=-c, maxval=c)
        else:
            noise = c * jax.random.normal(key_qvel, (nv,))
        return qpos, jnp.asarray(self.init_qvel, float) + noise

    def reset_to(self, qpos: jax.Array, qvel: jax.Array) -> State:
        """An episode from a given ``(qpos, qvel)`` (``set_state``: tests and checks start both sides alike)."""
        qpos, qvel = jnp.asarray(qpos, float), jnp.asarray(qvel, float)
        data = mjx.forward(self.mjx_model, mjx.make_data(self.mjx_model).replace(qpos=qpos, qvel=qvel))
        # MJX's forward writes the free joint's quaternion back normalized; MuJoCo's mj_forward leaves qpos as set,
        # so gymnasium's first ant observation holds the noisy, unnormalized quaternion: observe the qpos as given.
        # (The dynamics are the same: MuJoCo normalizes in kinematics and after integrating, MJX before.)
        obs = observation(self.spec, qpos, data.qvel, data.cfrc_ext)
        zero = jnp.zeros(())
        metrics = {"x_velocity": zero, **{k: zero for k in reward_terms(self.spec, zero, zero, zero, zero)}}
        del metrics["reward"]
        return State(pipeline_state=data, obs=obs, reward=zero, done=zero, metrics=metrics, info={})

    def physics(self, data: mjx.Data, action: jax.Array) -> mjx.Data:
        """``do_simulation``: ctrl = action, ``frame_skip`` MuJoCo steps, then ``mj_rnePostConstraint`` (ant)."""
        data = data.replace(ctrl=action)
        data = jax.lax.fori_loop(0, self.spec.frame_skip, lambda _, d: mjx.step(self.mjx_model, d), data)
        if self.spec.include_cfrc_ext_in_observation or self.spec.contact_cost_weight:
            data = mjx.rne_postconstraint(self.mjx_model, data)
        return data

    def step(self, state: State, action: jax.Array) -> State:
        spec, before = self.spec, state.pipeline_state
        data = self.physics(before, action)
        x_velocity = (x_position(spec, data.qpos, data.xpos) - x_position(spec, before.qpos, before.xpos)) / self.dt
        healthy = is_healthy(spec, data.qpos, data.qvel)
        terms = reward_terms(spec, x_velocity, action, healthy.astype(jnp.float32), data.cfrc_ext)
        finite = jnp.all(jnp.isfinite(data.qpos)) & jnp.all(jnp.isfinite(data.qvel))
        terminated = (~healthy) if spec.terminate_when_unhealthy else jnp.zeros((), bool)
        done = (terminated | ~finite).astype(jnp.float32)
        obs = jnp.where(finite, observation(spec, data.qpos, data.qvel, data.cfrc_ext), 0.0)
        reward = jnp.where(finite, terms.pop("reward"), 0.0)
        metrics = {"x_velocity": x_velocity, **terms}
        return state.replace(pipeline_state=data, obs=obs, reward=reward, done=done, metrics=metrics)

    @property
    def observation_size(self) -> int:
        s = self.spec
        size = self.mj_model.nq - s.skipped_qpos + self.mj_model.nv
        return size + (6 * (self.mj_model.nbody - 1) if s.include_cfrc_ext_in_observation else 0)

    @property
    def action_size(self) -> int:
        return self.mj_model.nu

    @property
    def backend(self) -> str:
        return "mjx"


# ------------------------------------------------------------------------------------------------------------------
# Cross-check against gymnasium's own env (tests/test_gym_v5.py, benchmarks/gym_v5_check.py)
# ------------------------------------------------------------------------------------------------------------------


def gymnasium_env(task: str, **overrides):
    """gymnasium's own v5 env (unwrapped: no time limit, no order enforcing), with the same overrides."""
    import gymnasium as gym

    spec = get_task(task)
    return gym.make(spec.gym_id, **overrides).unwrapped


def lockstep(env: GymV5, step, native, actions: np.ndarray) -> dict[str, np.ndarray]:
    """Run ``env`` (with jitted ``step``) and gymnasium's ``native`` env side by side from ``native``'s current state
    on the same ``actions`` (T, act); both keep stepping past a termination (the physics is defined there).

    Returns per-step arrays: ``obs_err`` (max |Δobs|), ``qpos_err``, ``reward_err`` (|Δr|), and ``done`` /
    ``native_done`` (termination flags)."""
    state = env.reset_to(native.data.qpos.copy(), native.data.qvel.copy())
    out = {k: [] for k in ("obs_err", "qpos_err", "reward_err", "done", "native_done")}
    for action in actions:
        obs, reward, terminated, _, _ = native.step(np.asarray(action, np.float64))
        state = step(state, jnp.asarray(action, float))
        out["obs_err"].append(np.max(np.abs(np.asarray(state.obs, np.float64) - obs)))
        out["qpos_err"].append(np.max(np.abs(np.asarray(state.pipeline_state.qpos, np.float64) - native.data.qpos)))
        out["reward_err"].append(abs(float(state.reward) - reward))
        out["done"].append(bool(state.done))
        out["native_done"].append(bool(terminated))
    return {k: np.asarray(v) for k, v in out.items()}


class NativeGymV5:
    """Gymnasium's own v5 env behind ``adroit_native.NativeAdroit``'s interface, for the host-loop trainer
    (``data.native_behavior``): ``reset(key) -> obs`` (gymnasium's reset noise, seeded from the key),
    ``step(action) -> (obs, reward, terminal, success)`` with gymnasium's termination and no success rule; the time
    limit is the caller's (1000 steps, as the registered env's)."""

    def __init__(self, name: str):
        self.task = name
        self.env = gymnasium_env(name.removesuffix("-v5"))
        self.observation_size = int(self.env.observation_space.shape[0])
        self.action_size = int(self.env.action_space.shape[0])

    def reset(self, key: jax.Array) -> np.ndarray:
        obs, _ = self.env.reset(seed=int(jax.random.randint(key, (), 0, 2**31 - 1)))
        return np.asarray(obs, np.float32)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool]:
        obs, reward, terminated, _, _ = self.env.step(np.asarray(action, np.float64))
        return np.asarray(obs, np.float32), float(reward), bool(terminated), False
