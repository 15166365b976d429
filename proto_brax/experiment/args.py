"""A sweep's arguments: ``SweepArgs`` (the command line, one field per flag), the presets, the grid axes they
name, and the checks that need no JAX (run before any backend starts)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Literal

from proto_brax.agents.registry import METHODS, PRETRAIN_ALGOS, get_method
from proto_brax.fidelity import Fidelity

GRID_AXES = ("tau", "eta", "alpha0")


MethodName = Literal[tuple(METHODS)]  # the one list of method names is proto_brax.agents.registry.METHODS


@dataclasses.dataclass
class SweepArgs:
    """PROTO finetuning sweep (or a baseline's, --algo). Grid axes take several values and form their product
    (× seeds)."""

    env: str = "hopper"
    """Registered env (--help lists them all in its description)."""
    backend: str | None = None
    """Brax backend (generalized, positional, spring, mjx); default: the env's measured default."""
    algo: MethodName = "proto-sac"
    """Method (put it first: its defaults then show in --help): PROTO (proto-sac, proto-td3, proto-bc), its named
    cases frozen (τ 0) and direct (α₀ 0), or a baseline: sac-scratch, td3-scratch, sac-offline, iql, awac, pex,
    calql, off2on."""
    tau: tuple[float, ...] = (0.0, 0.005)
    """Grid axis: π̄ Polyak speed τ in [0, 1] (0 = Frozen: π̄ stays π₀)."""
    eta: tuple[float, ...] = (0.5, 1.0)
    """Grid axis: annealing speed η >= 0 of the regularization weight α."""
    alpha0: tuple[float, ...] = (2.0,)
    """Grid axis: initial regularization weight α₀ >= 0 (0 = direct finetuning)."""
    seeds: tuple[int, ...] = (0,)
    """Seeds: every grid point runs once per seed."""
    grid: tuple[str, ...] = ()
    """More grid axes over any traced hyper-parameter, NAME=V1,V2,... (e.g. expectile=0.7,0.9 awr_temperature=1,3)."""
    steps: int = 10_000
    """Online env steps per run."""
    eval_every: int = 2_000
    """Env steps between evaluations (one compiled chunk)."""
    eval_episodes: int = 5
    """Deterministic evaluation episodes (vectorized) per evaluation."""
    anneal_horizon: float | None = None
    """N in α_t = α₀ (1 − η t / N); default: steps (α annealed over the same fraction of the run as the paper's 10⁶)."""
    batch_size: int = 256
    learning_starts: int = 1_000
    """Env steps collected before the first update."""
    updates_per_step: int = 1
    """Gradient updates per env step: the update-to-data ratio (UTD; RLPD's paper: 20)."""
    hidden: tuple[int, ...] = (256, 256)
    """Hidden layer sizes of actor and critics."""
    critic_layer_norm: bool | None = None
    """LayerNorm in the critics; default: on, except halfcheetah (paper)."""
    num_qs: int = 2
    """Critics in the ensemble (a bundle's must match)."""
    policy: Literal["tanh_gaussian", "gaussian"] = "tanh_gaussian"
    """The actor's distribution: tanh-squashed Gaussian (ours) or the official PROTO code's Gaussian with mean
    tanh(m(s)) and a state-independent std (FIDELITY.md); it must match the bundle's."""
    value_reg_backup: bool = True
    """PROTO penalty in the critic target (paper: off for AntMaze/Adroit)."""
    clipped_double_q: bool = True
    """Min over the critic ensemble in backups (paper: off for AntMaze)."""
    fidelity: Fidelity = Fidelity()
    """Switches for the official PROTO code's choices (FIDELITY.md); --algo proto-official-online turns the online
    ones on."""
    sampling: Literal["symmetric", "union", "online"] | None = None
    """Replay mixing; default: symmetric with a dataset, online without."""
    offline_fraction: float = 0.5
    """Share of each batch from the offline data in symmetric mode."""
    dataset: str | None = "auto"
    """Offline data: a registered name (e.g. hopper-medium; built into the cache if missing), a file (our .npz, or a
    D4RL-format .hdf5), 'auto' = ENV-medium (AntMaze: ENV-diverse), or 'none' (online data only)."""
    dataset_size: int | None = None
    """Transitions of a registered dataset, built if missing. Default: 10⁵, or the registered size where that is
    smaller (the human sets: 25 episodes). The paper's D4RL sets have 10⁶: pass 1000000."""
    checkpoint: str = "auto"
    """Pretrained bundle (python -m proto_brax.pretrain) to finetune from (π₀, Q₀, V₀): a path; 'auto' = the committed
    checkpoints/pretrained/DATASET/KIND for the method's bundle kind (eql for PROTO; iql for iql/pex; bc for proto-bc
    and awac) — PROTO falls back to a random π₀ when there is none, the baselines stop; 'none' = a random π₀. Bundle
    seeds map onto run seeds by value (else seed mod the bundle's seed count); a one-seed bundle is broadcast."""
    pretrain: Literal[PRETRAIN_ALGOS] | None = None
    """Pretrain on --dataset first (one bundle seed per sweep seed, saved in OUT/pretrained), then finetune from it."""
    pretrain_steps: int = 100_000
    """Gradient steps of --pretrain."""
    pretrain_hp: dict[str, float] = dataclasses.field(default_factory=dict)
    """Offline hyper-parameters of --pretrain, e.g. --pretrain-hp alpha 0.5 (AntMaze's EQL temperature; see
    proto_brax.agents.insample.OfflineHParams)."""
    hp: dict[str, float] = dataclasses.field(default_factory=dict)
    """Other traced hyper-parameters, e.g. --hp lr_actor 1e-4 gamma 0.995: the fields of the method's HParams
    (proto_brax.config.HParams and its agent's own; --algo NAME --help lists them with their defaults)."""
    reward_scale: float | None = None
    """Training rewards are reward_scale · r + reward_shift, offline and online (returns are reported raw). Default:
    the bundle's (its critic's units); without a bundle the env's rule: 1000 / (max − min episode return of the
    dataset) for locomotion, as the IQL/IVR/PROTO reference code, 1 without a dataset, for AntMaze and point."""
    reward_shift: float | None = None
    """Default: the bundle's, else the env's (AntMaze −1, as the reference code; else 0)."""
    out: Path = Path("runs/sweep")
    """Output directory."""
    overwrite: bool = False
    """Replace an existing --out."""
    resume: bool = False
    """Continue the interrupted sweep in --out (same configuration)."""
    tensorboard: bool = False
    """Also write TensorBoard event files (OUT/tensorboard/run_XXX; needs `pip install proto_brax[tensorboard]`)."""
    report: bool = True
    """Write the PNG report (learning curves, heat map, deviation, cost) into OUT/report."""
    distributed: bool = False
    """Multi-host: call jax.distributed.initialize() and shard the grid over every process's devices; process 0
    writes the outputs. The coordinator comes from --coordinator/--num-processes/--process-id, else from the cluster's
    environment as jax detects it (SLURM, Open MPI, or JAX_COORDINATOR_ADDRESS with the flags)."""
    coordinator: str | None = None
    """With --distributed: HOST:PORT of process 0's coordinator (implies --distributed)."""
    num_processes: int | None = None
    """With --distributed: the number of processes (each runs this same command with its own --process-id)."""
    process_id: int | None = None
    """With --distributed: this process's index, 0 .. num_processes − 1 (0 writes the outputs)."""
    devices: int | None = None
    """CPU only: host devices to shard the grid over (default: one per core). The numbers of a run depend on the
    layout (devices, runs per device): --resume refuses another one (docs/RELIABILITY.md)."""
    block: Literal["vmap", "map"] = "vmap"
    """How each device runs its runs: ``vmap``, one batched program (for accelerators); ``map``, one run after another
    through the unbatched program inside the same jitted chunk: on one CPU thread as fast per update as a single run,
    where a vmap of 5 is slower (docs/MEASUREMENTS.md#run-block). Each gives its own rounding: --resume keeps the
    one a sweep started with."""
    debug: bool = False
    """Show the full traceback of an input error (also: PROTO_BRAX_DEBUG=1), instead of a one-line message."""


def grid_axes(args: SweepArgs) -> dict[str, list[float]]:
    """τ, η, α₀ plus the --grid axes (NAME=V1,V2,...); a non-PROTO method takes one value of τ, η and α₀."""
    axes = {"tau": list(args.tau), "eta": list(args.eta), "alpha0": list(args.alpha0)}
    method = get_method(args.algo)
    if not method.proto_axes:
        many = [k for k, v in axes.items() if len(v) > 1]
        if many:
            raise ValueError(f"--algo {args.algo} does not use {', '.join(many)}: give one value (grid over its own "
                             "hyper-parameters with --grid NAME=V1,V2).")
    for spec in args.grid:
        name, sep, values = spec.partition("=")
        if not sep or not values:
            raise ValueError(f"--grid {spec!r}: write NAME=V1,V2,... (e.g. expectile=0.7,0.9).")
        if name in axes:
            raise ValueError(f"--grid {name}: axis given twice (use --{name} for τ, η and α₀).")
        try:
            axes[name] = [float(v) for v in values.split(",")]
        except ValueError:
            raise ValueError(f"--grid {spec!r}: values must be numbers separated by commas.") from None
    return axes


def validate_args(args: SweepArgs) -> None:
    """Checks of the command line that need no JAX (run before any backend starts): silent no-ops are errors."""
    if args.devices is not None and args.devices < 1:
        raise ValueError(f"--devices {args.devices}: give a number of host devices >= 1 (or leave it out: one per "
                         "core).")
    if args.steps >= 1 and args.learning_starts > args.steps:
        raise ValueError(f"--learning-starts {args.learning_starts} > --steps {args.steps}: no update would run. "
                         f"Lower --learning-starts (the first update comes after that many env steps) or raise "
                         "--steps.")
    if args.num_processes is not None and args.num_processes < 1:
        raise ValueError(f"--num-processes {args.num_processes}: give a number >= 1.")
    if args.process_id is not None and not (0 <= args.process_id < (args.num_processes or 1 << 30)):
        raise ValueError(f"--process-id {args.process_id}: give an index in [0, --num-processes).")
    if args.coordinator is not None and not args.coordinator.rpartition(":")[2].isdigit():
        raise ValueError(f"--coordinator {args.coordinator!r}: write HOST:PORT (e.g. node0:1234).")


# Fields of SweepArgs that do not change a run's numbers (not compared by --resume).
RUN_ONLY_FIELDS = ("out", "overwrite", "resume", "devices", "block", "report", "tensorboard", "distributed",
                   "coordinator", "num_processes", "process_id", "debug")


def sweep_record(args: SweepArgs) -> dict:
    """The arguments as config.json records them (what --resume compares): JSON types, without the run-only flags."""
    record = {k: (str(v) if isinstance(v, Path) else v) for k, v in dataclasses.asdict(args).items()
              if k not in RUN_ONLY_FIELDS}
    return json.loads(json.dumps(record))  # tuples -> lists, as config.json stores them


def with_later_defaults(old: dict, defaults: dict) -> dict:
    """``old`` (a config.json record) with every field it lacks set to its default, recursively: a field added to the
    suite after the sweep started defaults to the behaviour it had before (the rule for every new field), so an old
    sweep resumes under new code as long as nothing it recorded differs."""
    out = dict(old)
    for k, v in defaults.items():
        if k not in out:
            out[k] = v
        elif isinstance(v, dict) and isinstance(out[k], dict):
            out[k] = with_later_defaults(out[k], v)
    return out


@dataclasses.dataclass(frozen=True)
class Preset:
    """A named set of SweepArgs defaults (``--preset NAME``): applied first, then the method's, then the flags."""

    summary: str
    fields: dict  # SweepArgs field -> value

    def apply(self, args: SweepArgs) -> SweepArgs:
        return dataclasses.replace(args, **self.fields)


PAPER_MUJOCO = dict(tau=(5e-3,), eta=(0.9,), alpha0=(2.0,), seeds=(0, 1, 2, 3, 4), eval_every=5_000,
                    eval_episodes=10, learning_starts=1_000)
PRESETS: dict[str, Preset] = {
    "smoke": Preset(
        "tiny CPU smoke sweep on the point task (seconds)",
        dict(env="point", dataset="none", tau=(0.0, 0.005), eta=(0.9,), alpha0=(0.0, 2.0), seeds=(0, 1), steps=1_000,
             eval_every=500, eval_episodes=2, hidden=(32, 32), batch_size=32, learning_starts=100)),
    "paper-mujoco": Preset(
        "PROTO paper, MuJoCo: τ 5e-3, η 0.9, α₀ 2, 10⁶ steps annealed over 10⁶, 5 seeds, eval 10×5k",
        dict(PAPER_MUJOCO, steps=1_000_000, anneal_horizon=1e6)),
    "paper-mujoco-100k": Preset(
        "reduced-scale paper-mujoco: 10⁵ steps, α annealed over the same fraction (N = 10⁵)",
        dict(PAPER_MUJOCO, steps=100_000, anneal_horizon=1e5)),
    "paper-antmaze": Preset(
        "PROTO paper, AntMaze (reference script): antmaze-medium(-diverse), τ 5e-5, η 0.9, α₀ 0.5, no "
        "value-regularization backup, no clipped double-Q, 10⁶ steps, 5 seeds, eval 100×50k, EQL 2·10⁵",
        dict(env="antmaze-medium", dataset="auto", dataset_size=1_000_000, tau=(5e-5,), eta=(0.9,), alpha0=(0.5,),
             seeds=(0, 1, 2, 3, 4), steps=1_000_000, eval_every=50_000, eval_episodes=100, anneal_horizon=1e6,
             learning_starts=1_000, value_reg_backup=False, clipped_double_q=False, pretrain_steps=200_000,
             pretrain_hp={"alpha": 0.5})),
    # Adroit's offline data are D4RL's human demonstrations, which cannot be generated: the preset names D4RL's pen
    # file through Minari (loaded from the user's Minari cache; --dataset PATH or another Minari id for door/hammer).
    "paper-adroit": Preset(
        "PROTO paper, Adroit: pen from D4RL's human data (Minari D4RL/pen/human-v2, user-supplied), τ 5e-5, η 0.9, "
        "α₀ 2, no value-regularization backup, clipped double-Q, 10⁶ steps, 5 seeds, eval 10×5k, EQL 10⁵",
        dict(env="pen", dataset="D4RL/pen/human-v2", tau=(5e-5,), eta=(0.9,), alpha0=(2.0,), seeds=(0, 1, 2, 3, 4),
             steps=1_000_000, eval_every=5_000, eval_episodes=10, anneal_horizon=1e6, learning_starts=1_000,
             value_reg_backup=False, clipped_double_q=True, pretrain_steps=100_000)),
}


def sweep_args(algo: str = "proto-sac", preset: str | None = None, **overrides) -> SweepArgs:
    """The Python API's equivalent of ``--preset PRESET --algo ALGO --FIELD VALUE…``."""
    args = SweepArgs()
    if preset is not None:
        if preset not in PRESETS:
            raise ValueError(f"Unknown preset {preset!r}: choose one of {sorted(PRESETS)}.")
        args = PRESETS[preset].apply(args)
    return dataclasses.replace(args, algo=algo, **{**get_method(algo).defaults, **overrides})
