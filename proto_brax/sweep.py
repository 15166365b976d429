"""``python -m proto_brax.sweep``: a τ×η×α₀×seed grid of PROTO finetuning runs as one compiled, sharded program.

Every grid point and seed runs inside one ``jit(vmap(chunk))``; the grid axis is sharded over all devices (on a CPU,
one host device per core). Between chunks the host shows progress, appends evaluation rows to ``metrics.jsonl`` and
checkpoints the whole sweep state with orbax, so ``--resume`` continues an interrupted sweep and ends with the same
results as an uninterrupted one.

Outputs in ``--out``: ``config.json``, ``metrics.jsonl`` (one row per evaluation per run), ``summary.json`` (per grid
point: final and average return / normalized score over seeds, mean ± std, IQM with 95% bootstrap CI) and ``state/``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Any, Literal

import numpy as np

from proto_brax.agents.registry import METHODS, PRETRAIN_ALGOS, describe, get_method, pretrain_flags
from proto_brax.fidelity import Fidelity
from proto_brax.files import append_once, read_jsonl, strict_json, write_json_atomic, write_text_atomic
from proto_brax.startup import exit_on_input_error

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
    dataset_size: int | None = 100_000
    """Transitions of a registered dataset (the paper's D4RL sets have 10⁶: pass 1000000); built if missing."""
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
    """Other traced hyper-parameters, e.g. --hp lr_actor 1e-4 gamma 0.995 (see proto_brax.config.HParams)."""
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
    debug: bool = False
    """Show the full traceback of an input error (also: PROTO_BRAX_DEBUG=1), instead of a one-line message."""


def _finetune_config(args: SweepArgs):
    from proto_brax.config import FinetuneConfig
    from proto_brax.envs import default_layer_norm
    from proto_brax.networks import NetworkConfig

    method = get_method(args.algo)
    dataset = resolve_dataset(args)
    sampling = args.sampling or ("symmetric" if dataset is not None else "online")
    if sampling != "online" and dataset is None:
        raise ValueError(f"--sampling {sampling} needs offline data: pass --dataset, or use --sampling online.")
    return FinetuneConfig(
        env=args.env, backend=args.backend, algo=method.algo, regularizer=method.regularizer,
        net=NetworkConfig(hidden=tuple(args.hidden), critic_layer_norm=(
            default_layer_norm(args.env) if args.critic_layer_norm is None else args.critic_layer_norm),
            policy=args.policy, num_qs=args.num_qs),
        steps=args.steps, eval_every=args.eval_every, eval_episodes=args.eval_episodes, batch_size=args.batch_size,
        learning_starts=args.learning_starts, updates_per_step=args.updates_per_step, sampling=sampling,
        offline_fraction=args.offline_fraction,
        value_reg_backup=args.value_reg_backup, clipped_double_q=args.clipped_double_q, fidelity=args.fidelity,
    )


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


def _load_dataset(name_or_path: str | None, size: int | None = None):
    if name_or_path is None:
        return None, None
    from proto_brax import datasets
    from proto_brax.data.generate import dataset_names

    if name_or_path in dataset_names():
        path = datasets.dataset_path(name_or_path, size)
        hint = datasets.rebuild_command(name_or_path, size, 0)
        stale = path.exists() and datasets.stale_reason(datasets.cached_metadata(path, hint))
        if stale or not path.exists():  # made from other behaviour snapshots than the current rule picks, or missing
            state = f"is stale ({stale})" if stale else "is not cached"
            argv = datasets.make_argv(name_or_path, size, 0)
            print(f"dataset {name_or_path} {state}: building it (= python -m proto_brax.datasets {' '.join(argv)})",
                  flush=True)
            import subprocess
            import sys

            from proto_brax.data.dataset import load_npz

            # In a process of its own: generation runs under pinned XLA threading (datasets.generation_xla_flags),
            # which this process's jax, already started, may not have.
            subprocess.run([sys.executable, "-m", "proto_brax.datasets", *argv], check=True)
            # what was just built (re-checking it could call it stale again while its behaviour policy trains on)
            return load_npz(path)
    return datasets.load_dataset(name_or_path, size)  # a file, or an error naming the problem


REPO_ROOT = Path(__file__).resolve().parents[1]


def resolve_dataset(args: SweepArgs) -> str | None:
    """'none' -> None; 'auto' -> ENV-medium (AntMaze: ENV-diverse) when registered; else the given name or path."""
    from proto_brax.data.generate import ANTMAZE_ENVS, dataset_names

    if args.dataset in (None, "none"):
        return None
    if args.dataset == "auto":
        name = f"{args.env}-{'diverse' if args.env in ANTMAZE_ENVS else 'medium'}"
        return name if name in dataset_names() else None
    return args.dataset


def resolve_checkpoint(args: SweepArgs) -> Path | None:
    """'none' -> None; 'auto' -> the committed bundle of the dataset for the method's bundle kind; else the path.

    A method that needs a bundle (iql, pex, awac, proto-bc) stops with the commands that make one when 'auto' finds
    none; PROTO falls back to a random π₀ (announced)."""
    method = get_method(args.algo)
    if args.checkpoint == "none":
        return None
    if not method.bundles:
        if args.checkpoint != "auto":
            raise ValueError(f"--algo {args.algo} starts from a random init: drop --checkpoint (or use "
                             "--algo direct to finetune a bundle without regularization).")
        return None
    if args.checkpoint == "auto":
        dataset = resolve_dataset(args)
        kind = method.bundles[0]
        if dataset is None or Path(dataset).suffix:
            if method.requires_bundle and args.pretrain is None:
                raise ValueError(f"--algo {args.algo} starts from a {kind} bundle: pass --checkpoint PATH, or a "
                                 f"registered --dataset with a committed bundle.")
            return None
        auto = REPO_ROOT / "checkpoints" / "pretrained" / dataset / (kind + method.bundle_suffix)
        if (auto / "metadata.json").exists():
            return auto
        if args.pretrain is None:  # (with --pretrain the sweep makes its own bundle)
            rel = auto.relative_to(REPO_ROOT)
            extra = "".join(f" {f}" for f in pretrain_flags(args.policy, args.pretrain_hp))
            fix = (f"python -m proto_brax.pretrain --dataset {dataset} --algo {kind}{extra} --out {rel}, or add "
                   f"--pretrain {kind}, or pass --checkpoint PATH")
            if method.requires_bundle:
                raise FileNotFoundError(f"--algo {args.algo}: no committed {kind} bundle for {dataset}. Make one: "
                                        f"{fix}.")
            print(f"no committed {kind} bundle for {dataset}: π₀ is a random init (make one: {fix})", flush=True)
        return None
    return Path(args.checkpoint)


def reward_transform(args: SweepArgs, bundle_meta: dict | None, dataset) -> dict[str, float]:
    """{reward_scale, reward_shift} of the runs: the bundle's, whose critic learnt in those units (an explicit value
    that differs is an error), else the explicit values, else the env's rule on the (raw) dataset."""
    from proto_brax import envs

    if bundle_meta is not None:  # bundles from before the transform existed trained on raw rewards
        b = {"reward_scale": float(bundle_meta.get("reward_scale", 1.0)),
             "reward_shift": float(bundle_meta.get("reward_shift", 0.0))}
        for k, v in (("reward_scale", args.reward_scale), ("reward_shift", args.reward_shift)):
            if v is not None and not np.isclose(v, b[k]):
                raise ValueError(f"--{k.replace('_', '-')} {v}: the bundle was pretrained with {k} {b[k]:.6g} (its "
                                 f"critic is in those units): drop the flag, or pretrain a bundle with it.")
        return b
    scale, shift = envs.reward_transform(args.env, dataset, args.reward_scale, args.reward_shift)
    return {"reward_scale": scale, "reward_shift": shift}


def _load_checkpoint(path: Path | None, cfg, grid, method_name: str = "proto-sac"):
    """(pretrained, per_run, metadata): one bundle seed is shared by all runs; several are gathered per run."""
    if path is None:
        return None, False, None
    import jax.numpy as jnp

    from proto_brax import checkpoints
    from proto_brax.agents.learner import Pretrained
    from proto_brax.agents.registry import agent
    from proto_brax.envs import make_env

    env = make_env(cfg.env, cfg.backend)
    meta = checkpoints.read_metadata(path)
    checkpoints.validate_bundle(meta, cfg.env, env.observation_size, env.action_size, cfg.net)
    method = get_method(method_name)
    if meta.get("algo") not in method.bundles:
        raise ValueError(f"--algo {method_name} starts from a bundle pretrained with {' or '.join(method.bundles)}, "
                         f"but {path} holds {meta.get('algo')!r}: pass a matching --checkpoint or --pretrain "
                         f"{method.bundles[0]}.")
    state, meta = checkpoints.load_bundle(path)
    algo = agent(cfg.algo)
    value = state.value if algo.value else None
    if algo.value and value is None:
        raise ValueError(f"--algo {method_name} needs a bundle with a value network (IQL); {path} has none.")
    log_alpha = state.log_alpha_sac if algo.temperature else None  # only CQL bundles hold one
    carry = cfg.fidelity.carry_critic_state  # the critic's Adam state and target critic (FIDELITY.md row 5)
    pre = Pretrained(actor=state.actor, critic=state.critic, value=value, log_alpha_sac=log_alpha,
                     critic_target=state.critic_target if carry else None,
                     critic_opt=state.critic_opt if carry else None)
    seeds = list(meta["seeds"])
    if cfg.algo == "off2on":  # the bundle's seeds are one ensemble, shared by every run
        if len(seeds) != cfg.ensemble_size:
            want = " ".join(map(str, range(cfg.ensemble_size)))
            raise ValueError(f"--algo off2on uses the {cfg.ensemble_size} agents of one CQL bundle; {path} has "
                             f"{len(seeds)} seed(s): pretrain with --seeds {want}.")
        return pre, False, meta
    if len(seeds) == 1:
        return jax_tree_index(pre, 0), False, meta
    idx = [seeds.index(s) if s in seeds else s % len(seeds) for s in grid.seeds]
    return jax_tree_index(pre, jnp.asarray(idx)), True, meta


def jax_tree_index(tree, idx):
    import jax

    return jax.tree.map(lambda x: x[idx], tree)


# What a sweep writes into --out (and nothing else): only a directory holding these is replaced by --overwrite.
SWEEP_ENTRIES = frozenset({"config.json", "metrics.jsonl", "summary.json", "state", "report", "tensorboard",
                           "pretrained"})


def _our_temporary(name: str) -> bool:
    """Hidden temporaries of our atomic writes (``.NAME.XXXX.tmp``) and checkpoint saves (``.NAME.tmp-PID``)."""
    return name.startswith(".") and (name.endswith(".tmp") or ".tmp-" in name or ".old-" in name)


def _read_config(out: Path) -> dict | None:
    """``out/config.json`` when it is a sweep's (a JSON object with its ``sweep`` and ``finetune`` records)."""
    try:
        config = json.loads((out / "config.json").read_text())
    except (OSError, ValueError):
        return None
    return config if isinstance(config, dict) and {"sweep", "finetune"} <= set(config) else None


def not_a_sweep(out: Path) -> str | None:
    """Why the existing, non-empty directory ``out`` is not a sweep's output (then --overwrite must not delete it),
    or None when it is one: a sweep's config.json and nothing but what a sweep writes."""
    names = sorted(p.name for p in out.iterdir())
    foreign = [n for n in names if n not in SWEEP_ENTRIES and not _our_temporary(n)]
    shown = ", ".join(foreign[:5] + (["…"] if len(foreign) > 5 else []))
    if foreign:
        return f"it holds {shown}, which a sweep does not write"
    if all(_our_temporary(n) for n in names):
        return None  # a sweep killed before its config.json was complete
    if not (out / "config.json").exists():
        return "it has no config.json"
    if _read_config(out) is None:
        return "its config.json is not a sweep's"
    return None


def layout_record(grid_size: int, devices: list) -> dict:
    """How the grid is laid out over devices: the numbers of a run depend on it (docs/RELIABILITY.md)."""
    n = len(devices)
    padded = -(-grid_size // n) * n
    return {"devices": n, "platform": devices[0].platform, "runs_per_device": padded // n,
            "padding": padded - grid_size}


def _check_out(args: SweepArgs, sweep_cfg: dict, layout: dict | None = None) -> None:
    """Refuse an existing --out unless --resume (same configuration and layout) or --overwrite of a sweep's own
    output; writes nothing (an --overwrite removes the old sweep later, after every check has passed)."""
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"--out {out} is a file, not a directory: choose another --out.")
    if out.exists() and any(out.iterdir()):
        if args.resume:
            old = _read_config(out)
            if old is None:
                raise ValueError(f"--resume: {out} holds no sweep to resume (no readable config.json of a sweep).")
            recorded = with_later_defaults(old["sweep"], sweep_record(SweepArgs()))
            if recorded != sweep_cfg:
                diff = {k: (recorded.get(k), v) for k, v in sweep_cfg.items() if recorded.get(k) != v}
                raise ValueError(f"--resume: the configuration differs from the one in {out}: {diff}.")
            was = old.get("layout")
            if layout is not None and was is not None and was != layout:
                flag = (f"--devices {was['devices']}" if was.get("platform") == "cpu"
                        else f"{was['devices']} {was.get('platform')} device(s)")
                raise ValueError(f"--resume: {out} ran on {was['devices']} {was.get('platform')} device(s) "
                                 f"({was['runs_per_device']} run(s) each), this process has {layout['devices']} "
                                 f"({layout['runs_per_device']} each), which gives other numbers: resume with "
                                 f"{flag}.")
        elif not args.overwrite:
            raise FileExistsError(f"{out} exists: pass --resume to continue it, --overwrite to replace it, "
                                  "or choose another --out.")
        elif why := not_a_sweep(out):
            raise FileExistsError(f"--overwrite: {out} is not a sweep's output ({why}): refusing to delete it; "
                                  "choose another --out.")
    elif args.resume:
        raise FileNotFoundError(f"--resume: nothing to resume in {out}.")


def _prepare_out(args: SweepArgs, config: dict) -> None:
    """Create --out (replacing an old sweep with --overwrite) and write config.json: called once every check of the
    run has passed, so a refused run leaves an old sweep as it was."""
    out = Path(args.out)
    if args.resume:
        return
    if out.exists() and args.overwrite and any(out.iterdir()):
        if why := not_a_sweep(out):  # (checked before; the directory may have changed since)
            raise FileExistsError(f"--overwrite: {out} is not a sweep's output ({why}): refusing to delete it.")
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out / "config.json", strict_json(config))


