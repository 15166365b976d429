"""RLPD (Ball, Smith, Kostrikov, Levine, ICML 2023, "Efficient Online Reinforcement Learning with Offline Data"):
SAC from a random init on symmetric 50/50 offline/online batches, LayerNorm critics, a large critic ensemble whose
backup takes the min over a random subset (REDQ's M), and a high update-to-data ratio. No pretraining, no π̄.

Per env step, as the reference code (ikostrikov/rlpd, ``SACLearner.update``): ``updates_per_step`` critic steps, each
on a fresh batch and each followed by the target's Polyak step, then one actor step and one temperature step on the
last batch, against the critics after all of them.

* Critic (RLPD Sec. 3, with SAC's entropy backup): y = r + γ (1 − d)[min_{j∈M} Q̄_j(s′, a′) − α_sac log π(a′|s′)],
  a′ ~ π(·|s′), M a subset of ``NUM_MIN_QS`` of the E target critics drawn without replacement per update;
  loss = mean over the E critics and the batch of (Q_i(s, a) − y)².
* Actor: E[α_sac log π(a|s) − (1/E) Σ_i Q_i(s, a)], a ~ π(·|s): the mean of all E critics, not a min.
* Temperature: α_sac · (H − H̄) (``common.temperature_loss`` form 'alpha', as the reference code), H̄ = −|A|/2,
  α_sac starts at 1.

The sweep method ``rlpd`` (``registry.METHODS``) sets E = 10, LayerNorm critics, UTD 20 and symmetric sampling.
Rewards stay raw (reward scale 1), as the reference code trains on D4RL locomotion.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from proto_brax.agents import sac
from proto_brax.agents.common import apply_grads, polyak, temperature_step
from proto_brax.agents.learner import Learner, OnlineAlgorithm
from proto_brax.config import FinetuneConfig
from proto_brax.data.dataset import Transition
from proto_brax.networks import Networks

NUM_MIN_QS = 2  # target critics in each backup's min (RLPD's and REDQ's M = 2)


def target_subset(key: jax.Array, num_qs: int) -> jax.Array:
    """Indices of the M target critics of one backup: distinct, uniformly drawn."""
    return jax.random.choice(key, num_qs, (min(NUM_MIN_QS, num_qs),), replace=False)


def critic_loss(critic, learner: Learner, batch: Transition, key: jax.Array, hp: sac.SACHParams, nets: Networks):
    """mean_{i, batch} (Q_i(s, a) − y)², y = r + γ (1 − d)[min_{j∈M} Q̄_j(s′, a′) − α_sac log π(a′|s′)]."""
    k_act, k_subset = jax.random.split(key)
    mean, log_std = nets.actor.apply(learner.actor, batch.next_observations)
    a_next, _, logp_next = nets.policy.sample(k_act, mean, log_std)
    idx = target_subset(k_subset, nets.critic.num)
    # Only the M drawn critics are evaluated: the ensemble module with M members on the sliced parameters.
    members = jax.tree.map(lambda p: p[idx], learner.critic_target)
    q_next = jnp.min(nets.critic.clone(num=idx.shape[0]).apply(members, batch.next_observations, a_next), axis=0)
    v_next = q_next - jnp.exp(learner.log_alpha_sac) * logp_next
    target = lax.stop_gradient(batch.rewards + hp.gamma * (1.0 - batch.terminals) * v_next)
    q = nets.critic.apply(critic, batch.observations, batch.actions)
    loss = jnp.mean(jnp.square(q - target))
    return loss, {"critic_loss": loss, "q_mean": jnp.mean(q), "q_max": jnp.max(q), "target_mean": jnp.mean(target)}


def actor_loss(actor, critic, learner: Learner, obs: jax.Array, key: jax.Array, nets: Networks):
    """E[α_sac log π(a|s) − mean_i Q_i(s, a)], a ~ π(·|s) reparameterized."""
    mean, log_std = nets.actor.apply(actor, obs)
    a, _, logp = nets.policy.sample(key, mean, log_std)
    q = jnp.mean(nets.critic.apply(critic, obs, a), axis=0)
    loss = jnp.mean(lax.stop_gradient(jnp.exp(learner.log_alpha_sac)) * logp - q)
    return loss, {"actor_loss": loss, "entropy": -jnp.mean(logp), "log_prob": logp}


def update(learner: Learner, batch: Transition, key: jax.Array, alpha: jax.Array, hp: sac.SACHParams, nets: Networks,
           cfg: FinetuneConfig, step: jax.Array) -> tuple[Learner, dict]:
    """One critic step and the target's Polyak step; on the last of an env step's ``updates_per_step`` updates also
    the actor and the temperature."""
    del alpha  # no PROTO term
    k_critic, k_actor = jax.random.split(key)
    (_, c_info), grads = jax.value_and_grad(critic_loss, has_aux=True)(learner.critic, learner, batch, k_critic, hp,
                                                                       nets)
    critic, critic_opt = apply_grads(grads, learner.critic_opt, learner.critic)
    learner = learner.replace(critic=critic, critic_opt=critic_opt,
                              critic_target=polyak(critic, learner.critic_target, hp.target_tau))

    def actor_step(lrn: Learner):
        (_, info), grads = jax.value_and_grad(actor_loss, has_aux=True)(lrn.actor, lrn.critic, lrn,
                                                                       batch.observations, k_actor, nets)
        actor, actor_opt = apply_grads(grads, lrn.actor_opt, lrn.actor)
        target_entropy = hp.target_entropy_scale * batch.actions.shape[-1]
        log_alpha, alpha_opt, _ = temperature_step(lrn.log_alpha_sac, lrn.alpha_opt, info.pop("log_prob"),
                                                   target_entropy, "alpha")
        lrn = lrn.replace(actor=actor, actor_opt=actor_opt, log_alpha_sac=log_alpha, alpha_opt=alpha_opt)
        return lrn, {**info, "actor_updates": jnp.ones(())}

    def critic_only(lrn: Learner):
        return lrn, {"actor_loss": jnp.zeros(()), "entropy": jnp.zeros(()), "actor_updates": jnp.zeros(())}

    last = (step + 1) % cfg.updates_per_step == 0
    learner, a_info = lax.cond(last, actor_step, critic_only, learner)
    return learner, {**c_info, **a_info, "alpha_sac": jnp.exp(learner.log_alpha_sac)}


ONLINE = OnlineAlgorithm(update=update, act=sac.act, deviation=sac.deviation, temperature=True,
                         hparams=sac.SACHParams)
