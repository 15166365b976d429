"""Static configuration (shapes, loop counts, switches) and traced hyper-parameters (what a grid varies).

Anything that changes array shapes or the program's structure is a field of the frozen ``FinetuneConfig``, closed over
by ``make_finetune``. Scalars that a sweep varies are leaves of the ``HParams`` pytree, so a τ×η×α₀×seed grid is a
leading batch axis of one compiled program rather than one compilation per point.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from proto_brax import envs
from proto_brax.agents.registry import AGENTS
from proto_brax.data.replay import SAMPLING_MODES
from proto_brax.fidelity import Fidelity
from proto_brax.networks import NetworkConfig


@struct.dataclass
class HParams:
    """Traced scalar hyper-parameters every agent shares (defaults: PROTO paper / reference code for MuJoCo,
    shared/FACTS.md): PROTO's τ, η, α₀ schedule, the discount, the Polyak speed and the learning rates.

    An agent with hyper-parameters of its own subclasses this in its module (``sac.SACHParams``,
    ``td3.TD3HParams``, ...) and names the subclass in its ``OnlineAlgorithm.hparams``: a method's grid axes and
    ``--hp`` names are the fields of its agent's class. Each leaf is a float32 scalar for one run, or an array with a
    leading grid axis for a vmapped sweep.
    """

    tau: jax.Array = 5e-3  # π̄ Polyak speed: π̄ ← τ π + (1 − τ) π̄ (τ = 0: Frozen, π̄ stays π₀)
    eta: jax.Array = 0.9  # annealing speed of the regularization weight α
    alpha0: jax.Array = 2.0  # initial regularization weight α₀ (0: direct finetuning / plain SAC or TD3)
    alpha_min: jax.Array = 0.0  # floor of the annealed α
    anneal_horizon: jax.Array = 1e6  # N in α_t = max(α₀ (1 − η t / N), α_min), in env steps
    gamma: jax.Array = 0.99
    target_tau: jax.Array = 5e-3  # Polyak speed of the target critic (and TD3's target actor)
    lr_actor: jax.Array = 3e-4
    lr_critic: jax.Array = 3e-4

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))

    @classmethod
    def create(cls, **kwargs) -> "HParams":
        """Build from Python numbers (float32 scalars), rejecting names that are not this class's fields."""
        unknown = set(kwargs) - set(cls.names())
        if unknown:
            raise ValueError(f"Unknown hyper-parameter(s) {sorted(unknown)} of {cls.__name__}: valid names are "
                             f"{sorted(cls.names())}.")
        defaults = {f.name: f.default for f in dataclasses.fields(cls)}
        return cls(**{k: jnp.asarray(kwargs.get(k, v), jnp.float32) for k, v in defaults.items()})

    @classmethod
    def check(cls, v: dict[str, np.ndarray]) -> None:
        """Host-side range checks of the leaves ``v`` (name -> values); a subclass adds its own fields' checks."""
        if np.any((v["tau"] < 0) | (v["tau"] > 1)):
            raise ValueError(f"tau must lie in [0, 1] (0 = Frozen, π̄ fixed at π₀); got {v['tau']}.")
        for name in ("eta", "alpha0", "alpha_min"):
            if np.any(v[name] < 0):
                raise ValueError(f"{name} must be >= 0; got {v[name]}. Use alpha0 0 for direct finetuning.")
        if np.any(v["anneal_horizon"] <= 0):
            raise ValueError(f"anneal_horizon must be > 0; got {v['anneal_horizon']}.")
        for name in ("gamma", "target_tau"):
            if np.any((v[name] < 0) | (v[name] > 1)):
                raise ValueError(f"{name} must lie in [0, 1]; got {v[name]}.")
        positive("lr_actor", "lr_critic", v=v)


def positive(*names: str, v: dict[str, np.ndarray]) -> None:
    """Each named leaf must be > 0."""
    for name in names:
        if np.any(v[name] <= 0):
            raise ValueError(f"{name} must be > 0; got {v[name]}.")


def validate_hparams(hp: HParams) -> None:
    """Host-side checks, before anything compiles. Works on scalars and on grid-batched leaves."""
    v = {name: np.asarray(getattr(hp, name)) for name in type(hp).names()}
    for name, arr in v.items():
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"Hyper-parameter {name} must be finite, got {arr}.")
    type(hp).check(v)


