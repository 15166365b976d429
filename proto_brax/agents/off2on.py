"""Off2On (Lee, Seo, Lee, Abbeel, Shin, CoRL 2021): balanced replay and a pessimistic Q-ensemble.

* **Pessimistic Q-ensemble.** N CQL agents are pretrained independently (a CQL bundle with N seeds); finetuning keeps
  all N critic pairs and all N actors. The acting policy mixes the actors by moment matching (reference code):
  μ = mean_i μ_i, σ² = mean_i(μ_i² + σ_i²) − μ², a = tanh(u), u ~ N(μ, σ²). Each member i learns SAC's backup
  y_i = r + γ (1 − d)[min_j Q̄_ij(s′, a′) − α_sac log π(a′|s′)]; the actors maximize
  mean_i min_j Q_ij(s, a) − α_sac log π(a|s).
* **Balanced replay.** A density-ratio network w(s, a) ≈ d_online / d_offline is fit with the variational form of
  the Jensen–Shannon divergence (Off2On Eq. 4): minimize E_off[−log(2 / (w + 1))] − E_on[log(2w / (w + 1))]; the
  RL batch is drawn from offline ∪ online data with priority ∝ w^(1/T) / E_off[w^(1/T)] clipped to [10⁻³, 10³]
  (T = 5), updated for the rows just sampled; new online rows enter with the current maximum priority.
Hyper-parameters from the reference code: N 5, learning rates 3e-4, target τ 5e-3, T 5, initial temperature 1,
target entropy −|A|. Priorities live in ``Learner.extra`` (one float per offline row and per buffer row, per run).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct
from jax import lax

from proto_brax.agents import sac
from proto_brax.agents.common import actor_critic_step, adam, apply_grads
from proto_brax.agents.learner import Learner, OnlineAlgorithm
from proto_brax.agents.proto import kl_penalty
from proto_brax.config import FinetuneConfig
from proto_brax.data.dataset import Transition
from proto_brax.data.replay import ReplayBuffer, replay_gather
from proto_brax.networks import LOG_STD_MAX, LOG_STD_MIN, Networks, sample_tanh_gaussian

PRIORITY_MIN, PRIORITY_MAX = 1e-3, 1e3


@struct.dataclass
class Off2OnHParams(sac.SACHParams):
    """Off2On's own traced hyper-parameter."""

    off2on_temperature: jax.Array = 5.0  # replay priority ∝ w^(1/T) (reference code T = 5)


def mixture(nets: Networks, actors, obs: jax.Array):
    """(μ, log σ) of the moment-matched Gaussian of the N actors (leading axis of ``actors``)."""
    means, log_stds = jax.vmap(nets.actor.apply, in_axes=(0, None))(actors, obs)
    mean = jnp.mean(means, axis=0)
    var = jnp.mean(jnp.square(means) + jnp.exp(2.0 * log_stds), axis=0) - jnp.square(mean)
    log_std = jnp.clip(0.5 * jnp.log(jnp.maximum(var, 1e-12)), LOG_STD_MIN, LOG_STD_MAX)
    return mean, log_std


def ensemble_q(nets: Networks, critics, obs: jax.Array, action: jax.Array) -> jax.Array:
    """Q of every member pair: [N, 2, B]."""
    return jax.vmap(nets.critic.apply, in_axes=(0, None, None))(critics, obs, action)


def density_loss(params, nets: Networks, off: Transition, on: Transition):
    """Off2On Eq. 4 (Jensen–Shannon, variational form): E_off[−log(2/(w+1))] − E_on[log(2w/(w+1))]."""
    w_off = nets.density.apply(params, off.observations, off.actions)
    w_on = nets.density.apply(params, on.observations, on.actions)
    loss = jnp.mean(-jnp.log(2.0 / (w_off + 1.0) + 1e-10)) - jnp.mean(jnp.log(2.0 * w_on / (w_on + 1.0) + 1e-10))
    return loss, {"density_loss": loss, "w_offline": jnp.mean(w_off), "w_online": jnp.mean(w_on)}


def priorities(params, nets: Networks, rl: Transition, off: Transition, temperature: jax.Array) -> jax.Array:
    """clip(w(s, a)^(1/T) / mean_off w^(1/T), 10⁻³, 10³) for the RL batch rows."""
    w = nets.density.apply(params, rl.observations, rl.actions) ** (1.0 / temperature)
    norm = jnp.mean(nets.density.apply(params, off.observations, off.actions) ** (1.0 / temperature))
    return jnp.clip(w / (norm + 1e-10), PRIORITY_MIN, PRIORITY_MAX)


