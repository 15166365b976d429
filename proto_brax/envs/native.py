"""The native-MuJoCo twins of registered envs, stepped from Python: for data and experts, never for sweeps (those stay
one jitted program on MJX)."""

from __future__ import annotations

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
