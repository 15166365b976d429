"""Learner state shared by the online actor-critic algorithms, the pretrained bundle type, the optimizer factory and
the interface every online algorithm implements (``OnlineAlgorithm``)."""

from __future__ import annotations

import dataclasses
from typing import Callable

import jax
import jax.numpy as jnp
import optax
from flax import struct

from proto_brax.agents.common import adam
from proto_brax.config import HParams
from proto_brax.networks import Networks


@struct.dataclass
class Pretrained:
    """What finetuning starts from: π₀ (actor params), optionally Q₀ (critic-ensemble params) and V₀ (IQL, PEX)."""

    actor: dict
    critic: dict | None = None
    value: dict | None = None
    log_alpha_sac: jax.Array | None = None  # CQL / Cal-QL bundles: the pretrained SAC temperature
    # The critic's pretraining state, carried into finetuning with ``Fidelity.carry_critic_state`` (official code).
    critic_target: dict | None = None
    critic_opt: optax.OptState | None = None


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
    value: dict | None = None  # IQL / PEX: state value V(s)
    value_opt: optax.OptState | None = None
    extra: dict | None = None  # a method's own state (Off2On: density-ratio net and replay priorities)


@dataclasses.dataclass(frozen=True)
class OnlineAlgorithm:
    """What the online loop needs from an algorithm module (each module defines one as ``ONLINE``).

    ``update(learner, batch, key, alpha, hp, nets, cfg, step) -> (learner, metrics)``: one gradient step; metrics
    include ``actor_updates`` (1 where the actor changed). ``act(nets, learner, obs, key, hp, deterministic)``: the
    behaviour (or, deterministic, the evaluation) action. ``deviation(nets, actor, other, obs, key)``: a scalar drift
    diagnostic between two actors. The flags shape the learner built by ``init_learner``.
    """

    update: Callable
    act: Callable
    deviation: Callable
    temperature: bool = False  # SAC's auto-tuned entropy temperature α_sac
    target_actor: bool = False  # a Polyak target actor (TD3)
    value: bool = False  # a state-value network V (IQL, PEX), restored from the bundle when it has one
    fresh_actor: bool = False  # the trained actor starts from a random init; π₀ stays in ``pi0`` (PEX)
    mc_returns: bool = False  # batches carry Monte-Carlo returns-to-go (Cal-QL's calibration bound)
    # Optional hooks: ``init(key, nets, cfg, hp, obs_size, act_size, pretrained, dataset) -> Learner`` replaces
    # ``init_learner``; ``sample(key, learner, buffer, dataset, cfg) -> batch`` replaces the replay's sampling (the
    # batch is then whatever ``update`` expects).
    init: Callable | None = None
    sample: Callable | None = None
    deterministic: bool = False  # a deterministic actor π(s) (TD3) instead of a Gaussian's (mean, log σ)
    policies: tuple[str, ...] = ("tanh_gaussian",)  # the actor distributions (NetworkConfig.policy) it implements
    # ``configure(cfg) -> OnlineAlgorithm``: the agent specialized to a static configuration (TD3: its exploration
    # noise clip), called once by ``make_finetune``.
    configure: Callable | None = None
    # Its traced hyper-parameters: config.HParams, or the subclass its module defines with its own fields (the
    # names a sweep's --hp and --grid accept for it).
    hparams: type[HParams] = HParams


def init_learner(
    key: jax.Array, nets: Networks, algo: OnlineAlgorithm, hp: HParams, obs_size: int, act_size: int,
    pretrained: Pretrained | None, carry_critic_state: bool = False,
) -> Learner:
    """Fresh learner: π₀, Q₀ (and V₀) from ``pretrained`` where given, random otherwise; π̄ = π₀.

    ``carry_critic_state``: the critic's Adam state and target critic come from ``pretrained`` too (its learning rate
    set to ``hp.lr_critic``); otherwise a fresh Adam, and the target is a copy of the critic."""
    k_actor, k_critic = jax.random.split(key)
    k_value, k_fresh = jax.random.fold_in(key, 1), jax.random.fold_in(key, 2)  # SAC/TD3 inits stay as before
    obs, act = jnp.zeros((1, obs_size)), jnp.zeros((1, act_size))
    pi0 = pretrained.actor if pretrained is not None else nets.actor.init(k_actor, obs)
    actor = nets.actor.init(k_fresh, obs) if algo.fresh_actor else pi0
    if pretrained is not None and pretrained.critic is not None:
        critic = pretrained.critic
    else:
        critic = nets.critic.init(k_critic, obs, act)
    value = None
    if algo.value:
        value = pretrained.value if pretrained is not None and pretrained.value is not None else nets.value.init(
            k_value, obs)
    critic_target, critic_opt = critic, adam(hp.lr_critic).init(critic)
    if carry_critic_state:
        if pretrained is None or pretrained.critic_opt is None or pretrained.critic_target is None:
            raise ValueError("carry_critic_state needs a bundle with the critic's optimizer state and target critic "
                             "(Pretrained.critic_opt / critic_target); pass them, or turn carry_critic_state off.")
        critic_target = pretrained.critic_target
        opt = pretrained.critic_opt
        critic_opt = opt._replace(hyperparams={**opt.hyperparams, "learning_rate": jnp.asarray(hp.lr_critic,
                                                                                                jnp.float32)})
    log_alpha = None
    if algo.temperature:
        has = pretrained is not None and pretrained.log_alpha_sac is not None
        log_alpha = pretrained.log_alpha_sac if has else jnp.log(hp.alpha_sac_init)
    return Learner(
        actor=actor,
        critic=critic,
        critic_target=critic_target,
        pibar=pi0,
        pi0=pi0,
        actor_opt=adam(hp.lr_actor).init(actor),
        critic_opt=critic_opt,
        actor_target=actor if algo.target_actor else None,
        log_alpha_sac=log_alpha,
        alpha_opt=adam(hp.lr_alpha).init(log_alpha) if algo.temperature else None,
        value=value,
        value_opt=adam(hp.lr_critic).init(value) if algo.value else None,
    )
