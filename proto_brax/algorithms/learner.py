"""Learner state shared by the actor-critic algorithms, the pretrained bundle type, and the optimizer factory."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax
from flax import struct

from proto_brax.config import FinetuneConfig, HParams
from proto_brax.networks import Networks


def adam(learning_rate) -> optax.GradientTransformation:
    """Adam whose learning rate is a traced leaf of the optimizer state (so a grid can vary it).

    ``optax.inject_hyperparams`` reads numeric hyper-parameters from the state at update time, so the transformation
    used for ``update`` may be built with any placeholder value.
    """
    return optax.inject_hyperparams(optax.adam)(learning_rate=learning_rate)


@struct.dataclass
class Pretrained:
    """What finetuning starts from: π₀ (actor params) and optionally Q₀ (critic-ensemble params)."""

    actor: dict
    critic: dict | None = None


@struct.dataclass
class Learner:
    actor: dict
    critic: dict
    critic_target: dict
    pibar: dict  # π̄: Polyak average of the actor, starts at π₀
    pi0: dict  # π₀, kept to measure how far finetuning drifts from it
    actor_opt: optax.OptState
    critic_opt: optax.OptState
    actor_target: dict | None = None  # TD3 only
    log_alpha_sac: jax.Array | None = None  # SAC only: entropy temperature
    alpha_opt: optax.OptState | None = None  # SAC only


def init_learner(
    key: jax.Array, nets: Networks, cfg: FinetuneConfig, hp: HParams, obs_size: int, act_size: int,
    pretrained: Pretrained | None,
) -> Learner:
    k_actor, k_critic = jax.random.split(key)
    obs, act = jnp.zeros((1, obs_size)), jnp.zeros((1, act_size))
    actor = pretrained.actor if pretrained is not None else nets.actor.init(k_actor, obs)
    if pretrained is not None and pretrained.critic is not None:
        critic = pretrained.critic
    else:
        critic = nets.critic.init(k_critic, obs, act)
    sac = cfg.algo == "sac"
    log_alpha = jnp.log(hp.alpha_sac_init) if sac else None
    return Learner(
        actor=actor,
        critic=critic,
        critic_target=critic,
        pibar=actor,
        pi0=actor,
        actor_opt=adam(hp.lr_actor).init(actor),
        critic_opt=adam(hp.lr_critic).init(critic),
        actor_target=None if sac else actor,
        log_alpha_sac=log_alpha,
        alpha_opt=adam(hp.lr_alpha).init(log_alpha) if sac else None,
    )


def apply_grads(grads, opt_state, params):
    """One Adam step with the learning rate stored in ``opt_state``."""
    updates, opt_state = adam(0.0).update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state
