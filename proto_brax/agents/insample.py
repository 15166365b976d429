"""The in-sample actor-critic update shared by EQL, SQL and IQL (they differ only in the value loss and the weight).

Each step (IVR / IQL reference order): fit V(s) to the target critic's Q(s, a) on dataset actions with the method's
value loss; extract the policy by weighted maximum likelihood of dataset actions, weight w(Q − V); fit Q(s, a) to
r + γ (1 − d) V(s′); Polyak-update the target critic. No action outside the dataset is ever queried.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
from flax import struct
from jax import lax

from proto_brax.agents.common import adam, apply_grads, polyak
from proto_brax.data.dataset import Transition
from proto_brax.networks import Networks


@struct.dataclass
class OfflineHParams:
    """Traced offline hyper-parameters (defaults: PROTO's EQL for MuJoCo, IQL's paper values; shared/FACTS.md)."""

    alpha: jax.Array = 2.0  # EQL/SQL value-regularization temperature (paper: 2.0 MuJoCo, 0.5 AntMaze)
    expectile: jax.Array = 0.7  # IQL expectile (MuJoCo)
    temperature: jax.Array = 3.0  # IQL AWR inverse temperature β (MuJoCo)
    eql_weight_scale: jax.Array = 10.0  # EQL extraction weight exp(scale · (Q − V) / α) (IVR's code; PROTO's code 1)
    eql_z_clip: jax.Array = 5.0  # EQL value loss: z = (Q − V)/α clipped at this value (IVR's code 5; PROTO's code 7)
    weight_max: jax.Array = 100.0  # extraction weights are clipped to [0, weight_max]
    gamma: jax.Array = 0.99
    target_tau: jax.Array = 5e-3
    lr_actor: jax.Array = 3e-4
    lr_critic: jax.Array = 3e-4
    lr_value: jax.Array = 3e-4
    # CQL / Cal-QL pretraining (proto_brax.agents.cql): CQL's MuJoCo values; SAC temperature as from scratch.
    cql_alpha: jax.Array = 5.0
    alpha_sac_init: jax.Array = 1.0
    target_entropy_scale: jax.Array = -1.0
    lr_alpha: jax.Array = 3e-4

    @classmethod
    def create(cls, **kwargs) -> "OfflineHParams":
        import dataclasses

        names = {f.name: f.default for f in dataclasses.fields(cls)}
        unknown = set(kwargs) - set(names)
        if unknown:
            raise ValueError(f"Unknown offline hyper-parameter(s) {sorted(unknown)}: valid are {sorted(names)}.")
        return cls(**{k: jnp.asarray(kwargs.get(k, v), jnp.float32) for k, v in names.items()})


@struct.dataclass
class OfflineState:
    actor: dict
    critic: dict
    critic_target: dict
    value: dict | None
    actor_opt: object
    critic_opt: object
    value_opt: object | None
    log_alpha_sac: jax.Array | None = None  # CQL / Cal-QL: SAC's entropy temperature
    alpha_opt: object | None = None


ValueLoss = Callable[[jax.Array, jax.Array, OfflineHParams], jax.Array]  # (q, v, hp) -> scalar
Weight = Callable[[jax.Array, jax.Array, OfflineHParams], jax.Array]  # (q, v, hp) -> [B] weights


def init_offline_state(key, nets: Networks, obs_size: int, act_size: int, hp: OfflineHParams,
                       with_value: bool = True, with_temperature: bool = False) -> OfflineState:
    k_a, k_c, k_v = jax.random.split(key, 3)
    obs, act = jnp.zeros((1, obs_size)), jnp.zeros((1, act_size))
    actor = nets.actor.init(k_a, obs)
    critic = nets.critic.init(k_c, obs, act)
    value = nets.value.init(k_v, obs) if with_value else None
    return OfflineState(
        actor=actor, critic=critic, critic_target=critic, value=value,
        actor_opt=adam(hp.lr_actor).init(actor), critic_opt=adam(hp.lr_critic).init(critic),
        value_opt=adam(hp.lr_value).init(value) if with_value else None,
        log_alpha_sac=jnp.log(hp.alpha_sac_init) if with_temperature else None,
        alpha_opt=adam(hp.lr_alpha).init(jnp.log(hp.alpha_sac_init)) if with_temperature else None,
    )


def weighted_log_likelihood(actor, nets: Networks, batch: Transition, weight: jax.Array):
    """−E[w · log π(a|s)] over dataset actions (w constant): weighted behaviour cloning / AWR extraction."""
    mean, log_std = nets.actor.apply(actor, batch.observations)
    logp = nets.policy.log_prob(batch.actions, mean, log_std)
    loss = -jnp.mean(weight * logp)
    return loss, {"actor_loss": loss, "weight_mean": jnp.mean(weight), "log_prob": jnp.mean(logp)}


def q_to_v_loss(critic, nets: Networks, value, batch: Transition, gamma: jax.Array):
    """Mean over the ensemble and batch of (Q_i(s, a) − [r + γ (1 − d) V(s′)])²."""
    target = lax.stop_gradient(batch.rewards + gamma * (1.0 - batch.terminals)
                               * nets.value.apply(value, batch.next_observations))
    q = nets.critic.apply(critic, batch.observations, batch.actions)
    loss = jnp.mean(jnp.square(q - target))
    return loss, {"critic_loss": loss, "q_mean": jnp.mean(q)}


def insample_update(state: OfflineState, batch: Transition, nets: Networks, hp: OfflineHParams,
                    value_loss: ValueLoss, weight: Weight, extract_actions: jax.Array | None = None,
                    ) -> tuple[OfflineState, dict]:
    """One step of V, π and Q (see the module docstring). ``extract_actions`` replaces the dataset actions as the
    targets of the weighted likelihood (PEX imitates its composite policy's actions); V and Q always use the batch."""
    q = jnp.min(nets.critic.apply(state.critic_target, batch.observations, batch.actions), axis=0)

    def v_loss(value):
        v = nets.value.apply(value, batch.observations)
        loss = value_loss(q, v, hp)
        return loss, {"value_loss": loss, "v_mean": jnp.mean(v), "adv_mean": jnp.mean(q - v)}

    (_, v_info), g = jax.value_and_grad(v_loss, has_aux=True)(state.value)
    value, value_opt = apply_grads(g, state.value_opt, state.value)

    target = batch
    if extract_actions is not None:
        target = batch.replace(actions=extract_actions)
        q = jnp.min(nets.critic.apply(state.critic_target, batch.observations, extract_actions), axis=0)
    w = lax.stop_gradient(weight(q, nets.value.apply(value, batch.observations), hp))
    (_, a_info), g = jax.value_and_grad(weighted_log_likelihood, has_aux=True)(state.actor, nets, target, w)
    actor, actor_opt = apply_grads(g, state.actor_opt, state.actor)

    (_, c_info), g = jax.value_and_grad(q_to_v_loss, has_aux=True)(state.critic, nets, value, batch, hp.gamma)
    critic, critic_opt = apply_grads(g, state.critic_opt, state.critic)

    state = state.replace(
        actor=actor, critic=critic, critic_target=polyak(critic, state.critic_target, hp.target_tau), value=value,
        actor_opt=actor_opt, critic_opt=critic_opt, value_opt=value_opt,
    )
    return state, {**v_info, **a_info, **c_info}
