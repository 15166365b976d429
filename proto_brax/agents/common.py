"""Pieces every actor-critic agent shares: the optimizer with a traced learning rate, one gradient step, Polyak
averaging and SAC's entropy-temperature step (Haarnoja et al. 2018b, Eq. 18)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax
from jax import lax


def adam(learning_rate) -> optax.GradientTransformation:
    """Adam whose learning rate is a traced leaf of the optimizer state (so a grid can vary it).

    ``optax.inject_hyperparams`` reads numeric hyper-parameters from the state at update time, so the transformation
    used for ``update`` may be built with any placeholder value.
    """
    return optax.inject_hyperparams(optax.adam)(learning_rate=learning_rate)


def apply_grads(grads, opt_state, params):
    """One Adam step with the learning rate stored in ``opt_state``."""
    updates, opt_state = adam(0.0).update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state


def polyak(new, old, tau: jax.Array):
    """old ← τ·new + (1 − τ)·old. With τ = 0 the result equals ``old`` bit for bit (π̄ stays π₀: Frozen)."""
    return optax.incremental_update(new, old, tau)


def temperature_loss(log_alpha_sac: jax.Array, log_prob: jax.Array, target_entropy: jax.Array,
                     form: str = "log_alpha") -> jax.Array:
    """SAC's automatic entropy tuning: minimize log α_sac · (H(π) − H̄) with H(π) ≈ −log π(a|s) (stop-gradient).

    ``form='alpha'`` minimizes α_sac · (H − H̄) instead (the official PROTO code, as jaxrl's SAC, and RLPD): the same
    sign of the gradient in log α_sac, scaled by α_sac, so a small temperature moves more slowly.
    """
    scale = jnp.exp(log_alpha_sac) if form == "alpha" else log_alpha_sac
    return scale * jnp.mean(lax.stop_gradient(-log_prob) - target_entropy)


def temperature_step(log_alpha_sac: jax.Array, alpha_opt, log_prob: jax.Array, target_entropy: jax.Array,
                     form: str = "log_alpha"):
    """One Adam step of ``temperature_loss``: (log α_sac, its optimizer state, the loss)."""
    loss, grad = jax.value_and_grad(temperature_loss)(log_alpha_sac, log_prob, target_entropy, form)
    log_alpha_sac, alpha_opt = apply_grads(grad, alpha_opt, log_alpha_sac)
    return log_alpha_sac, alpha_opt, loss


def actor_critic_step(learner, critic_loss, actor_loss, target_entropy: jax.Array, target_tau: jax.Array,
                      form: str = "log_alpha"):
    """SAC's order of steps, shared by SAC, CQL / Cal-QL and Off2On: one Adam step of ``critic_loss(critic)``, one of
    ``actor_loss(actor, critic)`` against the *updated* critic (its aux holds ``log_prob``), the temperature step,
    and the target critic's Polyak step. Both losses return ``(loss, info)``. Returns (learner, critic info, actor
    info without ``log_prob``, temperature loss)."""
    (_, c_info), grads = jax.value_and_grad(critic_loss, has_aux=True)(learner.critic)
    critic, critic_opt = apply_grads(grads, learner.critic_opt, learner.critic)
    (_, a_info), grads = jax.value_and_grad(actor_loss, has_aux=True)(learner.actor, critic)
    actor, actor_opt = apply_grads(grads, learner.actor_opt, learner.actor)
    log_alpha_sac, alpha_opt, t_loss = temperature_step(learner.log_alpha_sac, learner.alpha_opt,
                                                        a_info.pop("log_prob"), target_entropy, form)
    learner = learner.replace(actor=actor, critic=critic, actor_opt=actor_opt, critic_opt=critic_opt,
                              critic_target=polyak(critic, learner.critic_target, target_tau),
                              log_alpha_sac=log_alpha_sac, alpha_opt=alpha_opt)
    return learner, c_info, a_info, t_loss
