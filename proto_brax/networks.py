"""Network factories: MLP, tanh-Gaussian actor, deterministic actor, critic ensemble and state value (flax.linen)."""

from __future__ import annotations

import dataclasses
import math
from typing import Literal, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0
_LOG2 = math.log(2.0)


class MLP(nn.Module):
    hidden: Sequence[int]
    out: int
    layer_norm: bool = False

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for h in self.hidden:
            x = nn.Dense(h)(x)
            if self.layer_norm:
                x = nn.LayerNorm()(x)
            x = nn.relu(x)
        return nn.Dense(self.out)(x)


class GaussianActor(nn.Module):
    """Outputs (mean, log_std) of a Gaussian over the pre-tanh action u; the action is a = tanh(u)."""

    action_size: int
    hidden: Sequence[int]
    layer_norm: bool = False

    @nn.compact
    def __call__(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        out = MLP(self.hidden, 2 * self.action_size, self.layer_norm)(obs)
        mean, log_std = jnp.split(out, 2, axis=-1)
        # Smooth squashing of log_std into [LOG_STD_MIN, LOG_STD_MAX] keeps gradients alive at the bounds.
        log_std = LOG_STD_MIN + 0.5 * (LOG_STD_MAX - LOG_STD_MIN) * (jnp.tanh(log_std) + 1.0)
        return mean, log_std


class DeterministicActor(nn.Module):
    """π(s) = tanh(mean(s)) with exactly the parameters of ``GaussianActor`` (its log-std head is unused).

    Sharing the parameter tree means any pretrained stochastic actor (EQL, BC, IQL) initializes PROTO-TD3 as its mean
    action, with no conversion; the unused half of the last layer costs |A| × hidden multiply-adds.
    """

    action_size: int
    hidden: Sequence[int]
    layer_norm: bool = False

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        out = MLP(self.hidden, 2 * self.action_size, self.layer_norm)(obs)
        return jnp.tanh(out[..., : self.action_size])


class GaussianMeanTanhActor(nn.Module):
    """The official PROTO code's policy (jaxrl's ``NormalTanhPolicy`` with ``tanh_squash_distribution=False`` and
    ``state_dependent_std=False``): a Gaussian over the action itself, mean tanh(m(s)) and a state-independent log-std
    (a free parameter, initialized at 0) hard-clipped to [LOG_STD_MIN, LOG_STD_MAX]. Returns (mean, log_std) of that
    Gaussian (already tanh-ed mean: samples are not squashed; ``GaussianPolicy`` clips them only for the env)."""

    action_size: int
    hidden: Sequence[int]
    layer_norm: bool = False

    @nn.compact
    def __call__(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        mean = jnp.tanh(MLP(self.hidden, self.action_size, self.layer_norm)(obs))
        log_std = jnp.clip(self.param("log_stds", nn.initializers.zeros, (self.action_size,)), LOG_STD_MIN,
                           LOG_STD_MAX)
        return mean, jnp.broadcast_to(log_std, mean.shape)


class DeterministicGaussianMeanTanhActor(nn.Module):
    """π(s) = tanh(m(s)) with exactly the parameters of ``GaussianMeanTanhActor`` (its log-std is unused)."""

    action_size: int
    hidden: Sequence[int]
    layer_norm: bool = False

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        self.param("log_stds", nn.initializers.zeros, (self.action_size,))
        return jnp.tanh(MLP(self.hidden, self.action_size, self.layer_norm)(obs))


class Critic(nn.Module):
    hidden: Sequence[int]
    layer_norm: bool = False

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
        return MLP(self.hidden, 1, self.layer_norm)(jnp.concatenate([obs, action], -1))[..., 0]


class CriticEnsemble(nn.Module):
    """``num`` independent critics in one module (nn.vmap); returns Q of shape [num, ...]."""

    hidden: Sequence[int]
    num: int = 2
    layer_norm: bool = False

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
        ensemble = nn.vmap(
            Critic,
            variable_axes={"params": 0},
            split_rngs={"params": True},
            in_axes=None,
            out_axes=0,
            axis_size=self.num,
        )
        return ensemble(self.hidden, self.layer_norm)(obs, action)


class ValueNet(nn.Module):
    hidden: Sequence[int]
    layer_norm: bool = False

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        return MLP(self.hidden, 1, self.layer_norm)(obs)[..., 0]


# ---------------------------------------------------------------------------------------------------------------
# Policy distributions: pure functions on the actor's (mean, log_std)


def gaussian_log_prob(u: jax.Array, mean: jax.Array, log_std: jax.Array) -> jax.Array:
    """log N(u; mean, exp(log_std)) summed over the last axis."""
    z = (u - mean) * jnp.exp(-log_std)
    return jnp.sum(-0.5 * z**2 - log_std - 0.5 * math.log(2 * math.pi), axis=-1)


def tanh_log_det(u: jax.Array) -> jax.Array:
    """log |d tanh(u)/du| summed over the last axis, in the stable form 2 (log 2 - u - softplus(-2u))."""
    return jnp.sum(2.0 * (_LOG2 - u - jax.nn.softplus(-2.0 * u)), axis=-1)


def sample_tanh_gaussian(key: jax.Array, mean: jax.Array, log_std: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Reparameterized sample. Returns (action, pre-tanh u, log π(action))."""
    u = mean + jnp.exp(log_std) * jax.random.normal(key, mean.shape)
    return jnp.tanh(u), u, gaussian_log_prob(u, mean, log_std) - tanh_log_det(u)


def tanh_gaussian_log_prob(action: jax.Array, mean: jax.Array, log_std: jax.Array, eps: float = 1e-6) -> jax.Array:
    """log π(a) of a given squashed action (e.g. a dataset action, for BC); a is clipped away from ±1 first."""
    u = jnp.arctanh(jnp.clip(action, -1.0 + eps, 1.0 - eps))
    return gaussian_log_prob(u, mean, log_std) - tanh_log_det(u)


@dataclasses.dataclass(frozen=True)
class TanhGaussianPolicy:
    """a = tanh(u), u ~ N(mean, std): this suite's default. ``sample`` returns (action, u, log π(action)); the PROTO KL
    (``regularizer.kl_penalty``) compares the two Gaussians at u, where the tanh Jacobians cancel."""

    def sample(self, key, mean, log_std):
        return sample_tanh_gaussian(key, mean, log_std)

    def mode(self, mean):
        return jnp.tanh(mean)

    def log_prob(self, action, mean, log_std):
        return tanh_gaussian_log_prob(action, mean, log_std)

    def to_env(self, action):
        return action  # already inside (−1, 1)


@dataclasses.dataclass(frozen=True)
class GaussianPolicy:
    """a ~ N(mean, std) with mean = tanh(m(s)) (``GaussianMeanTanhActor``, the official PROTO code's policy). Samples
    stay unsquashed in every loss (the critic sees actions outside [−1, 1]); log-probs are Gaussian densities of the
    sample, so ``sample``'s u is the action itself and the PROTO KL is log N(a; μ, σ) − log N(a; μ̄, σ̄). Only the
    env's action is clipped to [−1, 1]; dataset actions are clipped to ±(1 − 1e-5) for the likelihood, as the
    official code clips them at load."""

    def sample(self, key, mean, log_std):
        a = mean + jnp.exp(log_std) * jax.random.normal(key, mean.shape)
        return a, a, gaussian_log_prob(a, mean, log_std)

    def mode(self, mean):
        return mean

    def log_prob(self, action, mean, log_std):
        return gaussian_log_prob(jnp.clip(action, -1.0 + 1e-5, 1.0 - 1e-5), mean, log_std)

    def to_env(self, action):
        return jnp.clip(action, -1.0, 1.0)


POLICIES = {"tanh_gaussian": TanhGaussianPolicy(), "gaussian": GaussianPolicy()}


# ---------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class NetworkConfig:
    """Static network shapes (paper: 2 x 256, ReLU, LayerNorm on Q and V except halfcheetah)."""

    hidden: tuple[int, ...] = (256, 256)
    critic_layer_norm: bool = True
    actor_layer_norm: bool = False
    num_qs: int = 2
    policy: Literal["tanh_gaussian", "gaussian"] = "tanh_gaussian"
    """The actor's distribution: a tanh-squashed Gaussian with state-dependent std (ours), or the official PROTO
    code's Gaussian with mean tanh(m(s)) and a state-independent std (FIDELITY.md row 6)."""

    def __post_init__(self):
        if self.policy not in POLICIES:
            raise ValueError(f"Unknown policy {self.policy!r}: choose one of {list(POLICIES)}.")
        if self.num_qs < 1:
            raise ValueError(f"num_qs must be >= 1 (critics in the ensemble); got {self.num_qs}.")


class DensityRatioNet(nn.Module):
    """w(s, a) = relu(MLP(s, a)) ≥ 0, last bias initialized at 1 (w ≈ 1 at the start), for Off2On's balanced replay."""

    hidden: Sequence[int]

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
        x = jnp.concatenate([obs, action], -1)
        for h in self.hidden:
            x = nn.relu(nn.Dense(h)(x))
        return nn.relu(nn.Dense(1, bias_init=nn.initializers.constant(1.0))(x)[..., 0])


@dataclasses.dataclass(frozen=True)
class Networks:
    actor: nn.Module
    critic: CriticEnsemble
    value: ValueNet
    density: DensityRatioNet
    policy: TanhGaussianPolicy | GaussianPolicy = TanhGaussianPolicy()  # the actor's distribution functions


ACTORS = {("tanh_gaussian", False): GaussianActor, ("tanh_gaussian", True): DeterministicActor,
          ("gaussian", False): GaussianMeanTanhActor, ("gaussian", True): DeterministicGaussianMeanTanhActor}


def make_networks(cfg: NetworkConfig, action_size: int, deterministic: bool = False) -> Networks:
    actor_cls = ACTORS[cfg.policy, deterministic]
    return Networks(
        policy=POLICIES[cfg.policy],
        actor=actor_cls(action_size, cfg.hidden, cfg.actor_layer_norm),
        critic=CriticEnsemble(cfg.hidden, cfg.num_qs, cfg.critic_layer_norm),
        value=ValueNet(cfg.hidden, cfg.critic_layer_norm),
        density=DensityRatioNet(cfg.hidden),
    )
