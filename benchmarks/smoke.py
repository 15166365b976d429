"""CI smoke benchmark: a tiny sweep on CPU through the real CLI path; checks shapes and finiteness, writes timings.

    python benchmarks/smoke.py [--out benchmarks/results/smoke.json]
"""

from __future__ import annotations

import dataclasses
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import _quiet  # noqa: F401  (first: the quiet start)


@dataclasses.dataclass
class Args:
    out: Path = Path("benchmarks/results/smoke.json")
    env: str = "point"
    steps: int = 1_000
    eval_every: int = 500


def main() -> int:
    import tyro

    args = tyro.cli(Args)
    from proto_brax.train.grid import use_host_devices

    n_dev = use_host_devices(None)
    import jax
    import numpy as np

    from proto_brax import sweep
    from proto_brax.files import write_json_atomic

    with tempfile.TemporaryDirectory() as tmp:
        sargs = sweep.parse_args(["--preset", "smoke", "--env", args.env, "--steps", str(args.steps),
                                  "--eval-every", str(args.eval_every), "--out", str(Path(tmp) / "sweep")])
        t0 = time.time()
        summary = sweep.run_sweep(sargs)
        seconds = time.time() - t0
        rows = [json.loads(x) for x in (sargs.out / "metrics.jsonl").read_text().splitlines()]
        meta = json.loads((sargs.out / "summary.json").read_text())
    runs = 2 * 2 * 2
    chunks = args.steps // args.eval_every
    problems = []
    initial = [r for r in rows if r.get("initial")]  # π₀ evaluated at step 0, one row per run
    rows = [r for r in rows if not r.get("initial")]
    if len(rows) != runs * chunks or len(initial) != runs:
        problems.append(f"expected {runs * chunks} chunk rows and {runs} step-0 rows, got {len(rows)} and "
                        f"{len(initial)}")
    if not all(r["step"] == 0 and np.isfinite(r["eval_return"]) for r in initial):
        problems.append("bad step-0 rows")
    if len(summary) != 4:
        problems.append(f"expected 4 grid points in the summary, got {len(summary)}")
    for key in ("eval_return", "critic_loss", "actor_loss", "q_mean", "alpha"):
        if not all(np.isfinite(r[key]) for r in rows):
            problems.append(f"non-finite {key}")
    last = [r["grid_updates_per_s"] for r in rows if r["chunk"] == chunks - 1]
    result = {
        "seconds_total": seconds,
        "first_chunk_seconds_incl_compile": meta["first_chunk_seconds_incl_compile"],
        "grid_updates_per_s_last_chunk": last[0] if last else None,
        "runs": runs, "steps": args.steps, "env": args.env, "devices": n_dev,
        "jax": jax.__version__, "python": platform.python_version(), "problems": problems,
        "command": " ".join(sys.argv),
    }
    write_json_atomic(args.out, result)
    print(json.dumps(result, indent=2))
    if problems:
        print("SMOKE FAILED: " + "; ".join(problems))
        return 1
    print("smoke benchmark ok")
    return 0


if __name__ == "__main__":
    sys.exit(main())
