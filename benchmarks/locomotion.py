"""Reduced-scale reproduction of the PROTO paper on Brax locomotion: every (dataset, method) sweep, resumable.

    python benchmarks/locomotion.py run                     # all pending sweeps, in order, each resumable
    python benchmarks/locomotion.py run --datasets hopper-medium --methods proto-sac frozen
    python benchmarks/locomotion.py run --methods ablate-tau ablate-eta   # the appendix's τ and η ablations
    python benchmarks/locomotion.py status                  # what is done, running or missing

Each (dataset, method) is one ``python -m proto_brax.sweep --preset paper-mujoco-100k --algo METHOD`` over the seeds,
with the online budget ``--steps`` (α annealed over the same fraction of the run as the paper's 10⁶: the annealing
horizon equals the budget) from the committed bundle of the method's kind (``--checkpoint auto``), on the full 10⁶-row
dataset. Runs go to ``$PROTO_BRAX_RUNS/locomotion/DATASET/METHOD`` (default ``~/.cache/proto_brax/runs``: outside
the work tree, so a later checkout on the same machine resumes them) with ``--resume``, so killing this script and
running it again continues where it stopped; a finished sweep's ``summary.json``, ``config.json`` and gzipped
``metrics.jsonl`` are copied to ``benchmarks/results/locomotion/DATASET/METHOD/``. Methods whose bundle kind is not
committed for a dataset are skipped with the command that makes the bundle.

A method that trains on no dataset (``sac-scratch``) gives the same runs on every dataset of an env: it is swept once
per env, and its published sweep is copied to the env's other datasets (``results_md.py`` counts it once).

The ablations (the paper's appendix: τ ∈ {0.5, 1, 2} × τ₀ and η ∈ {0.8, 0.9, 1.0}) are the pseudo-methods
``ablate-tau`` and ``ablate-eta``, run on ``--ablation-datasets`` only: one PROTO-SAC sweep each over the two
non-default values × the seeds in one vmapped program; the default value is the ``proto-sac`` sweep itself.
"""

from __future__ import annotations

import dataclasses
import gzip
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Literal

import _quiet  # noqa: F401  (first: the quiet start)
import tyro

from proto_brax.agents.registry import METHODS, pretrain_flags
from proto_brax.analysis.locomotion_plan import ABLATIONS, DATASETS, PAPER_METHODS, PRESET, method_of
from proto_brax.envs import single_thread_xla_flags
from proto_brax.files import atomic_write, copy_atomic, nan_for_null

ROOT = Path(__file__).resolve().parents[1]

@dataclasses.dataclass
class Args:
    action: tyro.conf.Positional[Literal["run", "status"]] = "run"
    datasets: tuple[str, ...] = DATASETS
    methods: tuple[str, ...] = PAPER_METHODS + tuple(ABLATIONS)
    ablation_datasets: tuple[str, ...] = ("hopper-medium", "walker2d-medium", "halfcheetah-medium")
    """Where ``ablate-tau`` / ``ablate-eta`` run (the paper's appendix ablates on three datasets)."""
    seeds: tuple[int, ...] = (0, 1, 2, 3, 4)
    steps: int = 50_000  # online budget per run (paper: 10⁶); stated in every summary
    eval_every: int = 2_500
    """Evaluation period (paper: 5k of 10⁶). At the reduced budget, 2.5k puts two evaluations (2.5k, 5k) inside the
    first 10% of the run, where the initial drop is measured."""
    runs: Path = Path(os.environ.get("PROTO_BRAX_RUNS", Path.home() / ".cache" / "proto_brax" / "runs")) / "locomotion"
    """Working sweeps (resume state): outside the work tree, so that a later checkout on the same machine resumes them
    ($PROTO_BRAX_RUNS, default ~/.cache/proto_brax/runs)."""
    results: Path = ROOT / "benchmarks" / "results" / "locomotion"
    single_core: bool = False
    """Each sweep on one CPU device with one XLA thread (``--devices 1``, ``envs.single_thread_xla_flags``): for two
    runners side by side on a 2-core machine, where two single-threaded processes do more updates per second in total
    than two sharded ones (FACTS.md) and 5 seeds need no padding run. A started sweep resumes only under the setting
    it started with (its state's padding follows the device count)."""


def sweep_command(dataset: str, method: str, args: Args, resume: bool) -> list[str]:
    env = dataset.split("-")[0]
    m = method_of(method)
    cmd = [sys.executable, "-m", "proto_brax.sweep", "--preset", PRESET, "--algo", m.name,
           "--env", env, "--seeds", *map(str, args.seeds), "--steps", str(args.steps),
           "--eval-every", str(args.eval_every), "--anneal-horizon", str(float(args.steps)),
           "--out", str(args.runs / dataset / method)]
    if method in ABLATIONS:
        flag, values = ABLATIONS[method]
        cmd += [flag, *map(str, values)]
    if m.uses_dataset:
        cmd += ["--dataset", dataset, "--dataset-size", "1000000"]
    if args.single_core:
        cmd += ["--devices", "1"]
    return cmd + (["--resume"] if resume else [])