def critic_loss(critics, learner: Learner, batch: Transition, key: jax.Array, hp: Off2OnHParams, nets: Networks):
    """Σ_i mean_B Σ_j (Q_ij(s, a) − y_i)², y_i = r + γ (1 − d)[min_j Q̄_ij(s′, a′) − α_sac log π(a′|s′)]."""
    mean, log_std = mixture(nets, learner.actor, batch.next_observations)
    a_next, _, logp_next = sample_tanh_gaussian(key, mean, log_std)
    q_next = jnp.min(ensemble_q(nets, learner.critic_target, batch.next_observations, a_next), axis=1)  # [N, B]
    y = batch.rewards + hp.gamma * (1.0 - batch.terminals) * (q_next - jnp.exp(learner.log_alpha_sac) * logp_next)
    q = ensemble_q(nets, critics, batch.observations, batch.actions)  # [N, 2, B]
    loss = jnp.sum(jnp.mean(jnp.sum(jnp.square(q - lax.stop_gradient(y)[:, None]), axis=1), axis=-1))
    return loss, {"critic_loss": loss, "q_mean": jnp.mean(q), "q_max": jnp.max(q), "target_mean": jnp.mean(y)}


def actor_loss(actors, critics, learner: Learner, obs: jax.Array, key: jax.Array, nets: Networks):
    """E[α_sac log π(a|s) − mean_i min_j Q_ij(s, a)], a from the mixed policy (gradients reach all N actors)."""
    mean, log_std = mixture(nets, actors, obs)
    a, _, logp = sample_tanh_gaussian(key, mean, log_std)
    q = jnp.mean(jnp.min(ensemble_q(nets, critics, obs, a), axis=1), axis=0)
    loss = jnp.mean(lax.stop_gradient(jnp.exp(learner.log_alpha_sac)) * logp - q)
    return loss, {"actor_loss": loss, "entropy": -jnp.mean(logp), "log_prob": logp}


def sample(key: jax.Array, learner: Learner, buffer: ReplayBuffer, dataset: Transition, cfg: FinetuneConfig):
    """(RL batch by priority over offline ∪ online, uniform offline batch, uniform online batch, RL row ids)."""
    k_rl, k_off, k_on = jax.random.split(key, 3)
    n_data = dataset.rewards.shape[0]
    prio_on = learner.extra["priority_online"]
    valid = jnp.arange(prio_on.shape[0]) < buffer.size
    top = jnp.maximum(jnp.max(learner.extra["priority_offline"]), jnp.max(prio_on))
    prio_on = jnp.where(valid, jnp.where(prio_on > 0, prio_on, top), 0.0)  # new rows: the current maximum
    # Inverse-CDF sampling: one cumulative sum and a binary search per row (a Gumbel-max draw would need
    # batch × (offline + online) random numbers per update). Zero-priority rows have empty intervals.
    cdf = jnp.cumsum(jnp.concatenate([learner.extra["priority_offline"], prio_on]))
    u = jax.random.uniform(k_rl, (cfg.batch_size,)) * cdf[-1]
    rows = jnp.minimum(jnp.searchsorted(cdf, u, side="right"), cdf.shape[0] - 1)
    take = lambda data, idx: jax.tree.map(lambda x: jnp.take(x, idx, axis=0), data)  # noqa: E731
    off = take(dataset, jax.random.randint(k_off, (cfg.batch_size,), 0, n_data))
    on = take(buffer.data, jax.random.randint(k_on, (cfg.batch_size,), 0, jnp.maximum(buffer.size, 1)))
    return replay_gather(buffer, dataset, rows), off, on, rows


