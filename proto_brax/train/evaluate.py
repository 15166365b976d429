"""Vectorized evaluation: many episodes side by side, each to termination or the time limit, inside jit."""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
from jax import lax


def run_episodes(
    env, horizon: int, policy: Callable[[jax.Array, jax.Array], jax.Array], key: jax.Array, episodes: int
) -> jax.Array:
    """Returns of ``episodes`` episodes; ``policy(obs [n, obs], key) -> actions [n, act]``."""
    return run_episodes_with_lengths(env, horizon, policy, key, episodes)[0]


def run_episodes_with_lengths(
    env, horizon: int, policy: Callable[[jax.Array, jax.Array], jax.Array], key: jax.Array, episodes: int
) -> tuple[jax.Array, jax.Array]:
    """(returns [episodes], lengths [episodes] int32): an episode's length is its steps up to and including the one
    that ended it (``horizon`` if none did) — on a goal task that terminates at the goal, the steps to the goal."""
    k_reset, k_run = jax.random.split(key)
    s = jax.vmap(env.reset)(jax.random.split(k_reset, episodes))

    def body(carry, k):
        s, ret, alive, length = carry
        s = jax.vmap(env.step)(s, policy(s.obs, k))
        ret = ret + jnp.where(alive, s.reward, 0.0)  # where, not multiply: a finished episode may hold NaNs
        length = length + alive.astype(jnp.int32)
        return (s, ret, jnp.logical_and(alive, s.done == 0), length), None

    init = (s, jnp.zeros(episodes), jnp.ones(episodes, bool), jnp.zeros(episodes, jnp.int32))
    (_, ret, _, length), _ = lax.scan(body, init, jax.random.split(k_run, horizon))
    return ret, length
