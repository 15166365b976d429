"""Record what the cached datasets hold: ``benchmarks/results/datasets.json``, merged across machines.

    python -m proto_brax.datasets make hopper-medium   # ... any registered datasets, on any machine
    python benchmarks/datasets_record.py               # adds this machine's builds to the record

The datasets themselves (10⁶ rows, up to ~300 MB) live in each machine's cache and are not committed; this record is.
Per registered dataset it keeps every distinct build seen (content hash, episodes, returns or AntMaze's success
statistics, generation seconds, XLA flags; where it was seen: a machine's cache on a date, or a published sweep's
buffer, from its config.json) and which committed bundles were pretrained on exactly that content. A regenerated
dataset either reproduces a recorded build (generation is deterministic under ``datasets.generation_xla_flags``) or
shows up as another build of the same name: the provenance that RESULTS.md's *buffer data* column reports per sweep,
here per dataset. AntMaze entries give the fraction of runs reaching D4RL's evaluation goal (issue 7's per-dataset
success rate).
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import os
import platform
from pathlib import Path

import _quiet  # noqa: F401  (first: the quiet start)
import tyro

from proto_brax.data import cache as datasets
from proto_brax.data.generate import dataset_names
from proto_brax.envs import host_cpu
from proto_brax.files import write_json_atomic

ROOT = Path(__file__).resolve().parents[1]


@dataclasses.dataclass
class Args:
    out: Path = ROOT / "benchmarks" / "results" / "datasets.json"
    bundles: Path = ROOT / "checkpoints" / "pretrained"
    sweeps: Path = ROOT / "benchmarks" / "results" / "locomotion"  # published sweeps' configs hold their datasets
    cache_dir: Path | None = None  # the dataset cache (default: $PROTO_BRAX_DATA or ~/.cache/proto_brax/datasets)


def bundles_by_content(root: Path) -> dict[str, list[str]]:
    """content hash -> the committed bundles (``DATASET/ALGO``) pretrained on it."""
    found: dict[str, list[str]] = {}
    for meta in sorted(root.glob("*/*/metadata.json")):
        h = json.loads(meta.read_text()).get("dataset_content_hash")
        if h:
            found.setdefault(h, []).append(f"{meta.parent.parent.name}/{meta.parent.name}")
    return found


def build_entry(meta: dict) -> dict:
    """The part of a dataset's metadata that identifies and summarizes one build."""
    entry = {k: meta.get(k) for k in ("content_hash", "size", "kind", "env", "seed", "seconds", "xla_flags")}
    if "cpu" in meta:  # builds since the CPU was recorded (envs.host_cpu): another CPU can build other rows
        entry["cpu"] = meta["cpu"]
    if "stats" in meta:  # AntMaze: runs, success, cut short, rewarded transitions
        entry["stats"] = meta["stats"]
    else:
        entry["returns"] = meta["returns"]
    return entry


def merge(record: dict, name: str, entry: dict, seen: dict) -> bool:
    """Add ``entry`` to ``record[name]``'s builds unless its content hash is there (then add where it was seen).
    Returns whether the build is new."""
    builds = record.setdefault(name, {"builds": []})["builds"]
    for b in builds:
        if b["content_hash"] == entry["content_hash"]:
            if seen not in b["seen"]:
                b["seen"].append(seen)
            return False
    builds.append({**entry, "seen": [seen]})
    return True


def main(args: Args) -> dict:
    record = json.loads(args.out.read_text()) if args.out.exists() else {}
    by_content = bundles_by_content(args.bundles)
    for config in sorted(args.sweeps.glob("*/*/config.json")):  # the copies published sweeps had in their buffer
        meta = json.loads(config.read_text()).get("dataset_metadata")
        if meta and meta.get("name") in dataset_names():
            sweep = f"{config.parent.parent.name}/{config.parent.name}"
            merge(record, meta["name"], build_entry(meta), {"sweep": sweep})
    seen = {"date": datetime.date.today().isoformat(),
            "machine": f"{platform.node()} ({os.cpu_count()} cpus: {host_cpu()})"}
    for name in dataset_names():
        path = datasets.dataset_path(name, None, 0, args.cache_dir)
        if not path.exists():
            continue
        meta = datasets.cached_metadata(path)
        if why := datasets.stale_reason(meta):
            print(f"{name}: stale ({why}), not recorded")
            continue
        new = merge(record, name, build_entry(meta), seen)
        bundles = by_content.get(meta["content_hash"], [])
        summary = (f"{100 * meta['stats']['success_rate']:.1f}% of runs reach the evaluation goal" if "stats" in meta
                   else f"{meta['returns']['num_episodes']} episodes, return mean {meta['returns']['mean']:.1f}")
        print(f"{name}: {meta['content_hash'][:12]}… {'new build' if new else 'reproduces a recorded build'}; "
              f"{summary}; bundles on it: {', '.join(bundles) or 'none'}")
    for entry in record.values():  # bundles committed since an earlier record count too
        for b in entry["builds"]:
            b["bundles"] = by_content.get(b["content_hash"], [])
    write_json_atomic(args.out, dict(sorted(record.items())))
    return record


if __name__ == "__main__":
    main(tyro.cli(Args))