def sweep_env(args: Args) -> dict[str, str]:
    """The sweep's environment: with ``single_core``, one XLA thread."""
    env = dict(os.environ)
    if args.single_core:
        env["XLA_FLAGS"] = single_thread_xla_flags()
    return env


def missing_bundle(dataset: str, method: str) -> str | None:
    m = method_of(method)
    if not m.bundles:
        return None
    kind = m.bundles[0]
    if (ROOT / "checkpoints" / "pretrained" / dataset / (kind + m.bundle_suffix) / "metadata.json").exists():
        return None
    extra = "".join(f" {f}" for f in pretrain_flags(m.defaults.get("policy", "tanh_gaussian"),
                                                     m.defaults.get("pretrain_hp")))
    return (f"python -m proto_brax.pretrain --dataset {dataset} --algo {kind}{extra} --out "
            f"checkpoints/pretrained/{dataset}/{kind + m.bundle_suffix}")


def publish(dataset: str, method: str, args: Args) -> None:
    """Copy a finished sweep to the results tree; summary.json goes last, as it marks the sweep done."""
    src, dst = args.runs / dataset / method, args.results / dataset / method
    dst.mkdir(parents=True, exist_ok=True)
    copy_atomic(src / "config.json", dst / "config.json")
    with open(src / "metrics.jsonl", "rb") as f, atomic_write(dst / "metrics.jsonl.gz", "wb") as raw, \
            gzip.GzipFile(fileobj=raw, mode="wb", filename="", mtime=0) as g:  # mtime 0: same bytes on a rerun
        shutil.copyfileobj(f, g)
    for f in sorted((src / "report").rglob("*")):  # the sweep's report PNGs (none when it made no report)
        if f.is_file():
            copy_atomic(f, dst / "report" / f.relative_to(src / "report"))
    copy_atomic(src / "summary.json", dst / "summary.json")


def shared_sweep(dataset: str, method: str, args: Args) -> Path | None:
    """A published sweep of a dataset-free method on another dataset of the same env, which this dataset shares."""
    if method not in METHODS or METHODS[method].uses_dataset:
        return None
    env = dataset.split("-")[0]
    found = [args.results / d / method for d in DATASETS
             if d != dataset and d.split("-")[0] == env and (args.results / d / method / "summary.json").exists()]
    return found[0] if found else None


def main(args: Args) -> None:
    unknown = [m for m in args.methods if m not in METHODS and m not in ABLATIONS]
    if unknown:
        raise SystemExit(f"unknown --methods {unknown}: choose from {sorted(METHODS)} or {sorted(ABLATIONS)}.")
    for dataset in args.datasets:
        for method in args.methods:
            if method in ABLATIONS and dataset not in args.ablation_datasets:
                continue
            out = args.runs / dataset / method
            done = (args.results / dataset / method / "summary.json").exists()
            need = missing_bundle(dataset, method)
            if args.action == "status":
                shared = None if done else shared_sweep(dataset, method, args)
                state = "done" if done else ("needs bundle: " + need if need else
                                             f"shared: copies {shared.parent.name}'s on run" if shared else
                                             ("started" if out.exists() else "pending"))
                print(f"{dataset:28s} {method:12s} {state}")
                continue
            if done:
                continue
            if need:
                print(f"skip {dataset} {method}: no bundle ({need})", flush=True)
                continue
            if (src := shared_sweep(dataset, method, args)) is not None:
                dst, tmp = args.results / dataset / method, args.results / dataset / f".{method}.tmp"
                shutil.rmtree(tmp, ignore_errors=True)
                shutil.copytree(src, tmp)
                shutil.rmtree(dst, ignore_errors=True)  # an unfinished publish (no summary.json) of its own
                tmp.replace(dst)
                print(f"{dataset} {method}: the same runs as {src.parent.name} (trains on no dataset)", flush=True)
                continue
            if not (out / "summary.json").exists():  # else finished but not published (the runner was stopped)
                resume = (out / "config.json").exists()
                cmd = sweep_command(dataset, method, args, resume)
                print(f"[{time.strftime('%H:%M:%S')}] {' '.join(cmd[1:])}", flush=True)
                if subprocess.run(cmd, cwd=ROOT, env=sweep_env(args)).returncode != 0:
                    print(f"FAILED: {dataset} {method}", flush=True)
                    continue
            publish(dataset, method, args)
            summary = nan_for_null(json.loads((out / "summary.json").read_text()))  # a diverged run's null
            for point in summary["points"]:
                where = " ".join(f"{k} {point[k]:g}" for k in summary["grid_keys"])
                print(f"  {where}: final normalized {point['final_normalized_score']['mean']:.1f} ± "
                      f"{point['final_normalized_score']['std']:.1f}", flush=True)


if __name__ == "__main__":
    main(tyro.cli(Args))
