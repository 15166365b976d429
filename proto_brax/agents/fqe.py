"""FQE: fitted Q evaluation of a fixed policy, giving the Q₀ that PROTO+BC finetunes from (Le et al., ICML 2019).

Q_i(s, a) ← r + γ (1 − d) min_j Q̄_j(s′, a′), a′ ~ π(·|s′). The backup uses the same clipped double-Q the online
critic uses, so Q₀ starts on the scale the SAC/PROTO backup will keep; there is no entropy term (π is evaluated, not
improved).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from proto_brax.agents.bc import bc_update
from proto_brax.agents.common import apply_grads, polyak
from proto_brax.agents.insample import OfflineHParams, OfflineState
from proto_brax.data.dataset import Transition
from proto_brax.networks import Networks, sample_tanh_gaussian


def fqe_loss(critic, critic_target, actor, nets: Networks, batch: Transition, key: jax.Array, gamma: jax.Array):
    """Mean over ensemble and batch of (Q_i(s, a) − [r + γ (1 − d) min_j Q̄_j(s′, a′)])², a′ ~ π(·|s′)."""
    mean, log_std = nets.actor.apply(actor, batch.next_observations)
    a_next, _, _ = sample_tanh_gaussian(key, mean, log_std)
    q_next = jnp.min(nets.critic.apply(critic_target, batch.next_observations, a_next), axis=0)
    target = lax.stop_gradient(batch.rewards + gamma * (1.0 - batch.terminals) * q_next)
    q = nets.critic.apply(critic, batch.observations, batch.actions)
    loss = jnp.mean(jnp.square(q - target))
    return loss, {"critic_loss": loss, "q_mean": jnp.mean(q)}


def fqe_update(state: OfflineState, batch: Transition, key: jax.Array, nets: Networks, hp: OfflineHParams):
    """One FQE step for the policy ``state.actor`` (unchanged)."""
    (_, info), g = jax.value_and_grad(fqe_loss, has_aux=True)(
        state.critic, state.critic_target, state.actor, nets, batch, key, hp.gamma
    )
    critic, critic_opt = apply_grads(g, state.critic_opt, state.critic)
    return state.replace(critic=critic, critic_opt=critic_opt,
                         critic_target=polyak(critic, state.critic_target, hp.target_tau)), info


def bc_fqe_update(state: OfflineState, batch: Transition, key: jax.Array, nets: Networks, hp: OfflineHParams):
    """A BC step on the actor, then an FQE step evaluating the updated actor (FQE tracks BC as it converges)."""
    actor, actor_opt, bc_info = bc_update(state.actor, state.actor_opt, nets, batch)
    state = state.replace(actor=actor, actor_opt=actor_opt)
    state, info = fqe_update(state, batch, key, nets, hp)
    return state, {**bc_info, **info}
