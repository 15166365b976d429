"""The one list of agents and methods.

An **agent** is an online update of the engine (``FinetuneConfig.algo``): a module of ``proto_brax.agents`` holding
its losses, its ``update`` and an ``OnlineAlgorithm`` record (``agents.learner``). A **method** is what a sweep runs
(``python -m proto_brax.sweep --algo NAME``): an agent plus its settings. PROTO, its named special cases (Frozen:
τ = 0, direct: α₀ = 0, from scratch: a random π₀) and the PROTO paper's baselines are all methods; every method runs
in the same jitted, vmapped loop and is logged and reported the same way. A method's ``defaults`` replace the sweep's
defaults (after a ``--preset``, before the command line), so ``--algo NAME --help`` shows them. Hyper-parameters come
from each paper or its reference code (``proto_brax.config.HParams`` and each agent's subclass cite them).

Adding a method is one agent module plus its lines here (``AGENTS`` and ``METHODS``). This module imports no JAX: the
command lines build their arguments from it before anything heavy is imported; ``agent(name)`` imports the module.
"""

from __future__ import annotations

import dataclasses
import importlib
from typing import Any

from proto_brax.fidelity import Fidelity

# Agent name -> "module.ATTRIBUTE" of its OnlineAlgorithm in proto_brax.agents (imported on first use).
AGENTS: dict[str, str] = {
    "sac": "sac.ONLINE", "td3": "td3.ONLINE", "iql": "iql.ONLINE", "awac": "awac.ONLINE", "pex": "pex.ONLINE",
    "cql": "cql.ONLINE_CQL", "calql": "cql.ONLINE_CALQL", "off2on": "off2on.ONLINE", "rlpd": "rlpd.ONLINE",
}

# Offline pretraining algorithms (python -m proto_brax.pretrain --algo; proto_brax.train.offline).
PRETRAIN_ALGOS = ("eql", "sql", "iql", "bc", "cql", "calql")
VALUE_ALGOS = ("eql", "sql", "iql")  # bundles with a state-value network
TEMPERATURE_ALGOS = ("cql", "calql")  # bundles with SAC's entropy temperature
GAUSSIAN_POLICY_ALGOS = ("eql", "sql", "iql")  # also pretrain the official code's Gaussian policy (FIDELITY.md)
# Their defaults under the user's --hp: CQL's MuJoCo policy learning rate (its reference commands).
PRETRAIN_HP = {"cql": {"lr_actor": 1e-4}, "calql": {"lr_actor": 1e-4}}


def agent(name: str):
    """The ``OnlineAlgorithm`` of agent ``name`` (imports its module)."""
    if name not in AGENTS:
        raise ValueError(f"Unknown algo {name!r}: choose one of {list(AGENTS)}.")
    module, attr = AGENTS[name].split(".")
    return getattr(importlib.import_module(f"proto_brax.agents.{module}"), attr)


# Standard SAC from scratch (Haarnoja et al. 2018): initial temperature 1, target entropy −|A|.
SAC_SCRATCH_HP = {"alpha_sac_init": 1.0, "target_entropy_scale": -1.0}


@dataclasses.dataclass(frozen=True)
class Method:
    name: str
    algo: str  # the engine's online update (a key of AGENTS)
    summary: str
    bundles: tuple[str, ...] = ()  # pretraining algos it may start from, the first is 'auto'; () = random init only
    requires_bundle: bool = False  # no bundle found for 'auto' -> an error naming the fix (else a random π₀)
    bundle_suffix: str = ""  # 'auto' looks in checkpoints/pretrained/DATASET/KIND+SUFFIX (a variant's own bundles)
    proto_axes: bool = False  # τ, η, α₀ act on it (PROTO variants); other methods take one value of each
    regularizer: bool = True  # False skips π̄ work entirely (plain SAC/TD3: the cost of the unregularized update)
    defaults: dict[str, Any] = dataclasses.field(default_factory=dict)  # SweepArgs fields
    hp: dict[str, float] = dataclasses.field(default_factory=dict)  # HParams under the user's --hp

    @property
    def auto_bundle(self) -> str | None:
        """The bundle directory name ``--checkpoint auto`` starts from under checkpoints/pretrained/DATASET (its first
        kind plus its suffix: proto-official's ``eql-official``); None for a random-init method."""
        return self.bundles[0] + self.bundle_suffix if self.bundles else None

    @property
    def uses_dataset(self) -> bool:
        """False for the methods that train on online data only (SAC/TD3 from scratch): any dataset gives the same
        runs."""
        return self.defaults.get("dataset") != "none"