@dataclasses.dataclass(frozen=True)
class FinetuneConfig:
    """Static configuration of an online (fine)tuning run; every field fixes shapes or program structure."""

    env: str = "hopper"  # registered task name (proto_brax.envs.REGISTRY)
    backend: str | None = None  # brax backend; None = the env's measured default
    algo: str = "sac"  # the online update: an agent of proto_brax.agents.registry.AGENTS
    net: NetworkConfig = NetworkConfig()
    steps: int = 100_000  # online env steps per run
    eval_every: int = 5_000  # env steps per chunk; one evaluation at the end of each chunk
    eval_episodes: int = 10  # deterministic evaluation episodes (vectorized)
    num_envs: int = 1  # parallel envs per run (each step inserts num_envs transitions)
    batch_size: int = 256
    buffer_capacity: int | None = None  # online replay capacity; None = steps × num_envs + fidelity.online_preload
    sampling: Literal["symmetric", "union", "online"] = "symmetric"
    offline_fraction: float = 0.5  # share of each batch drawn from the offline data ("symmetric" mode)
    learning_starts: int = 1_000  # env steps collected before the first update
    updates_per_step: int = 1  # gradient steps per env step (UTD ratio)
    regularizer: bool = True  # False skips every π̄ computation: the same results as α₀ = 0, only cheaper
    value_reg_backup: bool = True  # the PROTO penalty inside the critic target (paper: off for AntMaze and Adroit)
    clipped_double_q: bool = True  # min over the critic ensemble (else mean; paper: off for AntMaze)
    fidelity: Fidelity = Fidelity()  # switches for the official PROTO code's choices (FIDELITY.md)
    policy_delay: int = 2  # TD3: actor and targets update every policy_delay critic updates
    episode_length: int | None = None  # None = the env's registered length
    cql_n_actions: int = 10  # CQL / Cal-QL: sampled actions of each kind in the logsumexp (reference codes: 10)
    ensemble_size: int = 5  # Off2On: CQL agents in the pessimistic ensemble (= seeds of its CQL bundle)
    # Online rewards enter the buffer as reward_scale · r + reward_shift, the transform the offline data and the
    # pretrained critic were trained with (proto_brax.envs.reward_transform); returns are reported raw.
    reward_scale: float = 1.0
    reward_shift: float = 0.0

    def __post_init__(self):
        envs.get_spec(self.env)
        if self.backend is not None:
            envs.check_backend(self.backend)
        if self.algo not in AGENTS:
            raise ValueError(f"Unknown algo {self.algo!r}: choose one of {list(AGENTS)}.")
        if self.sampling not in SAMPLING_MODES:
            raise ValueError(f"Unknown sampling {self.sampling!r}: choose one of {list(SAMPLING_MODES)}.")
        for name in ("steps", "eval_every", "eval_episodes", "num_envs", "batch_size", "updates_per_step",
                     "learning_starts", "policy_delay", "cql_n_actions", "ensemble_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1; got {getattr(self, name)}.")
        if self.steps % self.eval_every:
            raise ValueError(f"steps ({self.steps}) must be a multiple of eval_every ({self.eval_every}).")
        if not 0.0 <= self.offline_fraction <= 1.0:
            raise ValueError(f"offline_fraction must lie in [0, 1]; got {self.offline_fraction}.")
        if not (np.isfinite(self.reward_scale) and self.reward_scale > 0 and np.isfinite(self.reward_shift)):
            raise ValueError(f"reward_scale must be finite and > 0, reward_shift finite; got {self.reward_scale}, "
                             f"{self.reward_shift}.")
        clip = self.fidelity.td3_expl_noise_clip
        if clip is not None and not clip > 0:
            raise ValueError(f"fidelity.td3_expl_noise_clip must be > 0 (or None: no clip); got {clip}.")
        if self.fidelity.online_preload < 0:
            raise ValueError(f"fidelity.online_preload must be >= 0; got {self.fidelity.online_preload}.")
        if self.buffer_capacity is not None and self.buffer_capacity < self.num_envs:
            raise ValueError(f"buffer_capacity must be >= num_envs; got {self.buffer_capacity}.")

    @property
    def num_chunks(self) -> int:
        return self.steps // self.eval_every

    @property
    def capacity(self) -> int:
        return self.buffer_capacity or self.steps * self.num_envs + self.fidelity.online_preload

    @property
    def horizon(self) -> int:
        return self.episode_length or envs.get_spec(self.env).episode_length
