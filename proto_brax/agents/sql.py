"""SQL: sparse Q-learning, the IVR in-sample algorithm with the χ²-style (sparse) regularizer (Xu et al., ICLR 2023)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from proto_brax.agents.insample import OfflineHParams, insample_update


def value_loss(q: jax.Array, v: jax.Array, hp: OfflineHParams) -> jax.Array:
    """E[1(u > 0) · u² + V/α] with u = (Q − V)/(2α) + 1 (IVR's SQL objective, Xu et al. 2023, and its reference code;
    samples with u ≤ 0 get no weight). Before issue 35 this was u = (Q − V)/α + 1/2, which is IVR's loss at α/4 up to a
    factor: a silently different regularization strength."""
    u = (q - v) / (2.0 * hp.alpha) + 1.0
    return jnp.mean(jnp.where(u > 0, u**2, 0.0) + v / hp.alpha)


def weight(q: jax.Array, v: jax.Array, hp: OfflineHParams) -> jax.Array:
    """Policy-extraction weight clip(Q − V, 0, w_max) (IVR reference)."""
    return jnp.clip(q - v, 0.0, hp.weight_max)


def update(state, batch, nets, hp: OfflineHParams):
    return insample_update(state, batch, nets, hp, value_loss, weight)