def episode_stats(env: str, returns, lengths, success_steps=None) -> dict[str, float]:
    """Mean evaluation episode length; on a goal task (``EnvSpec.goal_task``: return 1 at the goal, which ends the
    episode) also the success rate and the mean steps to the goal of the successful episodes (the paper's Fig. 5); on
    a task with a success-step rule (``EnvSpec.success_steps``, Adroit) the success rate by that rule."""
    from proto_brax.envs import get_spec

    spec = get_spec(env)
    returns, lengths = np.asarray(returns), np.asarray(lengths)
    out = {"eval_length": float(lengths.mean())}
    if spec.goal_task:
        success = returns > 0
        out["success_rate"] = float(success.mean())
        out["steps_to_goal"] = float(lengths[success].mean()) if success.any() else float("nan")
    elif spec.success_steps is not None and success_steps is not None:
        out["success_rate"] = float((np.asarray(success_steps) > spec.success_steps).mean())
    return out


def steady_throughput(rows: list[dict], full_updates: int) -> float | None:
    """Mean grid updates/s over the chunks after the first (which includes compilation) whose runs updated at every
    step: a warm-up chunk does fewer updates, or none, in the same time and would under-report it."""
    per_chunk = {r["chunk"]: r["grid_updates_per_s"] for r in rows
                 if r.get("chunk", 0) > 0 and r.get("updates") == full_updates}
    return float(np.mean(list(per_chunk.values()))) if per_chunk else None


