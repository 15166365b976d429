"""Reduced-scale reproduction of the PROTO paper on Brax locomotion (and Adroit, AntMaze with ``--domain``): every
(dataset, method) sweep, resumable.

    python benchmarks/locomotion.py run                     # all pending sweeps, in order, each resumable
    python benchmarks/locomotion.py status --domain adroit  # pen/door/hammer-human: PROTO, Frozen, direct, IQL
    python benchmarks/locomotion.py run --datasets hopper-medium --methods proto-sac frozen
    python benchmarks/locomotion.py run --methods ablate-tau ablate-eta   # the appendix's τ and η ablations
    python benchmarks/locomotion.py status                  # what is done, running or missing
    python benchmarks/locomotion.py run --per-seed --seeds 0 1 --methods rlpd-utd1 --datasets halfcheetah-medium
                                         # seed by seed: each part lands alone, merged once seeds 0-4 are in

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
FIDELITY.md's rows are ablated one at a time by the pseudo-methods ``official-but-*`` (``FIDELITY_ABLATIONS``: the
``proto-official`` sweep with one choice put back to ours), run only when named, on ``--ablation-datasets``:

    python benchmarks/locomotion.py run --per-seed --methods official-but-temperature --ablation-datasets
        halfcheetah-medium --datasets halfcheetah-medium
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import time
from pathlib import Path
from typing import Literal

import _quiet  # noqa: F401  (first: the quiet start)
import tyro

from proto_brax.agents.registry import METHODS
from proto_brax.analysis import locomotion_plan as plan
from proto_brax.analysis.locomotion_plan import ABLATIONS
from proto_brax.files import nan_for_null

ROOT = Path(__file__).resolve().parents[1]
PRETRAINED = ROOT / "checkpoints" / "pretrained"


@dataclasses.dataclass
class Args:
    action: tyro.conf.Positional[Literal["run", "status"]] = "run"
    domain: Literal["locomotion", "adroit", "antmaze", "mujoco-v5"] = "locomotion"
    """Which benchmark (``locomotion_plan.DOMAINS``): its datasets, methods, preset, budget and results folder."""
    datasets: tuple[str, ...] | None = None
    """Default: the domain's (locomotion: the 12 Brax datasets)."""
    methods: tuple[str, ...] | None = None
    """Default: the domain's (locomotion: the paper's methods and the ablations)."""
    ablation_datasets: tuple[str, ...] = ("hopper-medium", "walker2d-medium", "halfcheetah-medium")
    """Where the ablations run (the paper's appendix ablates τ and η on three datasets; name the datasets where
    proto-official separates from PROTO-SAC for the ``official-but-*`` ones)."""
    seeds: tuple[int, ...] = plan.SEEDS
    """The seeds to run (with ``--per-seed``: the parts this runner makes; another runner may make the others)."""
    per_seed: bool = False
    """Run each seed as its own one-run sweep (a part), published under ``results/DATASET/METHOD/parts/seed-K`` as
    soon as it finishes; once the parts of all published seeds (0–4) are in, they are merged into the published sweep
    (``locomotion_plan.merge_parts``). For sweeps longer than a working session: each part is a fraction of the work
    and lands on its own. A part is its seed's run of the vmapped grid up to rounding."""
    steps: int | None = None
    """Online budget per run (paper: 10⁶), stated in every summary. Default: the domain's (locomotion and AntMaze 50k,
    Adroit 10k)."""
    eval_every: int | None = None
    """Evaluation period (paper: 5k of 10⁶). Default: the domain's. Locomotion's 2.5k puts two evaluations (2.5k,
    5k) inside the first 10% of the run, where the initial drop is measured; AntMaze's 5k halves the MJX
    evaluations, which cost there what the updates do; Adroit's 1k is 10% of its 10k."""
    runs: Path | None = None
    """Working sweeps (resume state), default $PROTO_BRAX_RUNS/DOMAIN (~/.cache/proto_brax/runs/DOMAIN): outside the
    work tree, so that a later checkout on the same machine resumes them."""
    results: Path | None = None
    """Default: benchmarks/results/DOMAIN."""
    single_core: bool = False
    """Each sweep on one CPU device with one XLA thread (``--devices 1``, ``envs.single_thread_xla_flags``): for two
    runners side by side on a 2-core machine, where two single-threaded processes do more updates per second in total
    than two sharded ones (FACTS.md) and 5 seeds need no padding run. Its runs go one after another through the one-run
    program (``--block map``: 1.25x (SAC) to 1.5x (RLPD) the grid rate of a one-thread vmap, and each run equals its
    ``--per-seed`` part bit for bit). A started sweep resumes only under the setting it started with (its state's
    padding follows the device count, its rounding the block)."""


