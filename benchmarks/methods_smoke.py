"""End-to-end smoke run of every sweep method on hopper-medium, through the real CLI (one subprocess each).

    python benchmarks/methods_smoke.py                     # all methods; ~30-40 min on the 2-core CPU
    python benchmarks/methods_smoke.py --methods iql pex   # a subset

Each method runs ``python -m proto_brax.sweep --algo NAME --dataset hopper-medium`` with a short online budget
(``--steps``, one seed). Methods whose bundle kind is committed for hopper-medium use it (``--checkpoint auto``);
the others pretrain their bundle inside the same command (``--pretrain KIND --pretrain-steps N``: IQL for iql/pex,
Cal-QL for calql, a 5-agent CQL ensemble for off2on). Records return code, wall seconds, the sweep's final evaluation
return and normalized score, and its steady updates/s, in ``benchmarks/results/methods_smoke.json`` (atomic write).
This checks that every method runs end to end; the budgets are far too small to rank methods.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import time
from pathlib import Path

import _quiet  # noqa: F401  (first: the quiet start)
import tyro

from proto_brax.agents.registry import METHODS
from proto_brax.files import write_json_atomic

ROOT = Path(__file__).resolve().parents[1]


@dataclasses.dataclass
class Args:
    methods: tuple[str, ...] = tuple(METHODS)
    dataset: str = "hopper-medium"
    steps: int = 3_000  # online steps per run
    eval_every: int = 1_500
    pretrain_steps: int = 2_000  # for methods whose bundle kind is not committed for the dataset
    out: Path = ROOT / "benchmarks" / "results" / "methods_smoke.json"
    runs: Path = ROOT / "runs" / "methods_smoke"


def command(name: str, args: Args) -> list[str]:
    m = METHODS[name]
    cmd = [sys.executable, "-m", "proto_brax.sweep", "--algo", name, "--seeds", "0", "--steps", str(args.steps),
           "--eval-every", str(args.eval_every), "--eval-episodes", "3", "--no-report", "--overwrite",
           "--learning-starts", "1000",  # scratch methods default to 5000: every method must update in the smoke
           "--out", str(args.runs / name)]
    cmd += ["--eta", "0.9"] + ([] if "tau" in m.defaults else ["--tau", "0.005"])  # one grid point: the paper's
    if m.uses_dataset:
        cmd += ["--dataset", args.dataset]
    if m.bundles:
        kind = m.bundles[0]
        if not (ROOT / "checkpoints" / "pretrained" / args.dataset / kind / "metadata.json").exists():
            cmd += ["--pretrain", kind, "--pretrain-steps", str(args.pretrain_steps)]
    return cmd


def main(args: Args) -> dict:
    results = json.loads(args.out.read_text()) if args.out.exists() else {}
    for name in args.methods:
        cmd = command(name, args)
        print(f"[{time.strftime('%H:%M:%S')}] {name}: {' '.join(cmd[1:])}", flush=True)
        t0 = time.time()
        p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
        rec = {"command": "python " + " ".join(cmd[1:]).replace(str(ROOT) + "/", ""), "returncode": p.returncode,
               "seconds": time.time() - t0}
        summary = args.runs / name / "summary.json"
        if p.returncode == 0 and summary.exists():
            point = json.loads(summary.read_text())["points"][0]
            rows = [json.loads(x) for x in (args.runs / name / "metrics.jsonl").read_text().splitlines()]
            rec.update(final_return=point["final_eval_return"]["mean"],
                       final_normalized=point["final_normalized_score"]["mean"],
                       returns=[r["eval_return"] for r in rows],
                       steady_updates_per_s=rows[-1]["grid_updates_per_s"])
        else:
            rec["error_tail"] = (p.stdout + p.stderr)[-3000:]
        results[name] = rec
        print(f"    rc {p.returncode} in {rec['seconds']:.0f} s; returns {rec.get('returns')}", flush=True)
        write_json_atomic(args.out, results)
    return results


if __name__ == "__main__":
    main(tyro.cli(Args))