def _rows(chunk: int, m: dict, grid, env: str, updates_per_s: float) -> list[dict]:
    from proto_brax.envs import normalized_score

    scalar_keys = [k for k, v in m.items() if np.ndim(v) == 1]
    rows = []
    for i, point in enumerate(grid.points):
        row = {"chunk": chunk, "run": i, **point}
        row.update({k: float(m[k][i]) for k in scalar_keys})
        row["step"] = int(m["step"][i])
        row["normalized_score"] = float(normalized_score(env, row["eval_return"]))
        row["eval_returns"] = [float(x) for x in m["eval_returns"][i]]
        row.update(episode_stats(env, m["eval_returns"][i], m["eval_lengths"][i], m["eval_success_steps"][i]))
        row["diverged"] = not all(np.isfinite(row[k]) for k in ("eval_return", "critic_loss", "q_mean"))
        row["grid_updates_per_s"] = updates_per_s
        rows.append(row)
    return rows


def _tensorboard_writers(out: Path, grid):
    try:
        from tensorboardX import SummaryWriter
    except ImportError as e:
        raise ImportError("--tensorboard needs tensorboardX: pip install 'proto_brax[tensorboard]'") from e
    writers = []
    for i, point in enumerate(grid.points):
        w = SummaryWriter(str(out / "tensorboard" / f"run_{i:03d}"))
        w.add_text("hparams", json.dumps(point))
        writers.append(w)
    return writers


