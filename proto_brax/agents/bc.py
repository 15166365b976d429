"""Behaviour cloning by maximum likelihood with the tanh-Gaussian actor."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from proto_brax.agents.common import apply_grads
from proto_brax.data.dataset import Transition
from proto_brax.networks import tanh_gaussian_log_prob


def bc_loss(actor, nets, batch: Transition):
    """−E_(s,a)~D[log π(a|s)], the log-density of the dataset action under the tanh-Gaussian (with its Jacobian)."""
    mean, log_std = nets.actor.apply(actor, batch.observations)
    loss = -jnp.mean(tanh_gaussian_log_prob(batch.actions, mean, log_std))
    return loss, {"bc_loss": loss, "mse": jnp.mean(jnp.square(jnp.tanh(mean) - batch.actions))}


def bc_update(actor, opt_state, nets, batch: Transition):
    (_, info), grads = jax.value_and_grad(bc_loss, has_aux=True)(actor, nets, batch)
    actor, opt_state = apply_grads(grads, opt_state, actor)
    return actor, opt_state, info