RLPD_DEFAULTS = {"checkpoint": "none", "alpha0": (0.0,), "tau": (5e-3,), "eta": (0.9,), "sampling": "symmetric",
                 "critic_layer_norm": True, "num_qs": 10, "updates_per_step": 20, "learning_starts": 5_000,
                 "reward_scale": 1.0, "reward_shift": 0.0}

METHODS: dict[str, Method] = {m.name: m for m in (
    Method("proto-sac", "sac", "PROTO with SAC (paper Eq. 3-4): KL to the Polyak-averaged π̄, α annealed linearly; "
           "from an EQL bundle", bundles=("eql", "sql", "iql", "bc"), proto_axes=True),
    Method("proto-td3", "td3", "PROTO with TD3 (paper appendix): ‖π(s) − π̄(s)‖² penalty, λ = β / mean|Q|, β = 4; "
           "the EQL actor's mean action is π₀", bundles=("eql", "sql", "iql", "bc"), proto_axes=True),
    Method("proto-bc", "sac", "PROTO-SAC from a BC actor and its FQE critic (PROTO+BC)", bundles=("bc",),
           requires_bundle=True, proto_axes=True),
    Method("proto-official", "sac", "PROTO-SAC as the official code runs it (FIDELITY.md): its policy class (Gaussian "
           "with mean tanh(m(s)) and a state-independent std), its EQL pretraining (extraction weight exp((Q − V)/α), "
           "z clip 7), the critic's Adam state and target carried over, and every online choice of "
           "proto-official-online; from an eql-official bundle", bundles=("eql",), bundle_suffix="-official",
           requires_bundle=True, proto_axes=True,
           defaults={"fidelity": Fidelity.official(), "learning_starts": 1, "policy": "gaussian",
                     "pretrain_hp": {"eql_weight_scale": 1.0, "eql_z_clip": 7.0}}),
    Method("proto-official-online", "sac", "PROTO-SAC with the official code's online choices (FIDELITY.md rows 1-5): "
           "actor on the critics' mean, α·(H − H̄) temperature loss, one random target critic without clipped "
           "double-Q, 10k offline rows preloaded into the online buffer and updates from the first step, the critic's "
           "Adam state and target carried over; from our EQL bundle",
           bundles=("eql", "sql", "iql", "bc"), proto_axes=True,
           defaults={"fidelity": Fidelity.official(), "learning_starts": 1}),
    Method("proto-td3-official-online", "td3", "PROTO-TD3 with the official code's online choices (FIDELITY.md): "
           "Q₂ actor, penalty averaged over action dims, β 2.5, exploration σ 0.2 clipped 0.5, the official backup, "
           "the dataset in the buffer (union sampling), updates from the first step",
           bundles=("eql", "sql", "iql", "bc"),
           proto_axes=True, defaults={"fidelity": dataclasses.replace(Fidelity.official(), online_preload=0),
                                      "learning_starts": 1, "sampling": "union"},
           hp={"beta": 2.5, "expl_noise": 0.2}),
    Method("frozen", "sac", "PROTO with τ = 0: a fixed regularization towards π₀ (the paper's Frozen)",
           bundles=("eql", "sql", "iql", "bc"), proto_axes=True, defaults={"tau": (0.0,)}),
    Method("direct", "sac", "direct SAC finetuning from the pretrained bundle: PROTO with α₀ = 0",
           bundles=("eql", "sql", "iql", "bc"), proto_axes=True, defaults={"alpha0": (0.0,), "tau": (5e-3,)}),
    Method("sac-scratch", "sac", "SAC from a random init with online data only (temperature 1, target entropy −|A|)",
           regularizer=False, defaults={"dataset": "none", "checkpoint": "none", "alpha0": (0.0,), "tau": (5e-3,),
                                        "eta": (0.9,), "learning_starts": 5_000},
           hp=SAC_SCRATCH_HP),
    Method("td3-scratch", "td3", "TD3 from a random init with online data only (Fujimoto et al. 2018)",
           regularizer=False, defaults={"dataset": "none", "checkpoint": "none", "alpha0": (0.0,), "tau": (5e-3,),
                                        "eta": (0.9,), "learning_starts": 5_000}),
    Method("sac-offline", "sac", "SAC from a random init with the offline dataset in the buffer (50/50 symmetric "
           "sampling)", regularizer=False,
           defaults={"checkpoint": "none", "alpha0": (0.0,), "tau": (5e-3,), "eta": (0.9,), "sampling": "symmetric"},
           hp=SAC_SCRATCH_HP),
    Method("iql", "iql", "IQL online finetuning (Kostrikov et al. 2022): expectile 0.7, AWR β 3, the dataset stays "
           "in the buffer (union sampling); from an IQL bundle", bundles=("iql",), requires_bundle=True,
           regularizer=False, defaults={"alpha0": (0.0,), "tau": (5e-3,), "eta": (0.9,), "sampling": "union"}),
    Method("awac", "awac", "AWAC (Nair et al. 2020): TD critic + advantage-weighted likelihood, λ = 1; from a BC actor "
           "and its FQE critic, prior data in the buffer (union sampling)", bundles=("bc",), requires_bundle=True,
           regularizer=False, defaults={"alpha0": (0.0,), "tau": (5e-3,), "eta": (0.9,), "sampling": "union"}),
    Method("calql", "calql", "Cal-QL (Nakamoto et al. 2023): CQL (α_cql 5, 10 actions per kind) whose push-down is "
           "bounded below by Monte-Carlo returns, SAC actor (learning rate 1e-4), 50/50 offline/online sampling; from "
           "a Cal-QL bundle (its temperature included)", bundles=("calql",), requires_bundle=True,
           regularizer=False, defaults={"alpha0": (0.0,), "tau": (5e-3,), "eta": (0.9,), "sampling": "symmetric"},
           hp={"lr_actor": 1e-4, "target_entropy_scale": -1.0, "alpha_sac_init": 1.0}),
    Method("off2on", "off2on", "Off2On (Lee et al. 2021): 5 CQL agents as a pessimistic Q-ensemble with a "
           "moment-matched policy, balanced replay by a density-ratio net (priority ∝ w^(1/5)); from a CQL bundle "
           "with 5 seeds", bundles=("cql",), requires_bundle=True, regularizer=False,
           defaults={"alpha0": (0.0,), "tau": (5e-3,), "eta": (0.9,), "sampling": "union"},
           hp={"target_entropy_scale": -1.0, "alpha_sac_init": 1.0}),
    Method("pex", "pex", "PEX (Zhang et al. 2023): frozen IQL π₀ + a new policy, Boltzmann choice by Q "
           "(inverse temperature 10), IQL losses, 50/50 offline/online sampling; from an IQL bundle",
           bundles=("iql",), requires_bundle=True, regularizer=False,
           defaults={"alpha0": (0.0,), "tau": (5e-3,), "eta": (0.9,), "sampling": "symmetric"}),
    Method("rlpd", "rlpd", "RLPD (Ball et al. 2023): SAC from a random init on 50/50 offline/online batches, 10 "
           "LayerNorm critics with the min over a random 2 in the backup, UTD 20 (--updates-per-step), raw rewards",
           regularizer=False, defaults=RLPD_DEFAULTS, hp={"alpha_sac_init": 1.0}),
    Method("rlpd-utd1", "rlpd", "RLPD at one update per env step (the UTD a 2-core CPU affords at the published "
           "budget; the paper runs 20)", regularizer=False,
           defaults={**RLPD_DEFAULTS, "updates_per_step": 1}, hp={"alpha_sac_init": 1.0}),
)}


def pretrain_flags(policy: str = "tanh_gaussian", pretrain_hp: dict | None = None) -> list[str]:
    """The ``python -m proto_brax.pretrain`` flags of a bundle variant: ``--policy`` when not the default, and every
    hyper-parameter pair after ONE ``--hp`` (a repeated ``--hp`` would replace the earlier one)."""
    flags = ["--policy", policy] if policy != "tanh_gaussian" else []
    hp = sorted((pretrain_hp or {}).items())
    return flags + (["--hp", *(x for k, v in hp for x in (k, f"{v:g}"))] if hp else [])


def get_method(name: str) -> Method:
    if name not in METHODS:
        raise ValueError(f"Unknown method {name!r}: choose one of {sorted(METHODS)}.")
    return METHODS[name]


def describe() -> str:
    return "; ".join(f"{m.name}: {m.summary}" for m in METHODS.values())
