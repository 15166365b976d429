"""PROTO-TD3: TD3 with the iterative MSE penalty towards π̄ (PROTO paper, appendix).

Actor loss E[−λ Q₁(s, π(s)) + α ‖π(s) − π̄(s)‖²] with λ = β / mean|Q₁| (stop-gradient, as TD3+BC normalizes);
target-policy smoothing, clipped double-Q and a delayed actor as in TD3. With ``value_reg_backup`` the critic target
also subtracts α ‖π(s′) − π̄(s′)‖² of the *current* actor π, the paper's backup (the TD3 analogue of PROTO-SAC's KL
term, Eq. 3). The target actor and π̄ start at π₀ and, at the default τ = target_tau, receive the same Polyak update:
a penalty on the target actor's action would be ‖clip(ε)‖², smoothing noise only (the bug fixed in issue 35).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
from flax import struct
from jax import lax

from proto_brax.agents.common import apply_grads, polyak
from proto_brax.agents.learner import Learner, OnlineAlgorithm
from proto_brax.agents.proto import mse_penalty
from proto_brax.agents.sac import target_q
from proto_brax.config import FinetuneConfig, HParams
from proto_brax.data.dataset import Transition
from proto_brax.networks import Networks


@struct.dataclass
class TD3HParams(HParams):
    """PROTO-TD3's own traced hyper-parameters (paper appendix; TD3's smoothing and exploration noise)."""

    beta: jax.Array = 4.0  # λ = β / mean|Q| (paper: 4)
    policy_noise: jax.Array = 0.2  # target-policy smoothing noise
    noise_clip: jax.Array = 0.5
    expl_noise: jax.Array = 0.1  # exploration noise σ


def critic_loss(
    critic, learner: Learner, batch: Transition, key: jax.Array, alpha: jax.Array, hp: TD3HParams,
    nets: Networks, cfg: FinetuneConfig,
):
    """y = r + γ (1 − d) [Q̄(s′, a′) − α ‖π(s′) − π̄(s′)‖²], a′ = clip(π_targ(s′) + clip(ε, ±c), ±1), ε ~ N(0, σ²).

    The penalty is the current actor's distance to π̄ at s′ (paper, appendix), not the smoothed target action's.
    ``Fidelity.td3_backup='official'`` is the official code's target instead:
    y = r + γ (1 − d) [Q̄(s′, π_targ(s′)) − α · mean_{batch, dims} (π(s′) + clip(ε, ±c) − π̄(s′))²].
    """
    s2 = batch.next_observations
    a_targ = nets.actor.apply(learner.actor_target, s2)
    noise = jnp.clip(hp.policy_noise * jax.random.normal(key, a_targ.shape), -hp.noise_clip, hp.noise_clip)
    official = cfg.fidelity.td3_backup == "official"
    a_next = a_targ if official else jnp.clip(a_targ + noise, -1.0, 1.0)
    v_next = target_q(nets.critic.apply(learner.critic_target, s2, a_next), cfg, jax.random.fold_in(key, 1))
    if cfg.regularizer and cfg.value_reg_backup:
        a_pi, a_bar = nets.actor.apply(learner.actor, s2), nets.actor.apply(learner.pibar, s2)
        if official:
            v_next = v_next - alpha * jnp.mean(jnp.square(a_pi + noise - a_bar))
        else:
            v_next = v_next - alpha * mse_penalty(a_pi, a_bar, cfg.fidelity.td3_penalty)
    target = lax.stop_gradient(batch.rewards + hp.gamma * (1.0 - batch.terminals) * v_next)
    q = nets.critic.apply(critic, batch.observations, batch.actions)
    loss = jnp.mean(jnp.square(q - target))
    return loss, {"critic_loss": loss, "q_mean": jnp.mean(q), "q_max": jnp.max(q), "target_mean": jnp.mean(target)}


def actor_loss(
    actor, critic, learner: Learner, obs: jax.Array, alpha: jax.Array, hp: TD3HParams, nets: Networks,
    cfg: FinetuneConfig,
):
    """E[−λ Q_k(s, π(s)) + α ‖π(s) − π̄(s)‖²], λ = β / mean|Q_k(s, π(s))| (stop-gradient); k = 1 (TD3+BC) or 2
    (``Fidelity.td3_actor_critic``, the official code); the penalty summed or averaged over action dimensions."""
    a = nets.actor.apply(actor, obs)
    q = nets.critic.apply(critic, obs, a)[cfg.fidelity.td3_actor_critic]
    lam = lax.stop_gradient(hp.beta / jnp.mean(jnp.abs(q)))
    if cfg.regularizer:
        penalty = mse_penalty(a, lax.stop_gradient(nets.actor.apply(learner.pibar, obs)), cfg.fidelity.td3_penalty)
    else:
        penalty = jnp.zeros_like(q)
    loss = jnp.mean(-lam * q + alpha * penalty)
    return loss, {"actor_loss": loss, "kl_pibar": jnp.mean(penalty), "lambda": lam}


def update(
    learner: Learner, batch: Transition, key: jax.Array, alpha: jax.Array, hp: TD3HParams,
    nets: Networks, cfg: FinetuneConfig, step: jax.Array,
) -> tuple[Learner, dict]:
    """Critic every call; actor, target actor, target critic and π̄ every ``policy_delay`` calls.

    ``step`` must be unbatched (the same for every run of a grid) so that ``lax.cond`` stays a real branch under vmap
    instead of computing both sides.
    """
    (_, c_info), grads = jax.value_and_grad(critic_loss, has_aux=True)(
        learner.critic, learner, batch, key, alpha, hp, nets, cfg
    )
    critic, critic_opt = apply_grads(grads, learner.critic_opt, learner.critic)
    learner = learner.replace(critic=critic, critic_opt=critic_opt)

    def actor_step(learner):
        (_, a_info), grads = jax.value_and_grad(actor_loss, has_aux=True)(
            learner.actor, learner.critic, learner, batch.observations, alpha, hp, nets, cfg
        )
        actor, actor_opt = apply_grads(grads, learner.actor_opt, learner.actor)
        learner = learner.replace(
            actor=actor,
            actor_opt=actor_opt,
            actor_target=polyak(actor, learner.actor_target, hp.target_tau),
            critic_target=polyak(learner.critic, learner.critic_target, hp.target_tau),
            pibar=polyak(actor, learner.pibar, hp.tau) if cfg.regularizer else learner.pibar,
        )
        return learner, {**a_info, "actor_updates": jnp.ones(())}

    def skip(learner):
        zero = jnp.zeros(())
        return learner, {"actor_loss": zero, "kl_pibar": zero, "lambda": zero, "actor_updates": zero}

    learner, a_info = lax.cond(step % cfg.policy_delay == 0, actor_step, skip, learner)
    return learner, {**c_info, **a_info}


def act(nets: Networks, learner: Learner, obs: jax.Array, key: jax.Array, hp: TD3HParams | None,
        deterministic: bool, noise_clip: float | None = None) -> jax.Array:
    """π(s) plus Gaussian exploration noise N(0, σ²) (clipped to ±c with ``Fidelity.td3_expl_noise_clip``, the
    official code's 0.5), the sum clipped to the action box; π(s) alone for evaluation."""
    a = nets.actor.apply(learner.actor, obs)
    if deterministic:
        return a
    noise = hp.expl_noise * jax.random.normal(key, a.shape)
    if noise_clip is not None:  # static: the default program has no clip at all (bit-identical to before)
        noise = jnp.clip(noise, -noise_clip, noise_clip)
    return jnp.clip(a + noise, -1.0, 1.0)


def deviation(nets: Networks, actor, other, obs: jax.Array, key: jax.Array) -> jax.Array:
    """Mean ‖π(s) − other(s)‖² on a batch of states (a diagnostic: π vs π̄ and π vs π₀)."""
    del key
    return jnp.mean(mse_penalty(nets.actor.apply(actor, obs), nets.actor.apply(other, obs)))


def configure(cfg: FinetuneConfig) -> OnlineAlgorithm:
    """TD3 with the exploration noise clip of ``cfg.fidelity`` (a static choice: no clip leaves no op in the
    program)."""
    clip = cfg.fidelity.td3_expl_noise_clip
    return ONLINE if clip is None else dataclasses.replace(ONLINE, act=functools.partial(act, noise_clip=clip))


ONLINE = OnlineAlgorithm(update=update, act=act, deviation=deviation, target_actor=True, deterministic=True,
                         hparams=TD3HParams,
                         policies=("tanh_gaussian", "gaussian"), configure=configure)
