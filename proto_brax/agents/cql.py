"""CQL (Kumar et al., NeurIPS 2020) and Cal-QL (Nakamoto et al., NeurIPS 2023): SAC with a conservative critic.

Critic loss per ensemble member i (CQL(H), Eq. 4 of the CQL paper, with importance sampling as its reference code):
    TD_i + α_cql · E_s[ logsumexp_k(X_i(s)) − Q_i(s, a_data) ],
    X_i(s) = { Q_i(s, a_k^unif) − log 0.5^|A|,  Q̃_i(s, a_k^π(s)) − log π(a_k|s),  Q̃_i(s, a_k^π(s′)) − log π(a_k|s′) },
with N = ``cql_n_actions`` samples of each kind (all evaluated at s, actions stop-gradient). CQL: Q̃ = Q. Cal-QL
(Eq. 5 of its paper) calibrates the push-down with the behaviour policy's Monte-Carlo return: Q̃ = max(Q, G_MC(s)).
TD_i is the backup without the entropy term (``backup_entropy=False`` in both reference codes):
y = r + γ (1 − d) min_j Q̄_j(s′, a′), a′ ~ π(·|s′). The actor and SAC's temperature are trained as in SAC.
Reference values: α_cql 5 and policy learning rate 1e-4 (CQL's MuJoCo commands), 10 actions per kind, temperature 1;
Cal-QL mixes offline and online data 50/50 when finetuning.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jax import lax

from proto_brax.agents import awac, sac
from proto_brax.agents.common import actor_critic_step
from proto_brax.agents.insample import OfflineHParams, OfflineState
from proto_brax.agents.learner import Learner, OnlineAlgorithm
from proto_brax.config import FinetuneConfig
from proto_brax.data.dataset import Transition
from proto_brax.networks import Networks, sample_tanh_gaussian


@struct.dataclass
class CQLHParams(sac.SACHParams):
    """CQL's and Cal-QL's own traced hyper-parameter."""

    cql_alpha: jax.Array = 5.0  # conservative weight α_cql (CQL's MuJoCo min_q_weight)

    @classmethod
    def check(cls, v: dict[str, np.ndarray]) -> None:
        super().check(v)
        if np.any(v["cql_alpha"] < 0):
            raise ValueError(f"cql_alpha must be >= 0; got {v['cql_alpha']}.")


def conservative_penalty(critic, actor, batch: Transition, key: jax.Array, nets: Networks, n_actions: int,
                         calibrated: bool):
    """Mean over members of E_s[logsumexp_k X_i(s) − Q_i(s, a_data)] (see the module docstring); returns (value, info).
    """
    b, act_size = batch.actions.shape
    k_unif, k_cur, k_next = jax.random.split(key, 3)
    a_unif = jax.random.uniform(k_unif, (n_actions, b, act_size), minval=-1.0, maxval=1.0)

    def policy_samples(k, obs):
        mean, log_std = nets.actor.apply(actor, obs)
        keys = jax.random.split(k, n_actions)
        a, _, logp = jax.vmap(lambda kk: sample_tanh_gaussian(kk, mean, log_std))(keys)
        return lax.stop_gradient(a), lax.stop_gradient(logp)  # [N, B, A], [N, B]

    a_cur, logp_cur = policy_samples(k_cur, batch.observations)
    a_next, logp_next = policy_samples(k_next, batch.next_observations)
    q_at = jax.vmap(lambda a: nets.critic.apply(critic, batch.observations, a))  # [N, B, A] -> [N, members, B]
    q_unif, q_cur, q_next = q_at(a_unif), q_at(a_cur), q_at(a_next)
    info = {}
    if calibrated:
        bound = batch.mc_returns[None, None, :]
        info["cql_bound_rate"] = jnp.mean(jnp.concatenate([q_cur, q_next]) < bound)
        q_cur, q_next = jnp.maximum(q_cur, bound), jnp.maximum(q_next, bound)
    log_unif = act_size * math.log(0.5)  # density of the uniform proposal on [−1, 1]^|A|
    x = jnp.concatenate([q_unif - log_unif, q_cur - logp_cur[:, None], q_next - logp_next[:, None]])  # [3N, m, B]
    q_data = nets.critic.apply(critic, batch.observations, batch.actions)  # [m, B]
    gap = jax.nn.logsumexp(x, axis=0) - q_data
    penalty = jnp.mean(gap)
    return penalty, {**info, "cql_gap": penalty, "cql_q_unif": jnp.mean(q_unif), "cql_q_pi": jnp.mean(q_cur)}


def make_update(calibrated: bool):
    def update(learner: Learner, batch: Transition, key: jax.Array, alpha: jax.Array, hp: CQLHParams,
               nets: Networks, cfg: FinetuneConfig, step: jax.Array) -> tuple[Learner, dict]:
        """Conservative critic step, then SAC's actor and temperature steps, then the target Polyak."""
        del alpha, step
        k_td, k_cql, k_actor = jax.random.split(key, 3)

        def critic_loss(critic):
            td, info = awac.critic_loss(critic, learner, batch, k_td, hp, nets, cfg)
            penalty, p_info = conservative_penalty(critic, learner.actor, batch, k_cql, nets, cfg.cql_n_actions,
                                                   calibrated)
            return td + hp.cql_alpha * penalty, {**info, **p_info}

        learner, c_info, a_info, _ = actor_critic_step(
            learner, critic_loss,
            lambda actor, critic: sac.actor_loss(actor, critic, learner, batch.observations, k_actor, jnp.zeros(()),
                                                 nets, cfg),
            hp.target_entropy_scale * batch.actions.shape[-1], hp.target_tau)
        return learner, {**c_info, **a_info, "alpha_sac": jnp.exp(learner.log_alpha_sac),
                         "actor_updates": jnp.ones(())}

    return update


update_cql = make_update(calibrated=False)
update_calql = make_update(calibrated=True)

ONLINE_CQL = OnlineAlgorithm(update=update_cql, act=sac.act, deviation=sac.deviation, temperature=True,
                             hparams=CQLHParams)
ONLINE_CALQL = OnlineAlgorithm(update=update_calql, act=sac.act, deviation=sac.deviation, temperature=True,
                               hparams=CQLHParams,
                               mc_returns=True)


def offline_update(state: OfflineState, batch: Transition, key: jax.Array, nets: Networks, hp: OfflineHParams,
                   cfg: FinetuneConfig, calibrated: bool) -> tuple[OfflineState, dict]:
    """CQL / Cal-QL pretraining step on dataset batches: the online update on the bundle's fields."""
    learner = Learner(actor=state.actor, critic=state.critic, critic_target=state.critic_target, pibar=state.actor,
                      pi0=state.actor, actor_opt=state.actor_opt, critic_opt=state.critic_opt,
                      log_alpha_sac=state.log_alpha_sac, alpha_opt=state.alpha_opt)
    fhp = CQLHParams.create().replace(gamma=hp.gamma, target_tau=hp.target_tau, cql_alpha=hp.cql_alpha,
                                   target_entropy_scale=hp.target_entropy_scale)
    update = update_calql if calibrated else update_cql
    learner, info = update(learner, batch, key, jnp.zeros(()), fhp, nets, cfg, jnp.zeros((), jnp.int32))
    state = state.replace(actor=learner.actor, critic=learner.critic, critic_target=learner.critic_target,
                          actor_opt=learner.actor_opt, critic_opt=learner.critic_opt,
                          log_alpha_sac=learner.log_alpha_sac, alpha_opt=learner.alpha_opt)
    info.pop("actor_updates")
    return state, info
