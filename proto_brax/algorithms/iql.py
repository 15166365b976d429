"""IQL: implicit Q-learning (Kostrikov, Nair, Levine, ICLR 2022): expectile value regression, AWR extraction."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from proto_brax.algorithms.insample import OfflineHParams, insample_update


def value_loss(q: jax.Array, v: jax.Array, hp: OfflineHParams) -> jax.Array:
    """Expectile regression E[|τ − 1(u < 0)| u²], u = Q − V (IQL Eq. 5; τ = 0.7 MuJoCo, 0.9 AntMaze)."""
    u = q - v
    return jnp.mean(jnp.abs(hp.expectile - (u < 0).astype(u.dtype)) * u**2)


def weight(q: jax.Array, v: jax.Array, hp: OfflineHParams) -> jax.Array:
    """AWR weight min(exp(β (Q − V)), w_max) (IQL Eq. 7; β = 3 MuJoCo, 10 AntMaze; w_max 100)."""
    return jnp.minimum(jnp.exp(hp.temperature * (q - v)), hp.weight_max)


def update(state, batch, nets, hp: OfflineHParams):
    return insample_update(state, batch, nets, hp, value_loss, weight)