def _write_tensorboard(writers, rows: list[dict]) -> None:
    for r in rows:
        for k, v in r.items():
            if isinstance(v, float) and k not in ("tau", "eta", "alpha0", "anneal_horizon"):
                writers[r["run"]].add_scalar(k, v, r["step"])
        writers[r["run"]].flush()


def _truncate_metrics(path: Path, chunks_done: int, runs: int | None = None) -> None:
    """Keep the rows of the checkpointed chunks (those before ``chunks_done``, and π₀'s): rows logged after the last
    checkpoint (a crash between the two) and a torn last line (a crash inside an append) are dropped; their chunks
    are re-run from the checkpoint. With ``runs``, every kept chunk must hold that many rows."""
    if not path.exists():
        return
    rows, torn = read_jsonl(path)
    keep = [r for r in rows if r["chunk"] < chunks_done]
    if torn:
        print(f"{path}: dropped a torn last line (a crash during an append); its chunk is re-run", flush=True)
    if runs is not None and chunks_done > 0:
        counts = {c: 0 for c in range(-1, chunks_done)}
        for r in keep:
            counts[r["chunk"]] = counts.get(r["chunk"], 0) + 1
        short = {c: n for c, n in counts.items() if n != runs}
        if short:
            raise ValueError(f"--resume: {path} lacks rows of checkpointed chunks ({short} rows, {runs} expected per "
                             "chunk): the file was damaged; rerun the sweep with --overwrite.")
    write_text_atomic(path, "".join(json.dumps(strict_json(r), allow_nan=False) + "\n" for r in keep))


def _append_rows(path: Path, rows: list[dict]) -> None:
    """One chunk's rows as strict JSON lines (NaN -> null), appended in one write: a kill leaves all or none."""
    append_once(path, "".join(json.dumps(strict_json(r), allow_nan=False) + "\n" for r in rows))


def lowest_early_scores(runs: list[list[dict]], fraction: float = 0.1) -> list[float]:
    """The paper's initial drop, per run (its evaluation rows after step 0, sorted by step): the lowest normalized
    score within the first ``fraction`` of the online steps (of the longest run), or the first evaluation's score
    where none falls inside."""
    horizon = max(r["step"] for rs in runs for r in rs)
    return [min([r["normalized_score"] for r in rs if r["step"] <= fraction * horizon] or [rs[0]["normalized_score"]])
            for rs in runs]


def summarize_runs(rows: list[dict], grid_keys: list[str]) -> list[dict]:
    """Per grid point (over seeds): final and average return/normalized score with mean ± std and IQM [95% CI]."""
    from proto_brax.analysis.stats import summarize

    by_point: dict[tuple, dict[int, list[dict]]] = {}
    for r in rows:
        by_point.setdefault(tuple(r[k] for k in grid_keys), {}).setdefault(r["seed"], []).append(r)
    out = []
    for point, seeds in by_point.items():
        initial = [[r for r in rs if r.get("initial")] for rs in seeds.values()]
        runs = [sorted((r for r in rs if not r.get("initial")), key=lambda r: r["step"]) for rs in seeds.values()]
        rec = dict(zip(grid_keys, point))
        rec["seeds"] = sorted(seeds)
        rec["diverged_seeds"] = sorted(s for s, rs in seeds.items() if any(r["diverged"] for r in rs))
        for key in ("eval_return", "normalized_score"):
            rec[f"final_{key}"] = summarize([rs[-1][key] for rs in runs])
            rec[f"average_{key}"] = summarize([np.mean([r[key] for r in rs]) for rs in runs])
        rec["final_dev_pi0"] = summarize([rs[-1]["dev_pi0"] for rs in runs])
        if all("success_rate" in rs[-1] for rs in runs):  # goal tasks and Adroit: success rate
            rec["final_success_rate"] = summarize([rs[-1]["success_rate"] for rs in runs])
        if all("steps_to_goal" in rs[-1] for rs in runs):  # goal tasks: the paper's steps to the goal (Fig. 5)
            rec["final_steps_to_goal"] = summarize([rs[-1]["steps_to_goal"] for rs in runs])
        if all(initial):  # π₀ at step 0, and the initial drop: the lowest score within the first 10% of the run
            rec["initial_normalized_score"] = summarize([i[0]["normalized_score"] for i in initial])
            rec["min_normalized_first_10pct"] = summarize(lowest_early_scores(runs))
        out.append(rec)
    return out


