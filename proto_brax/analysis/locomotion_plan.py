"""The published locomotion benchmark: its datasets, its methods and the paper's ablations (appendix), run by
``benchmarks/locomotion.py`` and reported by ``proto_brax.analysis.results_md``; the runner's queue of sweeps, each
one's state (done, needs a bundle, shared, started, pending), its command line and its publication."""

from __future__ import annotations

import gzip
import os
import shutil
import sys
from pathlib import Path

from proto_brax.agents.registry import METHODS, Method, pretrain_flags
from proto_brax.experiment.args import PRESETS
from proto_brax.files import atomic_write, copy_atomic

DATASETS = tuple(f"{env}-{kind}" for env in ("hopper", "walker2d", "halfcheetah", "ant")
                 for kind in ("medium", "medium-replay", "random"))
PAPER_METHODS = ("proto-sac", "frozen", "direct", "iql", "sac-scratch", "proto-td3", "proto-bc")
PRESET = "paper-mujoco-100k"
# the ablations' middle values (proto-sac)
TAU0, ETA0 = PRESETS[PRESET].fields["tau"][0], PRESETS[PRESET].fields["eta"][0]
# Ablation -> the sweep flag and its two non-default values (0.5 and 2 × τ₀; η 0.8 and 1.0).
ABLATIONS = {"ablate-tau": ("--tau", (0.5 * TAU0, 2 * TAU0)), "ablate-eta": ("--eta", (0.8, 1.0))}


def method_of(name: str) -> Method:
    """The sweep method a runner method name stands for (an ablation is a PROTO-SAC sweep)."""
    return METHODS["proto-sac" if name in ABLATIONS else name]


def planned_sweeps(datasets: tuple[str, ...], methods: tuple[str, ...],
                   ablation_datasets: tuple[str, ...]) -> list[tuple[str, str]]:
    """The runner's queue, in order: every (dataset, method), an ablation only on ``ablation_datasets``."""
    return [(d, m) for d in datasets for m in methods if m not in ABLATIONS or d in ablation_datasets]


def sweep_command(dataset: str, method: str, out: Path, seeds: tuple[int, ...], steps: int, eval_every: int,
                  single_core: bool, resume: bool) -> list[str]:
    """``python -m proto_brax.sweep`` of one (dataset, method) into ``out``: the preset, the online budget ``steps``
    with α annealed over all of it, the ablation's two values, the full dataset (unless the method trains on none)."""
    env = dataset.split("-")[0]
    m = method_of(method)
    cmd = [sys.executable, "-m", "proto_brax.sweep", "--preset", PRESET, "--algo", m.name,
           "--env", env, "--seeds", *map(str, seeds), "--steps", str(steps),
           "--eval-every", str(eval_every), "--anneal-horizon", str(float(steps)),
           "--out", str(out)]
    if method in ABLATIONS:
        flag, values = ABLATIONS[method]
        cmd += [flag, *map(str, values)]
    if m.uses_dataset:
        cmd += ["--dataset", dataset, "--dataset-size", "1000000"]
    if single_core:
        cmd += ["--devices", "1"]
    return cmd + (["--resume"] if resume else [])


def sweep_env(single_core: bool) -> dict[str, str]:
    """The sweep's environment: with ``single_core``, one XLA thread."""
    # Here, not at the top: proto_brax.envs loads MuJoCo and Brax, which RESULTS.md's driver (through this module)
    # does not need.
    from proto_brax.envs import single_thread_xla_flags

    env = dict(os.environ)
    if single_core:
        env["XLA_FLAGS"] = single_thread_xla_flags()
    return env


def missing_bundle(dataset: str, method: str, pretrained: Path) -> str | None:
    """The command that makes the pretrained bundle ``method`` starts from on ``dataset`` when ``pretrained`` (the
    repository's ``checkpoints/pretrained``) lacks it; None when it is there or the method needs none."""
    m = method_of(method)
    if not m.bundles:
        return None
    kind = m.bundles[0]  # the bundle kind that --checkpoint auto picks
    if (pretrained / dataset / (kind + m.bundle_suffix) / "metadata.json").exists():
        return None
    extra = "".join(f" {f}" for f in pretrain_flags(m.defaults.get("policy", "tanh_gaussian"),
                                                     m.defaults.get("pretrain_hp")))
    return (f"python -m proto_brax.pretrain --dataset {dataset} --algo {kind}{extra} --out "
            f"checkpoints/pretrained/{dataset}/{kind + m.bundle_suffix}")


def publish(src: Path, dst: Path) -> None:
    """Copy a finished sweep ``src`` to the results tree at ``dst``; summary.json goes last, as it marks the sweep
    done."""
    dst.mkdir(parents=True, exist_ok=True)
    copy_atomic(src / "config.json", dst / "config.json")
    with open(src / "metrics.jsonl", "rb") as f, atomic_write(dst / "metrics.jsonl.gz", "wb") as raw, \
            gzip.GzipFile(fileobj=raw, mode="wb", filename="", mtime=0) as g:  # mtime 0: same bytes on a rerun
        shutil.copyfileobj(f, g)
    for f in sorted((src / "report").rglob("*")):  # the sweep's report PNGs (none when it made no report)
        if f.is_file():
            copy_atomic(f, dst / "report" / f.relative_to(src / "report"))
    copy_atomic(src / "summary.json", dst / "summary.json")


def shared_sweep(dataset: str, method: str, results: Path) -> Path | None:
    """A published sweep (under ``results``) of a dataset-free method on another dataset of the same env, which this
    dataset shares."""
    if method not in METHODS or METHODS[method].uses_dataset:
        return None
    env = dataset.split("-")[0]
    found = [results / d / method for d in DATASETS
             if d != dataset and d.split("-")[0] == env and (results / d / method / "summary.json").exists()]
    return found[0] if found else None


def copy_shared(src: Path, dst: Path) -> None:
    """Publish the shared sweep ``src`` as ``dst`` too: copied beside it first, then renamed over whatever ``dst``
    holds (an unfinished publish of its own, without summary.json)."""
    tmp = dst.parent / f".{dst.name}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(src, tmp)
    shutil.rmtree(dst, ignore_errors=True)
    tmp.replace(dst)


def sweep_status(dataset: str, method: str, runs: Path, results: Path, pretrained: Path) -> str:
    """What ``locomotion.py status`` says of one sweep: done (published), needs bundle (with the command that makes
    it), shared (a dataset-free method's sweep on another dataset, copied on run), started (a working directory under
    ``runs``) or pending."""
    if (results / dataset / method / "summary.json").exists():
        return "done"
    if need := missing_bundle(dataset, method, pretrained):
        return "needs bundle: " + need
    if (shared := shared_sweep(dataset, method, results)) is not None:
        return f"shared: copies {shared.parent.name}'s on run"
    return "started" if (runs / dataset / method).exists() else "pending"
