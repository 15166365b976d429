"""The native-MuJoCo twins of registered envs, stepped from Python: for data and experts, never for sweeps (those stay
one jitted program on MJX)."""

from __future__ import annotations

from typing import Callable

import jax
import numpy as np

from proto_brax import envs
from proto_brax.envs.adroit_native import NativeAdroit
from proto_brax.envs.gym_v5 import NativeGymV5

NATIVE_ENVS = ("pen", "door", "hammer", "hopper-v5", "walker2d-v5", "halfcheetah-v5", "ant-v5")


def native_env(name: str) -> NativeAdroit | NativeGymV5:
    """Adroit on the MJX env's capsule model (``adroit_native.NativeAdroit``) or gymnasium's own v5 env
    (``gym_v5.NativeGymV5``). Interface: ``reset(key) -> obs``, ``step(action) -> (obs, reward, terminal, success)``,
    ``observation_size``, ``action_size``."""
    if name not in NATIVE_ENVS:
        raise ValueError(f"{name!r} has no native twin here: {', '.join(NATIVE_ENVS)} have.")
    return NativeGymV5(name) if name.endswith("-v5") else NativeAdroit(name)


def native_episodes(env: NativeAdroit | NativeGymV5, policy: Callable[[np.ndarray, jax.Array, int], np.ndarray],
                    keys: jax.Array) -> dict:
    """One episode per key (``reset(key)``), to the registered time limit or a termination, with ``policy(obs, key,
    t) -> action``: the returns, their mean, and D4RL's success rate (an episode succeeds on more than
    ``success_steps`` successful steps) where the task has one (Adroit; else None)."""
    spec = envs.get_spec(env.task)
    returns, successes = [], []
    for key in keys:
        obs, ret, steps_ok = env.reset(key), 0.0, 0
        for t in range(spec.episode_length):
            obs, reward, terminal, success = env.step(np.asarray(policy(obs, key, t)))
            ret, steps_ok = ret + reward, steps_ok + int(success)
            if terminal:
                break
        returns.append(ret)
        successes.append(spec.success_steps is not None and steps_ok > spec.success_steps)
    rate = float(np.mean(successes)) if spec.success_steps is not None else None
    return {"returns": returns, "return_mean": float(np.mean(returns)), "success_rate": rate}