def print_table(summary: list[dict], grid_keys: list[str]) -> None:
    head = " ".join(f"{k:>8}" for k in grid_keys)
    print(f"\n{head} | {'final return':>20} | {'IQM [95% CI]':>26} | {'norm. score':>14} | diverged")
    for rec in summary:
        f = rec["final_eval_return"]
        n = rec["final_normalized_score"]
        vals = " ".join(f"{rec[k]:>8.4g}" for k in grid_keys)
        print(f"{vals} | {f['mean']:>9.1f} ± {f['std']:>8.1f} | {f['iqm']:>8.1f} [{f['iqm_low']:>7.1f}, "
              f"{f['iqm_high']:>7.1f}] | {n['mean']:>6.1f} ± {n['std']:>5.1f} | {rec['diverged_seeds'] or '-'}")


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
RUN_ONLY_FIELDS = ("out", "overwrite", "resume", "devices", "report", "tensorboard", "distributed", "coordinator",
                   "num_processes", "process_id", "debug")


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


@dataclasses.dataclass
class Plan:
    """A checked sweep, ready to run: everything a run needs, built before --out is touched."""

    args: SweepArgs
    cfg: Any  # FinetuneConfig
    axes: dict[str, list[float]]
    grid: Any  # train.grid.Grid
    ft: Any  # train.online.Finetune (None until --pretrain has made its bundle)
    pretrained: Any
    per_run: bool  # bundle seeds gathered per run (else one shared)
    dataset: Any
    dataset_name: str | None
    config: dict  # config.json
    lead: bool  # this process writes the outputs (process 0)


def plan_sweep(args: SweepArgs) -> Plan:
    """Every check of the command line, the bundle and the dataset, then the compiled-to-be program and config.json's
    record; nothing is written."""
    from proto_brax.train.grid import make_grid

    validate_args(args)
    cfg = _finetune_config(args)
    method = get_method(args.algo)
    axes = grid_axes(args)
    base = {"anneal_horizon": float(args.anneal_horizon or args.steps), **method.hp, **args.hp}
    grid = make_grid(axes, list(args.seeds), base=base)  # validated before anything compiles
    sweep_cfg = sweep_record(args)
    import jax

    lead = jax.process_index() == 0  # with --distributed, process 0 writes; the others compute their shards
    layout = {**layout_record(grid.size, jax.devices()), "processes": jax.process_count()}
    if lead:  # (another process must not look at --out: process 0 may have created it already)
        _check_out(args, sweep_cfg, layout)
    if jax.process_count() > 1 and args.resume:
        raise ValueError("--resume is not supported across several processes yet: resume on one host.")
    dataset_name = resolve_dataset(args)
    ckpt = resolve_checkpoint(args)
    if args.pretrain is not None and (dataset_name is None or args.checkpoint not in ("auto", "none")):
        raise ValueError("--pretrain needs --dataset (the data to pretrain on) and no --checkpoint.")
    if args.pretrain is not None and args.pretrain not in method.bundles:
        raise ValueError(f"--algo {args.algo} cannot start from a {args.pretrain} bundle: --pretrain "
                         f"{' or '.join(method.bundles) or '(none: it starts from a random init)'}.")
    # The bundle is validated (and loaded: a few MB) before any dataset is built or read.
    pretrained, per_run, bmeta = _load_checkpoint(None if args.pretrain else ckpt, cfg, grid, args.algo)
    from proto_brax.checkpoints import bundle_dataset_record, regenerated_note, validate_bundle_dataset
    from proto_brax.data.generate import dataset_names

    if bmeta is not None and dataset_name in dataset_names():  # by name, before a registered dataset is built;
        validate_bundle_dataset(bmeta, dataset_name)  # a file or Minari id may hold the bundle's rows: by content
    dataset, dmeta = _load_dataset(dataset_name, args.dataset_size)  # non-finite values are refused here
    if bmeta is not None and dataset_name is not None:
        validate_bundle_dataset(bmeta, dataset_name, (dmeta or {}).get("content_hash"))
    from proto_brax.agents.registry import agent
    from proto_brax.data.dataset import validate_for_env
    from proto_brax.train.online import make_finetune

    if dataset is not None:  # every check of the data before --out is touched
        from proto_brax.envs import make_env

        env = make_env(cfg.env, cfg.backend)
        validate_for_env(dataset, env.observation_size, env.action_size, str(dataset_name), env_name=cfg.env)
        if agent(cfg.algo).mc_returns and np.unique(np.asarray(grid.hparams.gamma)).size != 1:
            raise ValueError(f"--algo {args.algo} computes the dataset's returns-to-go once: use one gamma.")
    if args.pretrain is None:
        cfg = dataclasses.replace(cfg, **reward_transform(args, bmeta, dataset))
    ft = make_finetune(cfg) if args.pretrain is None else None  # (errors surface here, before --out is written)
    config = {"sweep": sweep_cfg, "method": dataclasses.asdict(method), "finetune": dataclasses.asdict(cfg),
              "grid": list(grid.points),
              "layout": layout,
              "dataset_metadata": dmeta,
              "checkpoint_metadata": bmeta}
    if bmeta is not None and dmeta is not None:
        config["dataset_vs_bundle"] = bundle_dataset_record(bmeta, dmeta)
        if note := regenerated_note(config["dataset_vs_bundle"]):
            print(note, flush=True)
    return Plan(args=args, cfg=cfg, axes=axes, grid=grid, ft=ft, pretrained=pretrained, per_run=per_run,
                dataset=dataset, dataset_name=dataset_name, config=config, lead=lead)


