"""Pretrain the committed bundles: every (dataset, algorithm) pair, one single-threaded process per core.

    python benchmarks/pretrain_all.py                              # EQL and BC+FQE on the 12 locomotion datasets
    python benchmarks/pretrain_all.py --algos iql --envs hopper    # a subset
    python benchmarks/pretrain_all.py --algos --methods proto-official   # a method's own bundles (eql-official)

Each pair runs ``python -m proto_brax.pretrain --dataset ENV-KIND --algo ALGO --seeds 0 --steps 100000`` (the paper's
10⁵ steps) into ``checkpoints/pretrained/ENV-KIND/ALGO``; a pair whose bundle exists is skipped, so an interrupted
queue resumes by running the same command again (a bundle is written atomically at the end of its run). A bundle
whose ``dataset_content_hash`` differs from the cached dataset's (the dataset was regenerated since) is stale and is
remade with ``--overwrite``, as is one without a recorded reward transform. Datasets are
built into the cache first when missing. ``--workers`` processes run at once, each pinned to one core with XLA's
single-threaded CPU flags (two such processes do more updates per second in total than one two-threaded process on
this 2-core machine, shared/FACTS.md). Logs go to runs/pretrain_all/.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import _quiet  # noqa: F401  (first: the quiet start)
import tyro

from proto_brax.envs import single_thread_xla_flags

ROOT = Path(__file__).resolve().parents[1]

SINGLE_THREAD = single_thread_xla_flags("")  # the children's whole XLA_FLAGS


@dataclasses.dataclass
class Args:
    envs: tuple[str, ...] = ("hopper", "walker2d", "halfcheetah", "ant")
    kinds: tuple[str, ...] = ("medium", "random", "medium-replay")
    algos: tuple[str, ...] = ("eql", "bc")
    methods: tuple[str, ...] = ()
    """Sweep methods whose bundles are a variant of their kind (proto-official: eql-official, pretrained with its
    --policy and --pretrain-hp defaults), made besides --algos."""
    steps: int = 100_000
    seeds: tuple[int, ...] = (0,)
    workers: int = 2
    cores: tuple[int, ...] = ()
    """Core of each worker (default 0, 1, …): two queues at once, e.g. --workers 1 --cores 1 beside another."""
    logs: Path = ROOT / "runs" / "pretrain_all"


def cached_hash(dataset: str) -> str | None:
    """Content hash recorded in the cached dataset file (reads only its metadata entry), None if not cached."""
    from proto_brax.data.cache import cached_metadata, dataset_path

    path = dataset_path(dataset)
    return cached_metadata(path)["content_hash"] if path.exists() else None


def bundle_jobs(args: Args) -> list[tuple[str, str, list[str]]]:
    """(algo, bundle directory name, extra pretrain flags) of every bundle kind asked for: plain algos, and each
    method's variant (its bundle kind + suffix, with the method's --policy and --pretrain-hp defaults)."""
    from proto_brax.agents.registry import get_method, pretrain_flags

    jobs = [(algo, algo, []) for algo in args.algos]
    for name in args.methods:
        m = get_method(name)
        extra = pretrain_flags(m.defaults.get("policy", "tanh_gaussian"), m.defaults.get("pretrain_hp"))
        jobs.append((m.bundles[0], m.auto_bundle, extra))
    return jobs


def pending(args: Args) -> list[tuple[str, tuple[str, str, list[str]], bool]]:
    """(dataset, job, stale) for every bundle to make; stale = it exists but was trained on another dataset, or on raw
    rewards (made before bundles recorded their reward transform)."""
    out = []
    for env in args.envs:
        for kind in args.kinds:
            for job in bundle_jobs(args):
                meta = ROOT / "checkpoints" / "pretrained" / f"{env}-{kind}" / job[1] / "metadata.json"
                if not meta.exists():
                    out.append((f"{env}-{kind}", job, False))
                    continue
                m = json.loads(meta.read_text())
                h = cached_hash(f"{env}-{kind}")
                # Bundles from before the reward transform trained on raw rewards: the finetuning α then means less.
                if (h and m["dataset_content_hash"] != h) or "reward_scale" not in m:
                    out.append((f"{env}-{kind}", job, True))
    return out


def main(args: Args) -> None:
    args.logs.mkdir(parents=True, exist_ok=True)
    queue = pending(args)
    print(f"{len(queue)} bundle(s) to make: {[(d, job[1], stale) for d, job, stale in queue]}", flush=True)
    from proto_brax.data.cache import dataset_path

    for dataset in dict.fromkeys(d for d, _, _ in queue):  # build missing datasets first (deterministic, cached)
        if not dataset_path(dataset).exists():
            print(f"[{time.strftime('%H:%M:%S')}] building {dataset}", flush=True)
            subprocess.run([sys.executable, "-m", "proto_brax.datasets", "make", dataset], cwd=ROOT, check=True)
    running: dict[int, tuple[subprocess.Popen, tuple[str, str], float]] = {}
    while queue or running:
        for core in range(args.workers):
            if core not in running and queue:
                dataset, (algo, name, extra), stale = queue.pop(0)
                cpu = args.cores[core] if core < len(args.cores) else core % (os.cpu_count() or 1)
                cmd = ["taskset", "-c", str(cpu), sys.executable, "-m", "proto_brax.pretrain",
                       "--dataset", dataset, "--algo", algo, "--steps", str(args.steps),
                       "--seeds", *map(str, args.seeds), *extra,
                       "--out", str(ROOT / "checkpoints" / "pretrained" / dataset / name),
                       *(["--overwrite"] if stale else [])]
                log = open(args.logs / f"{dataset}-{name}.log", "a")
                env = {**os.environ, "XLA_FLAGS": SINGLE_THREAD}
                running[core] = (subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, env=env),
                                 (dataset, name), time.time())
                print(f"[{time.strftime('%H:%M:%S')}] core {core}: {dataset} {name}", flush=True)
        time.sleep(5)
        for core, (p, job, t0) in list(running.items()):
            if p.poll() is not None:
                print(f"[{time.strftime('%H:%M:%S')}] {job[0]} {job[1]}: exit {p.returncode} after "
                      f"{time.time() - t0:.0f} s", flush=True)
                del running[core]


if __name__ == "__main__":
    main(tyro.cli(Args))