def update(learner: Learner, batch, key: jax.Array, alpha: jax.Array, hp: Off2OnHParams, nets: Networks,
           cfg: FinetuneConfig, step: jax.Array) -> tuple[Learner, dict]:
    """Priorities of the sampled rows, density-ratio step, critic-ensemble step, actor step, temperature, targets."""
    del alpha, step
    rl, off, on, rows = batch
    k_critic, k_actor = jax.random.split(key)
    extra = dict(learner.extra)
    new_p = lax.stop_gradient(priorities(extra["density"], nets, rl, off, hp.off2on_temperature))
    n_data = extra["priority_offline"].shape[0]
    # Rows drawn twice get one of their new values; out-of-range writes (the other source) are dropped.
    extra["priority_offline"] = extra["priority_offline"].at[jnp.where(rows < n_data, rows, n_data)].set(
        new_p, mode="drop")
    n_on = extra["priority_online"].shape[0]
    extra["priority_online"] = extra["priority_online"].at[jnp.where(rows >= n_data, rows - n_data, n_on)].set(
        new_p, mode="drop")
    (_, d_info), g = jax.value_and_grad(density_loss, has_aux=True)(extra["density"], nets, off, on)
    extra["density"], extra["density_opt"] = apply_grads(g, extra["density_opt"], extra["density"])

    learner, c_info, a_info, t_loss = actor_critic_step(
        learner, lambda critics: critic_loss(critics, learner, rl, k_critic, hp, nets),
        lambda actors, critics: actor_loss(actors, critics, learner, rl.observations, k_actor, nets),
        hp.target_entropy_scale * rl.actions.shape[-1], hp.target_tau)
    learner = learner.replace(extra=extra)
    return learner, {**c_info, **a_info, **d_info, "alpha_sac": jnp.exp(learner.log_alpha_sac),
                     "temperature_loss": t_loss, "priority_mean": jnp.mean(new_p),
                     "offline_share": jnp.mean(rows < n_data), "actor_updates": jnp.ones(())}


def init(key: jax.Array, nets: Networks, cfg: FinetuneConfig, hp: Off2OnHParams, obs_size: int, act_size: int,
         pretrained, dataset: Transition | None) -> Learner:
    """N actors and critic pairs from a CQL bundle with N seeds (or random), a fresh density net and temperature."""
    if dataset is None:
        raise ValueError("off2on needs the offline dataset (balanced replay draws from offline ∪ online data).")
    n = cfg.ensemble_size
    k_a, k_c, k_d = jax.random.split(key, 3)
    obs, act = jnp.zeros((1, obs_size)), jnp.zeros((1, act_size))
    if pretrained is not None:
        actor, critic = pretrained.actor, pretrained.critic
        if jax.tree.leaves(actor)[0].shape[0] != n:
            raise ValueError(f"off2on: the bundle holds {jax.tree.leaves(actor)[0].shape[0]} agents but "
                             f"ensemble_size is {n}: pretrain with --seeds of that many values.")
    else:
        actor = jax.vmap(lambda k: nets.actor.init(k, obs))(jax.random.split(k_a, n))
        critic = jax.vmap(lambda k: nets.critic.init(k, obs, act))(jax.random.split(k_c, n))
    density = nets.density.init(k_d, obs, act)
    log_alpha = jnp.log(hp.alpha_sac_init)
    extra = {"density": density, "density_opt": adam(hp.lr_critic).init(density),
             "priority_offline": jnp.ones((dataset.rewards.shape[0],), jnp.float32),
             "priority_online": jnp.zeros((cfg.capacity,), jnp.float32)}
    return Learner(actor=actor, critic=critic, critic_target=critic, pibar=actor, pi0=actor,
                   actor_opt=adam(hp.lr_actor).init(actor), critic_opt=adam(hp.lr_critic).init(critic),
                   log_alpha_sac=log_alpha, alpha_opt=adam(hp.lr_alpha).init(log_alpha), extra=extra)


def act(nets: Networks, learner: Learner, obs: jax.Array, key: jax.Array, hp: Off2OnHParams | None,
        deterministic: bool) -> jax.Array:
    mean, log_std = mixture(nets, learner.actor, obs)
    return jnp.tanh(mean) if deterministic else sample_tanh_gaussian(key, mean, log_std)[0]


def deviation(nets: Networks, actor, other, obs: jax.Array, key: jax.Array) -> jax.Array:
    """Monte-Carlo KL between the two mixed policies."""
    mean, log_std = mixture(nets, actor, obs)
    mean_o, log_std_o = mixture(nets, other, obs)
    _, u, _ = sample_tanh_gaussian(key, mean, log_std)
    return jnp.mean(kl_penalty(u, mean, log_std, mean_o, log_std_o))


ONLINE = OnlineAlgorithm(update=update, act=act, deviation=deviation, temperature=True, init=init, sample=sample,
                         hparams=Off2OnHParams)
