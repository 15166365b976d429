"""PROTO-SAC: soft actor-critic with the iterative KL penalty towards π̄ (PROTO paper, Eq. 3–4).

With α = 0 (α₀ = 0: direct finetuning, or SAC from scratch from a random init) every PROTO term vanishes and the
losses are exactly SAC's; with τ = 0, π̄ stays π₀ (Frozen). One code path serves all of them.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jax import lax

from proto_brax.agents.common import actor_critic_step, polyak
from proto_brax.agents.learner import Learner, OnlineAlgorithm
from proto_brax.agents.proto import kl_penalty
from proto_brax.config import FinetuneConfig, HParams, positive
from proto_brax.data.dataset import Transition
from proto_brax.networks import Networks


@struct.dataclass
class SACHParams(HParams):
    """SAC's entropy temperature (PROTO's reference code when finetuning; SAC from scratch: ``SAC_SCRATCH_HP``)."""

    lr_alpha: jax.Array = 3e-4  # learning rate of SAC's entropy temperature
    alpha_sac_init: jax.Array = 0.01  # initial SAC entropy temperature (reference code: 0.01 when finetuning)
    target_entropy_scale: jax.Array = -0.5  # target entropy = scale × |A| (reference code: −|A|/2)

    @classmethod
    def check(cls, v: dict[str, np.ndarray]) -> None:
        super().check(v)
        positive("lr_alpha", "alpha_sac_init", v=v)


def reduce_q(q: jax.Array, clipped_double_q: bool) -> jax.Array:
    """Reduce the ensemble axis 0: min (clipped double-Q) or mean."""
    return jnp.min(q, axis=0) if clipped_double_q else jnp.mean(q, axis=0)


def target_q(q: jax.Array, cfg: FinetuneConfig, key: jax.Array) -> jax.Array:
    """The backup's reduction of the target ensemble [E, B]: min with clipped double-Q; without it the mean, or one
    member drawn at random per update (``Fidelity.unclipped_target='random'``, the official code's REDQ-style
    subsample of one)."""
    if cfg.clipped_double_q or cfg.fidelity.unclipped_target == "mean":
        return reduce_q(q, cfg.clipped_double_q)
    return q[jax.random.randint(key, (), 0, q.shape[0])]


def actor_q(q: jax.Array, cfg: FinetuneConfig) -> jax.Array:
    """The actor's reduction of the ensemble: the backup's (min or mean), or always the mean (official code)."""
    return jnp.mean(q, axis=0) if cfg.fidelity.actor_q == "mean" else reduce_q(q, cfg.clipped_double_q)


def critic_loss(
    critic, learner: Learner, batch: Transition, key: jax.Array, alpha: jax.Array, hp: SACHParams,
    nets: Networks, cfg: FinetuneConfig, pibar_next: tuple[jax.Array, jax.Array] | None = None,
):
    """Critic loss with the PROTO backup (Eq. 3).

    y = r + γ (1 − d) [Q̄(s′, a′) − α_sac log π(a′|s′) − α (log π(a′|s′) − log π̄(a′|s′))],  a′ ~ π(·|s′),
    where Q̄ is min (or mean, or a random member: ``target_q``) over the target ensemble. Without
    ``value_reg_backup`` (the paper's AntMaze and Adroit setting) the bracket is Q̄(s′, a′) alone: the reference
    code's ``entropy_backup=False`` drops SAC's entropy term together with the PROTO term. Loss = mean over ensemble
    members and batch of (Q_i(s, a) − y)². ``pibar_next``: π̄'s (mean, log σ) at s′ when already computed.
    """
    mean, log_std = nets.actor.apply(learner.actor, batch.next_observations)
    a_next, u_next, logp_next = nets.policy.sample(key, mean, log_std)
    # fold_in: the random member's key leaves the sample's key (and so every default run) unchanged.
    q_next = target_q(nets.critic.apply(learner.critic_target, batch.next_observations, a_next), cfg,
                      jax.random.fold_in(key, 1))
    v_next = q_next - jnp.exp(learner.log_alpha_sac) * logp_next if cfg.value_reg_backup else q_next
    if cfg.regularizer and cfg.value_reg_backup:
        mean_bar, log_std_bar = pibar_next or nets.actor.apply(learner.pibar, batch.next_observations)
        v_next = v_next - alpha * kl_penalty(u_next, mean, log_std, mean_bar, log_std_bar)
    target = lax.stop_gradient(batch.rewards + hp.gamma * (1.0 - batch.terminals) * v_next)
    q = nets.critic.apply(critic, batch.observations, batch.actions)
    loss = jnp.mean(jnp.square(q - target))
    return loss, {"critic_loss": loss, "q_mean": jnp.mean(q), "q_max": jnp.max(q), "target_mean": jnp.mean(target)}


def actor_loss(
    actor, critic, learner: Learner, obs: jax.Array, key: jax.Array, alpha: jax.Array,
    nets: Networks, cfg: FinetuneConfig, pibar_now: tuple[jax.Array, jax.Array] | None = None,
):
    """Actor loss with the PROTO penalty (Eq. 4): E[α_sac log π(a|s) + α (log π(a|s) − log π̄(a|s)) − Q(s, a)],
    Q the ensemble's min or mean (``actor_q``). ``pibar_now``: π̄'s (mean, log σ) at s when already computed."""
    mean, log_std = nets.actor.apply(actor, obs)
    a, u, logp = nets.policy.sample(key, mean, log_std)
    if cfg.regularizer:
        mean_bar, log_std_bar = pibar_now or nets.actor.apply(learner.pibar, obs)
        kl = kl_penalty(u, mean, log_std, lax.stop_gradient(mean_bar), lax.stop_gradient(log_std_bar))
    else:
        kl = jnp.zeros_like(logp)
    q = actor_q(nets.critic.apply(critic, obs, a), cfg)
    alpha_sac = lax.stop_gradient(jnp.exp(learner.log_alpha_sac))
    loss = jnp.mean(alpha_sac * logp + alpha * kl - q)
    return loss, {"actor_loss": loss, "entropy": -jnp.mean(logp), "kl_pibar": jnp.mean(kl), "log_prob": logp}


def update(
    learner: Learner, batch: Transition, key: jax.Array, alpha: jax.Array, hp: SACHParams,
    nets: Networks, cfg: FinetuneConfig, step: jax.Array,
) -> tuple[Learner, dict]:
    """One PROTO-SAC gradient step: critic, actor (against the new critic), temperature, target Q̄ and π̄ Polyak."""
    del step  # SAC updates every component every step
    k_critic, k_actor = jax.random.split(key)
    pibar_next = pibar_now = None
    if cfg.regularizer and cfg.value_reg_backup:
        # π̄ at s′ (backup) and at s (actor penalty) in one forward pass: π̄ changes only after both steps.
        n = batch.observations.shape[0]
        stats = nets.actor.apply(learner.pibar, jnp.concatenate([batch.next_observations, batch.observations]))
        pibar_next, pibar_now = tuple(x[:n] for x in stats), tuple(x[n:] for x in stats)
    learner, c_info, a_info, t_loss = actor_critic_step(
        learner, lambda critic: critic_loss(critic, learner, batch, k_critic, alpha, hp, nets, cfg, pibar_next),
        lambda actor, critic: actor_loss(actor, critic, learner, batch.observations, k_actor, alpha, nets, cfg,
                                         pibar_now),
        hp.target_entropy_scale * batch.actions.shape[-1], hp.target_tau, cfg.fidelity.temperature_loss)
    if cfg.regularizer:
        learner = learner.replace(pibar=polyak(learner.actor, learner.pibar, hp.tau))
    return learner, {**c_info, **a_info, "temperature_loss": t_loss, "alpha_sac": jnp.exp(learner.log_alpha_sac),
                     "actor_updates": jnp.ones(())}


def act(nets: Networks, learner: Learner, obs: jax.Array, key: jax.Array, hp: SACHParams | None,
        deterministic: bool) -> jax.Array:
    """a ~ π(·|s) (clipped to the action box for the env), or the mean action tanh(mean) for evaluation."""
    mean, log_std = nets.actor.apply(learner.actor, obs)
    if deterministic:
        return nets.policy.mode(mean)
    return nets.policy.to_env(nets.policy.sample(key, mean, log_std)[0])


def deviation(nets: Networks, actor, other, obs: jax.Array, key: jax.Array) -> jax.Array:
    """Monte-Carlo KL(π‖other) on a batch of states (a diagnostic: π‖π̄ and π‖π₀)."""
    mean, log_std = nets.actor.apply(actor, obs)
    mean_o, log_std_o = nets.actor.apply(other, obs)
    _, u, _ = nets.policy.sample(key, mean, log_std)
    return jnp.mean(kl_penalty(u, mean, log_std, mean_o, log_std_o))


ONLINE = OnlineAlgorithm(update=update, act=act, deviation=deviation, temperature=True, hparams=SACHParams,
                         policies=("tanh_gaussian", "gaussian"))