def resolve(args: Args) -> Args:
    """The domain's defaults for what the command line left out."""
    d = plan.DOMAINS[args.domain]
    runs_root = Path(os.environ.get("PROTO_BRAX_RUNS", Path.home() / ".cache" / "proto_brax" / "runs"))
    return dataclasses.replace(args, datasets=args.datasets or d.datasets, methods=args.methods or d.methods,
                               steps=args.steps or d.steps, eval_every=args.eval_every or d.eval_every,
                               runs=args.runs or runs_root / d.name,
                               results=args.results or ROOT / "benchmarks" / "results" / d.name)


def run_and_publish(args: Args, domain: plan.Domain, dataset: str, method: str, out: Path, dst: Path,
                    seeds: tuple[int, ...]) -> bool:
    """Run (or resume) one sweep of ``seeds`` into ``out`` unless it finished, and publish it to ``dst``; False if it
    failed."""
    if not (out / "summary.json").exists():  # else finished but not published (the runner was stopped)
        cmd = plan.sweep_command(dataset, method, out, seeds, args.steps, args.eval_every, args.single_core,
                                 resume=(out / "config.json").exists(), domain=domain,
                                 report=not args.per_seed)
        print(f"[{time.strftime('%H:%M:%S')}] {' '.join(cmd[1:])}", flush=True)
        if subprocess.run(cmd, cwd=ROOT, env=plan.sweep_env(args.single_core)).returncode != 0:
            print(f"FAILED: {dataset} {method}" + (f" seeds {list(seeds)}" if args.per_seed else ""), flush=True)
            return False
    plan.publish(out, dst)
    return True


def main(args: Args) -> None:
    args, domain = resolve(args), plan.DOMAINS[args.domain]
    unknown = [m for m in args.methods if m not in METHODS and m not in ABLATIONS]
    if unknown:
        raise SystemExit(f"unknown --methods {unknown}: choose from {sorted(METHODS)} or {sorted(ABLATIONS)}.")
    for dataset, method in plan.planned_sweeps(args.datasets, args.methods, args.ablation_datasets):
        if args.action == "status":
            state = plan.sweep_status(dataset, method, args.runs, args.results, PRETRAINED, domain)
            print(f"{dataset:28s} {method:12s} {state}")
            continue
        out, dst = args.runs / dataset / method, args.results / dataset / method
        if (dst / "summary.json").exists():
            continue
        if need := plan.missing_bundle(dataset, method, PRETRAINED, domain):
            print(f"skip {dataset} {method}: no bundle ({need})", flush=True)
            continue
        if (src := plan.shared_sweep(dataset, method, args.results, domain)) is not None:
            plan.copy_shared(src, dst)
            print(f"{dataset} {method}: the same runs as {src.parent.name} (trains on no dataset)", flush=True)
            continue
        if args.per_seed:
            for seed in args.seeds:
                if not (plan.part_dir(dst, seed) / "summary.json").exists():
                    run_and_publish(args, domain, dataset, method, plan.part_dir(out, seed),
                                    plan.part_dir(dst, seed), (seed,))
            parts = [plan.part_dir(dst, s) for s in plan.SEEDS]
            if not all((p / "summary.json").exists() for p in parts):
                print(f"{dataset} {method}: parts published for seeds "
                      f"{[s for s, p in zip(plan.SEEDS, parts) if (p / 'summary.json').exists()]} of "
                      f"{list(plan.SEEDS)}; merged once all are in", flush=True)
                continue
            plan.merge_parts(parts, dst)
            print(f"{dataset} {method}: merged the parts of seeds {list(plan.SEEDS)}", flush=True)
        elif not run_and_publish(args, domain, dataset, method, out, dst, args.seeds):
            continue
        summary = nan_for_null(json.loads((dst / "summary.json").read_text()))  # a diverged run's null
        for point in summary["points"]:
            where = " ".join(f"{k} {point[k]:g}" for k in summary["grid_keys"])
            print(f"  {where}: final normalized {point['final_normalized_score']['mean']:.1f} ± "
                  f"{point['final_normalized_score']['std']:.1f}", flush=True)


if __name__ == "__main__":
    main(tyro.cli(Args))