def pretrain_into_out(plan: Plan) -> Plan:
    """--pretrain: the bundle in OUT/pretrained (one bundle seed per run seed; a resumed sweep reuses it), then the
    finetuning program from it."""
    from proto_brax.checkpoints import bundle_dataset_record
    from proto_brax.pretrain import PretrainArgs, pretrain
    from proto_brax.train.online import make_finetune

    args, cfg = plan.args, plan.cfg
    bundle = Path(args.out) / "pretrained"
    if not (bundle / "metadata.json").exists():
        # Off2On's ensemble is the bundle's seeds (shared by every run); otherwise one bundle seed per run seed.
        seeds = tuple(range(cfg.ensemble_size)) if cfg.algo == "off2on" else tuple(args.seeds)
        pretrain(PretrainArgs(dataset=plan.dataset_name, dataset_size=args.dataset_size, algo=args.pretrain,
                              env=args.env, seeds=seeds,
                              steps=args.pretrain_steps, log_every=min(10_000, args.pretrain_steps),
                              hidden=tuple(args.hidden), critic_layer_norm=cfg.net.critic_layer_norm,
                              policy=cfg.net.policy,
                              reward_scale=args.reward_scale, reward_shift=args.reward_shift,
                              hp=dict(args.pretrain_hp),
                              out=bundle, overwrite=True))
    pretrained, per_run, bmeta = _load_checkpoint(bundle, cfg, plan.grid, args.algo)
    cfg = dataclasses.replace(cfg, **reward_transform(args, bmeta, plan.dataset))
    config = {**plan.config, "checkpoint_metadata": bmeta, "finetune": dataclasses.asdict(cfg),
              "dataset_vs_bundle": bundle_dataset_record(bmeta, plan.config["dataset_metadata"])}
    if plan.lead:
        write_json_atomic(Path(args.out) / "config.json", strict_json(config))
    return dataclasses.replace(plan, cfg=cfg, ft=make_finetune(cfg), pretrained=pretrained, per_run=per_run,
                               config=config)


def train_dataset(plan: Plan):
    """The offline data as the runs train on it: rewards transformed, Cal-QL's returns-to-go, on the device."""
    import jax

    from proto_brax.agents.registry import agent
    from proto_brax.data.dataset import transform_rewards, with_returns_to_go

    cfg, dataset = plan.cfg, plan.dataset
    if dataset is None:
        return None
    dataset = transform_rewards(dataset, cfg.reward_scale, cfg.reward_shift)
    if agent(cfg.algo).mc_returns:  # Cal-QL's calibration bound: returns-to-go with the runs' γ
        dataset = with_returns_to_go(dataset, float(np.asarray(plan.grid.hparams.gamma)[0]))
    return jax.tree.map(jax.numpy.asarray, dataset)


def execute(plan: Plan) -> float | None:
    """Run (or resume) the grid chunk by chunk: progress, metrics rows, resume checkpoints. Returns the seconds of
    the first chunk run (compilation included), None when nothing was left to run."""
    import jax
    from tqdm import tqdm

    from proto_brax import __version__, checkpoints
    from proto_brax.train.grid import compile_grid, grid_mesh, padded_size, run_grid

    args, cfg, grid, lead = plan.args, plan.cfg, plan.grid, plan.lead
    dataset = train_dataset(plan)
    mesh = grid_mesh()
    out = Path(args.out)
    metrics_path = out / "metrics.jsonl"
    print(f"grid: {grid.size} runs ({' × '.join(f'{k} {len(v)}' for k, v in plan.axes.items())} × "
          f"{len(args.seeds)} seeds), padded to {padded_size(grid.size, mesh)} over {mesh.devices.size} device(s) "
          f"{[d.platform for d in mesh.devices.flat]}; {cfg.steps} steps per run", flush=True)

    def restore(state):
        latest = checkpoints.latest_step(out / "state") if args.resume else None
        if latest is None:
            _truncate_metrics(metrics_path, -1)  # nothing checkpointed yet: start over, dropping every logged row
            return state, 0
        state, meta = checkpoints.restore(latest, state)
        _truncate_metrics(metrics_path, meta["chunks_done"], runs=grid.size)
        print(f"resumed after chunk {meta['chunks_done']} of {cfg.num_chunks}", flush=True)
        bar.update(meta["chunks_done"] * cfg.eval_every)
        return state, meta["chunks_done"]

    tb = _tensorboard_writers(out, grid) if args.tensorboard and lead else None
    bar = tqdm(total=cfg.steps, unit="step", desc="sweep", dynamic_ncols=True, file=sys.stdout)
    timing = {"t": time.time(), "first": None}

    def on_chunk(c, m, state):
        now = time.time()
        dt = now - timing["t"]
        if timing["first"] is None:
            timing["first"] = dt  # includes compilation
        updates_per_s = float(np.sum(m["updates"])) / dt
        rows = _rows(c, m, grid, cfg.env, updates_per_s)
        bar.update(cfg.eval_every)
        timing["t"] = time.time()
        if not lead:
            return
        _append_rows(metrics_path, rows)
        if tb is not None:
            _write_tensorboard(tb, rows)
        if jax.process_count() == 1:  # across hosts the state is not gathered to one place: no resume checkpoints
            checkpoints.save_step(out / "state", c + 1, state, {"chunks_done": c + 1, "version": __version__})
        finite = [r["eval_return"] for r in rows if np.isfinite(r["eval_return"])]
        bar.set_postfix(eval=f"{np.mean(finite) if finite else float('nan'):.1f}", upd_s=f"{updates_per_s:.0f}")

    program = compile_grid(plan.ft, mesh, plan.per_run)

    def on_start(stats):
        """π₀ at step 0 (chunk −1): the reference of the initial drop; curves start there."""
        if not lead:
            return
        from proto_brax.envs import normalized_score

        returns, lengths, success_steps = stats
        rows = [{"chunk": -1, "run": i, **point, "step": 0, "eval_return": float(np.mean(returns[i])),
                 "eval_returns": [float(x) for x in returns[i]],
                 "normalized_score": float(normalized_score(cfg.env, float(np.mean(returns[i])))),
                 **episode_stats(cfg.env, returns[i], lengths[i], success_steps[i]),
                 "diverged": not bool(np.all(np.isfinite(returns[i]))), "initial": True,
                 "dev_pi0": 0.0, "dev_pibar": 0.0, "grid_updates_per_s": float("nan")}
                for i, point in enumerate(grid.points)]
        _append_rows(metrics_path, rows)
        if tb is not None:
            _write_tensorboard(tb, rows)

    run_grid(plan.ft, grid, plan.pretrained, dataset, mesh=mesh, program=program, callback=on_chunk,
             restore=restore, on_start=on_start, per_run_pretrained=plan.per_run)
    bar.close()
    if tb is not None:
        for w in tb:
            w.close()
    return timing["first"]


