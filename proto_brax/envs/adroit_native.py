"""An Adroit task on native MuJoCo, stepped from Python: the same capsule model, reset, observation, reward, success
and D4RL termination as the MJX env (``proto_brax.envs.adroit``), at native speed (gymnasium-robotics' loop, ~2,000
env steps/s here against MJX's ~100-150). Data generation need not be one jitted program: the Adroit experts train on
it (``proto_brax.data.native_behavior``), then the sweeps finetune on the MJX env with the same dynamics up to the
cross-check's error (``benchmarks/adroit_check.py``)."""

from __future__ import annotations

import jax
import mujoco
import numpy as np

from proto_brax import envs
from proto_brax.envs import adroit


class NativeAdroit:
    """``reset(key) -> obs`` and ``step(action) -> (obs, reward, terminal, success)``, numpy in and out.

    Each episode draws its layout row with the MJX env's own ``adroit.sample_layout`` (the same distribution from the
    same key) and writes it into the model, as gymnasium-robotics' ``reset_model`` does; the physics starts at
    ``qpos0`` with zero velocity. ``terminal`` is D4RL's pen drop (with ``d4rl_reward``, as the registered envs) or a
    non-finite state; the time limit is the caller's (``envs.get_spec(task).episode_length``).
    """

    def __init__(self, task: str, d4rl_reward: bool | None = None, cylinders: str = "capsule"):
        spec = envs.get_spec(task)
        self.task = task
        self.d4rl_reward = dict(spec.kwargs).get("d4rl_reward", False) if d4rl_reward is None else d4rl_reward
        # (the MJX-only contact bounds are ignored natively); cylinders: adroit.adroit_xml's stand-in for them
        self.model = adroit.load_capsule_model(task, cylinders=cylinders)
        self.data = mujoco.MjData(self.model)
        self.ids = adroit.task_ids(task, self.model)
        field, body = adroit.LAYOUT[task]
        self._row = getattr(self.model, field)[self.ids.body[body]]  # a view: writing it changes the model
        self._own = self._row.copy()
        self._act_mean = np.mean(self.model.actuator_ctrlrange, axis=1)
        self._act_rng = 0.5 * (self.model.actuator_ctrlrange[:, 1] - self.model.actuator_ctrlrange[:, 0])
        self.observation_size = adroit.get_task(task).obs_size
        self.action_size = adroit.get_task(task).act_size

    def reset(self, key: jax.Array) -> np.ndarray:
        self._row[:] = np.asarray(adroit.sample_layout(self.task, key, self._own))
        mujoco.mj_resetData(self.model, self.data)
        mujoco.mj_forward(self.model, self.data)
        return self._obs()

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool]:
        d = self.data
        d.ctrl[:] = self._act_mean + np.clip(action, -1.0, 1.0) * self._act_rng
        mujoco.mj_step(self.model, d, nstep=adroit.FRAME_SKIP)
        mujoco.mj_rnePostConstraint(self.model, d)  # as gymnasium's do_simulation
        if not (np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel))):
            return np.zeros(self.observation_size, np.float32), 0.0, True, False
        reward, success, dropped = adroit.reward_and_success(self.task, self.ids, d.qpos, d.qvel, d.xpos,
                                                             d.site_xpos, self.d4rl_reward, xp=np)
        return self._obs(), float(reward), bool(dropped) and self.d4rl_reward, bool(success)

    def _obs(self) -> np.ndarray:
        d = self.data
        return adroit.observation(self.task, self.ids, d.qpos, d.qvel, d.xpos, d.xquat, d.site_xpos, d.sensordata,
                                  xp=np).astype(np.float32)
