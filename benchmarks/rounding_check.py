"""Does a change that moves floating-point rounding keep a sweep's results within seed noise?

    python benchmarks/rounding_check.py --new DIR [--published DIR] [--out JSON]

Compares a re-run sweep (``DIR/summary.json``, e.g. ``python benchmarks/locomotion.py run --methods proto-sac
--datasets hopper-medium --results DIR_ROOT`` with ``PROTO_BRAX_RUNS`` pointing elsewhere, so the published sweep
is not resumed) against the published one, point by point: the initial, early-drop and final normalized scores'
IQM with its 95% bootstrap CI, and whether the two CIs overlap. Issue 37 asks this of every speed-up that changes
rounding (fused passes, other kernels): overlapping final IQM CIs on one locomotion dataset with 5 seeds.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import sys
from pathlib import Path

import _quiet  # noqa: F401  (first: the quiet start)
import tyro

from proto_brax.files import strict_json, write_json_atomic

ROOT = Path(__file__).resolve().parents[1]
METRICS = ("initial_normalized_score", "min_normalized_first_10pct", "final_normalized_score",
           "average_normalized_score")


@dataclasses.dataclass
class Args:
    new: Path
    """The re-run sweep's directory (holds summary.json)."""
    published: Path = ROOT / "benchmarks" / "results" / "locomotion" / "hopper-medium" / "proto-sac"
    out: Path = ROOT / "benchmarks" / "results" / "rounding_check.json"
    note: str = ""
    """What changed between the two (recorded in the JSON)."""


def compare(new: dict, old: dict) -> list[dict]:
    """Per grid point and metric: both IQMs with CIs, and whether the CIs overlap."""
    rows = []
    for p_new, p_old in zip(new["points"], old["points"], strict=True):
        point = {k: p_new[k] for k in new["grid_keys"]}
        if point != {k: p_old[k] for k in old["grid_keys"]}:
            raise SystemExit(f"the sweeps' grids differ: {point} against {p_old}; compare sweeps of the same grid.")
        for metric in METRICS:
            if metric not in p_new or metric not in p_old:
                continue
            a, b = p_new[metric], p_old[metric]
            rows.append({**point, "metric": metric, "new": a, "published": b,
                         "ci_overlap": bool(a["iqm_low"] <= b["iqm_high"] and b["iqm_low"] <= a["iqm_high"])})
    return rows


def main(args: Args) -> dict:
    new, old = (json.loads((d / "summary.json").read_text()) for d in (args.new, args.published))
    rows = compare(new, old)
    def fmt(x: dict) -> str:
        return f"{x['iqm']:6.1f} [{x['iqm_low']:5.1f}, {x['iqm_high']:5.1f}] (mean {x['mean']:5.1f} ± {x['std']:4.1f})"

    for r in rows:
        print(f"{r['metric']:28s} new {fmt(r['new'])}  published {fmt(r['published'])}  CIs overlap: "
              f"{r['ci_overlap']}")
    configs = {name: json.loads((d / "config.json").read_text()) for name, d in (("new", args.new),
                                                                                 ("published", args.published))}
    payload = {"benchmark": "rounding_check", "command": " ".join(["python benchmarks/rounding_check.py",
                                                                  *sys.argv[1:]]),
               "date": datetime.datetime.now().isoformat(timespec="seconds"), "note": args.note,
               "new": str(args.new), "published": str(args.published.relative_to(ROOT)
                                                      if args.published.is_relative_to(ROOT) else args.published),
               "dataset_vs_bundle": {k: c.get("dataset_vs_bundle") for k, c in configs.items()},
               "dataset_content_hash": {k: c.get("dataset_metadata", {}).get("content_hash")
                                        for k, c in configs.items()},
               "rows": rows, "all_final_cis_overlap": all(r["ci_overlap"] for r in rows
                                                          if r["metric"] == "final_normalized_score")}
    write_json_atomic(args.out, strict_json(payload))
    print(f"final IQM CIs overlap at every point: {payload['all_final_cis_overlap']}; wrote {args.out}")
    return payload


if __name__ == "__main__":
    main(tyro.cli(Args))
