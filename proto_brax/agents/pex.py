"""PEX: policy expansion (Zhang, Xu, Yu, ICLR 2023), IQL-based as in its paper.

The policy set is {π₀, π}: π₀ is the offline IQL policy, kept frozen (``Learner.pi0``); π is a new policy learned
online from a random init (``Learner.actor``). At each state both propose an action — π₀ its deterministic action,
π a sample — and one is chosen with probability (PEX Eq. 4)
    P(i) = softmax_i(β_pex · Q(s, aᵢ)),  Q = min over the critic ensemble,  β_pex = ``pex_inv_temperature`` (10),
greedily (argmax, π's mean action) at evaluation. The critic and V continue from the IQL bundle with IQL's losses;
π is trained by IQL's advantage-weighted likelihood of the *composite* policy's chosen actions (PEX reference code).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from proto_brax.agents import iql, sac
from proto_brax.agents.learner import Learner, OnlineAlgorithm
from proto_brax.config import FinetuneConfig
from proto_brax.data.dataset import Transition
from proto_brax.networks import Networks, sample_tanh_gaussian


@struct.dataclass
class PEXHParams(iql.IQLHParams):
    """PEX's traced hyper-parameters: IQL's and the policy choice's inverse temperature."""

    pex_inv_temperature: jax.Array = 10.0  # P(choose πᵢ) ∝ exp(inv_temperature · Q(s, aᵢ)) (PEX code default)


def candidates(nets: Networks, learner: Learner, obs: jax.Array, key: jax.Array, deterministic: bool):
    """(a₀, a₁, Q [..., 2]): π₀'s deterministic action, π's sample (its tanh(mean) if deterministic), their Q."""
    a0 = jnp.tanh(nets.actor.apply(learner.pi0, obs)[0])
    mean, log_std = nets.actor.apply(learner.actor, obs)
    a1 = jnp.tanh(mean) if deterministic else sample_tanh_gaussian(key, mean, log_std)[0]
    q = jnp.stack([jnp.min(nets.critic.apply(learner.critic, obs, a), axis=0) for a in (a0, a1)], axis=-1)
    return a0, a1, q


def selection_logits(q: jax.Array, inv_temperature: jax.Array) -> jax.Array:
    """PEX Eq. 4: logits β_pex · Q(s, aᵢ) of the categorical choice between the policies."""
    return inv_temperature * q


def act(nets: Networks, learner: Learner, obs: jax.Array, key: jax.Array, hp: PEXHParams | None,
        deterministic: bool) -> jax.Array:
    k_pi, k_choice = jax.random.split(key)
    a0, a1, q = candidates(nets, learner, obs, k_pi, deterministic)
    if deterministic:
        choice = jnp.argmax(q, axis=-1)
    else:
        choice = jax.random.categorical(k_choice, selection_logits(q, hp.pex_inv_temperature), axis=-1)
    return jnp.where(choice[..., None] == 1, a1, a0)


def update(learner: Learner, batch: Transition, key: jax.Array, alpha: jax.Array, hp: PEXHParams, nets: Networks,
           cfg: FinetuneConfig, step: jax.Array) -> tuple[Learner, dict]:
    """IQL's V and Q steps on the batch; π imitates the composite policy's actions with weight exp(β (Q − V))."""
    del alpha, cfg, step
    chosen = act(nets, learner, batch.observations, key, hp, deterministic=False)
    state, info = iql.update(iql.offline_view(learner), batch, nets, iql.offline_hparams(hp), chosen)
    return iql.merge(learner, state), {**info, "actor_updates": jnp.ones(())}


ONLINE = OnlineAlgorithm(update=update, act=act, deviation=sac.deviation, value=True, fresh_actor=True,
                         hparams=PEXHParams)
