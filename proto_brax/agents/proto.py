"""The PROTO term: iterative policy regularization towards π̄, a Polyak-averaged copy of the actor.

Li et al., "PROTO: Iterative Policy Regularized Offline-to-Online Reinforcement Learning", Eq. 3–4: the KL penalty
α·[log π(a|s) − log π̄(a|s)] enters both the critic target and the actor loss; π̄ ← τ π + (1 − τ) π̄ after each actor
update (π̄ = π₀ at the start; ``common.polyak``); α is annealed linearly. The TD3 variant (paper appendix) uses
α‖π(s) − π̄(s)‖².
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from proto_brax.networks import gaussian_log_prob


def alpha_schedule(alpha0: jax.Array, eta: jax.Array, horizon: jax.Array, alpha_min: jax.Array, t: jax.Array):
    """α_t = max(α₀ (1 − η t / N), α_min): linear annealing that reaches α_min at t = N (1 − α_min/α₀) / η."""
    return jnp.maximum(alpha0 * (1.0 - eta * t / horizon), alpha_min)


def kl_penalty(u: jax.Array, mean: jax.Array, log_std: jax.Array, mean_bar: jax.Array, log_std_bar: jax.Array):
    """Single-sample estimate log π(a|s) − log π̄(a|s) at a = tanh(u), u ~ N(mean, std).

    Both policies squash the same u with tanh, so the Jacobian term log|d tanh(u)/du| cancels exactly: the difference
    of the two Gaussian log-densities at u is the difference of the tanh-Gaussian log-densities at a, without arctanh.
    Gradients flow through u (reparameterization) and mean/log_std; π̄'s statistics are constants for the caller.
    """
    return gaussian_log_prob(u, mean, log_std) - gaussian_log_prob(u, mean_bar, log_std_bar)


def mse_penalty(action: jax.Array, action_bar: jax.Array, reduce: str = "sum") -> jax.Array:
    """‖π(s) − π̄(s)‖², summed over action dimensions (PROTO-TD3); ``reduce='mean'`` averages them instead (the
    official code's ``((a − a_k) ** 2).mean()``: the same penalty divided by |A|)."""
    sq = jnp.square(action - action_bar)
    return jnp.mean(sq, axis=-1) if reduce == "mean" else jnp.sum(sq, axis=-1)