def summarize(plan: Plan, first_chunk_seconds: float | None) -> list[dict]:
    """summary.json, the results table, the throughput line and the PNG report from metrics.jsonl."""
    args, cfg, axes = plan.args, plan.cfg, plan.axes
    out = Path(args.out)
    rows, _ = read_jsonl(out / "metrics.jsonl")  # (null, as the file stores NaN, read back as NaN)
    grid_keys = [k for k in axes if len(axes[k]) > 1] or ["tau"]
    summary = summarize_runs(rows, grid_keys)
    write_json_atomic(out / "summary.json", strict_json({
        "grid_keys": grid_keys, "points": summary, "env": cfg.env, "steps": cfg.steps, "method": args.algo,
        "dataset": plan.dataset_name,
        "first_chunk_seconds_incl_compile": first_chunk_seconds,
    }))
    print_table(summary, grid_keys)
    steady = steady_throughput(rows, cfg.eval_every * cfg.updates_per_step)
    throughput = f"{steady:.0f} updates/s over the grid" if steady else "not measured (no full chunk after the first)"
    if first_chunk_seconds is None:
        print(f"\nno chunk left to run: the sweep in {out} was complete; steady throughput {throughput}")
    else:
        print(f"\ncompile + first chunk: {first_chunk_seconds:.1f} s; steady throughput {throughput}")
    if args.report:
        from proto_brax.report import make_report

        make_report([out], out / "report", verbose=False)
    print(f"\nwrote {out}/config.json, metrics.jsonl ({len(rows)} rows), summary.json"
          + (", report/ (PNG plots)" if args.report else ""))
    return summary


def run_sweep(args: SweepArgs) -> list[dict]:
    """Plan (every check, nothing written), prepare --out, pretrain (--pretrain), run (or resume) the grid, summarize;
    returns the per-point summary (empty on processes other than 0)."""
    plan = plan_sweep(args)
    if plan.lead:
        _prepare_out(args, plan.config)
    if args.pretrain is not None:
        plan = pretrain_into_out(plan)
    first = execute(plan)
    return summarize(plan, first) if plan.lead else []


PRESETS: dict[str, tuple[str, dict]] = {
    "smoke": ("tiny CPU smoke sweep on the point task (seconds)", dict(
        env="point", dataset="none", tau=(0.0, 0.005), eta=(0.9,), alpha0=(0.0, 2.0), seeds=(0, 1), steps=1_000,
        eval_every=500,
        eval_episodes=2, hidden=(32, 32), batch_size=32, learning_starts=100)),
    "paper-mujoco": ("PROTO paper, MuJoCo: τ 5e-3, η 0.9, α₀ 2, 10⁶ steps annealed over 10⁶, 5 seeds, eval 10×5k", dict(
        tau=(5e-3,), eta=(0.9,), alpha0=(2.0,), seeds=(0, 1, 2, 3, 4), steps=1_000_000, eval_every=5_000,
        eval_episodes=10, anneal_horizon=1e6, learning_starts=1_000)),
    "paper-mujoco-100k": ("reduced-scale paper-mujoco: 10⁵ steps, α annealed over the same fraction (N = 10⁵)", dict(
        tau=(5e-3,), eta=(0.9,), alpha0=(2.0,), seeds=(0, 1, 2, 3, 4), steps=100_000, eval_every=5_000,
        eval_episodes=10, anneal_horizon=1e5, learning_starts=1_000)),
    "paper-antmaze": ("PROTO paper, AntMaze (reference script): antmaze-medium(-diverse), τ 5e-5, η 0.9, α₀ 0.5, no "
                      "value-regularization backup, no clipped double-Q, 10⁶ steps, 5 seeds, eval 100×50k, EQL 2·10⁵",
                      dict(env="antmaze-medium", dataset="auto", dataset_size=1_000_000, tau=(5e-5,), eta=(0.9,),
                           alpha0=(0.5,), seeds=(0, 1, 2, 3, 4), steps=1_000_000, eval_every=50_000,
                           eval_episodes=100, anneal_horizon=1e6, learning_starts=1_000, value_reg_backup=False,
                           clipped_double_q=False, pretrain_steps=200_000, pretrain_hp={"alpha": 0.5})),
    # Adroit's offline data are D4RL's human demonstrations, which cannot be generated: the preset names D4RL's pen
    # file through Minari (loaded from the user's Minari cache; --dataset PATH or another Minari id for door/hammer).
    "paper-adroit": ("PROTO paper, Adroit: pen from D4RL's human data (Minari D4RL/pen/human-v2, user-supplied), "
                     "τ 5e-5, η 0.9, α₀ 2, no value-regularization backup, clipped double-Q, 10⁶ steps, 5 seeds, "
                     "eval 10×5k, EQL 10⁵",
                     dict(env="pen", dataset="D4RL/pen/human-v2", tau=(5e-5,), eta=(0.9,), alpha0=(2.0,),
                          seeds=(0, 1, 2, 3, 4), steps=1_000_000, eval_every=5_000, eval_episodes=10,
                          anneal_horizon=1e6, learning_starts=1_000, value_reg_backup=False, clipped_double_q=True,
                          pretrain_steps=100_000)),
}


