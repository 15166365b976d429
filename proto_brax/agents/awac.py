"""AWAC: advantage-weighted actor-critic (Nair, Gupta, Dalal, Levine, 2020), finetuned online from a pretrained actor.

Policy evaluation is an off-policy TD backup with the current policy's next action (AWAC Eq. 3, no entropy term);
policy improvement is advantage-weighted maximum likelihood of buffer actions (AWAC Eq. 13):
    π ← argmax E_{(s,a)~B}[log π(a|s) · exp(A(s, a) / λ)],  A(s, a) = Q(s, a) − Q(s, a_π),  a_π ~ π(·|s).
Weights are clipped to [0, awr_weight_max] and λ = 1 as in CORL's AWAC (``awac_lambda`` 1.0, max weight 100).
The prior data stays in the buffer (the suite's "union" sampling).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jax import lax

from proto_brax.agents import sac
from proto_brax.agents.common import apply_grads, polyak
from proto_brax.agents.insample import weighted_log_likelihood
from proto_brax.agents.learner import Learner, OnlineAlgorithm
from proto_brax.config import FinetuneConfig, HParams, positive
from proto_brax.data.dataset import Transition
from proto_brax.networks import Networks, sample_tanh_gaussian


@struct.dataclass
class AWACHParams(HParams):
    """AWAC's own traced hyper-parameters (CORL's defaults)."""

    awac_lambda: jax.Array = 1.0  # temperature λ of the weight exp(A / λ)
    awr_weight_max: jax.Array = 100.0  # weights are clipped to [0, awr_weight_max]

    @classmethod
    def check(cls, v: dict[str, np.ndarray]) -> None:
        super().check(v)
        positive("awac_lambda", "awr_weight_max", v=v)


def critic_loss(critic, learner: Learner, batch: Transition, key: jax.Array, hp: AWACHParams, nets: Networks,
                cfg: FinetuneConfig):
    """Mean over members and batch of (Q_i(s, a) − y)², y = r + γ (1 − d) min_j Q̄_j(s′, a′), a′ ~ π(·|s′)."""
    mean, log_std = nets.actor.apply(learner.actor, batch.next_observations)
    a_next = sample_tanh_gaussian(key, mean, log_std)[0]
    q_next = sac.reduce_q(nets.critic.apply(learner.critic_target, batch.next_observations, a_next),
                          cfg.clipped_double_q)
    target = lax.stop_gradient(batch.rewards + hp.gamma * (1.0 - batch.terminals) * q_next)
    q = nets.critic.apply(critic, batch.observations, batch.actions)
    loss = jnp.mean(jnp.square(q - target))
    return loss, {"critic_loss": loss, "q_mean": jnp.mean(q), "q_max": jnp.max(q), "target_mean": jnp.mean(target)}


def advantage_weights(critic, actor, batch: Transition, key: jax.Array, hp: AWACHParams, nets: Networks,
                      cfg: FinetuneConfig) -> jax.Array:
    """min(exp((Q(s, a) − Q(s, a_π)) / λ), w_max) with a_π ~ π(·|s) (one sample, as CORL)."""
    mean, log_std = nets.actor.apply(actor, batch.observations)
    a_pi = sample_tanh_gaussian(key, mean, log_std)[0]
    q_data = sac.reduce_q(nets.critic.apply(critic, batch.observations, batch.actions), cfg.clipped_double_q)
    v = sac.reduce_q(nets.critic.apply(critic, batch.observations, a_pi), cfg.clipped_double_q)
    return jnp.minimum(jnp.exp((q_data - v) / hp.awac_lambda), hp.awr_weight_max)


def update(learner: Learner, batch: Transition, key: jax.Array, alpha: jax.Array, hp: AWACHParams, nets: Networks,
           cfg: FinetuneConfig, step: jax.Array) -> tuple[Learner, dict]:
    """Critic step, then the weighted-likelihood actor step against the new critic, then the target Polyak."""
    del alpha, step
    k_critic, k_adv = jax.random.split(key)
    (_, c_info), g = jax.value_and_grad(critic_loss, has_aux=True)(learner.critic, learner, batch, k_critic, hp,
                                                                    nets, cfg)
    critic, critic_opt = apply_grads(g, learner.critic_opt, learner.critic)
    w = lax.stop_gradient(advantage_weights(critic, learner.actor, batch, k_adv, hp, nets, cfg))
    (_, a_info), g = jax.value_and_grad(weighted_log_likelihood, has_aux=True)(learner.actor, nets, batch, w)
    actor, actor_opt = apply_grads(g, learner.actor_opt, learner.actor)
    learner = learner.replace(actor=actor, critic=critic, actor_opt=actor_opt, critic_opt=critic_opt,
                              critic_target=polyak(critic, learner.critic_target, hp.target_tau))
    return learner, {**c_info, **a_info, "actor_updates": jnp.ones(())}


ONLINE = OnlineAlgorithm(update=update, act=sac.act, deviation=sac.deviation, hparams=AWACHParams)
