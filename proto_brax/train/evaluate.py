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
    k_reset, k_run = jax.random.split(key)
    s = jax.vmap(env.reset)(jax.random.split(k_reset, episodes))

    def body(carry, k):
        s, ret, alive = carry
        s = jax.vmap(env.step)(s, policy(s.obs, k))
        ret = ret + jnp.where(alive, s.reward, 0.0)  # where, not multiply: a finished episode may hold NaNs
        return (s, ret, jnp.logical_and(alive, s.done == 0)), None

    init = (s, jnp.zeros(episodes), jnp.ones(episodes, bool))
    (_, ret, _), _ = lax.scan(body, init, jax.random.split(k_run, horizon))
    return ret