def sweep_args(algo: str = "proto-sac", preset: str | None = None, **overrides) -> SweepArgs:
    """The Python API's equivalent of ``--preset PRESET --algo ALGO --FIELD VALUE…``."""
    args = SweepArgs()
    if preset is not None:
        if preset not in PRESETS:
            raise ValueError(f"Unknown preset {preset!r}: choose one of {sorted(PRESETS)}.")
        args = dataclasses.replace(args, **PRESETS[preset][1])
    return dataclasses.replace(args, algo=algo, **{**get_method(algo).defaults, **overrides})


def _flag_value(argv: list[str], flag: str) -> str | None:
    for i, a in enumerate(argv):
        if a == flag:
            return argv[i + 1] if i + 1 < len(argv) else ""
        if a.startswith(flag + "="):
            return a.split("=", 1)[1]
    return None


def parse_args(argv: list[str] | None = None) -> SweepArgs:
    """tyro CLI. ``--preset NAME`` then ``--algo NAME`` set the defaults that the other flags override."""
    import tyro

    argv = list(sys.argv[1:] if argv is None else argv)
    from proto_brax.startup import refuse_repeated

    refuse_repeated(argv, ("--hp", "--pretrain-hp"))
    defaults = SweepArgs()
    if "--preset" in argv:
        i = argv.index("--preset")
        if i + 1 >= len(argv) or argv[i + 1] not in PRESETS:
            names = ", ".join(f"{k} ({v[0]})" for k, v in PRESETS.items())
            raise SystemExit(f"--preset needs one of: {names}")
        defaults = dataclasses.replace(SweepArgs(), **PRESETS[argv[i + 1]][1])
        del argv[i:i + 2]
    algo = _flag_value(argv, "--algo")
    description = f"{SweepArgs.__doc__}"
    if algo is not None:
        if algo not in METHODS:
            raise SystemExit(f"--algo needs one of: {describe()}")
        method = METHODS[algo]
        defaults = dataclasses.replace(defaults, algo=algo, **method.defaults)
        description += f" --algo {algo}: {method.summary}." + (
            f" Its hyper-parameters under --hp: {method.hp}." if method.hp else "")
    presets = "; ".join(f"{k}: {v[0]}" for k, v in PRESETS.items())
    description += f" Presets (--preset NAME, before other flags): {presets}."
    if "-h" in argv or "--help" in argv:  # the registry imports Brax: only when help is shown
        from proto_brax.envs import REGISTRY

        description += f" Envs (--env): {', '.join(REGISTRY)}."
    return tyro.cli(SweepArgs, default=defaults, args=argv, description=description)


def start_distributed(args: SweepArgs) -> None:
    """jax.distributed.initialize() from the flags, each missing one left to jax's cluster detection (SLURM, Open
    MPI, JAX_COORDINATOR_ADDRESS)."""
    import jax

    kw = {k: v for k, v in (("coordinator_address", args.coordinator), ("num_processes", args.num_processes),
                            ("process_id", args.process_id)) if v is not None}
    if args.coordinator is not None and (args.num_processes is None or args.process_id is None):
        raise ValueError("--coordinator needs --num-processes N and --process-id I too (the same command on every "
                         "process, each with its own --process-id).")
    jax.distributed.initialize(**kw)


def main(argv: list[str] | None = None) -> None:
    def run() -> None:
        args = parse_args(argv)
        validate_args(args)  # before any backend starts
        # Before JAX initializes its backend: host devices for sharding on CPU, and the scheduler fix MJX needs.
        from proto_brax import envs
        from proto_brax.train.grid import use_host_devices

        if (args.backend or envs.get_spec(args.env).default_backend) == "mjx":
            os.environ["XLA_FLAGS"] = envs.mjx_xla_flags()
        if args.distributed or args.coordinator is not None:
            if args.devices is not None:  # (use_host_devices would start the backend: initialize() must come first)
                import jax

                jax.config.update("jax_num_cpu_devices", args.devices)
            start_distributed(args)
        else:
            use_host_devices(args.devices)
        run_sweep(args)

    exit_on_input_error(run, argv)


if __name__ == "__main__":
    from proto_brax.startup import quiet_start

    quiet_start()
    main()
