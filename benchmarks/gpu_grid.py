"""The paper's τ×η×seed grid as one program on whatever accelerator is present: measured, then projected to 10⁶ steps.

    python benchmarks/gpu_grid.py                 # 45 runs (τ {2.5e-3, 5e-3, 1e-2} × η {0.8, 0.9, 1.0} × 5 seeds),
                                                  # hopper-medium, 10⁶-row dataset, K chunks of 5k steps
    python benchmarks/gpu_grid.py --tiny          # CPU smoke: 8 runs on the point task (CI)

It runs the real sweep (``python -m proto_brax.sweep --preset paper-mujoco`` with the grid above, α annealed over
10⁶ steps) for ``--chunks`` evaluation periods instead of 200, and measures the chunks after the first (which includes
compilation). It prints and writes (``benchmarks/results/gpu_grid.json``, or ``--out``): runs × env steps per second,
seconds per chunk, the projected wall time of the full 10⁶-step grid (compile + 200 chunks at the measured rate), the
device, and peak memory (the accelerator's ``peak_bytes_in_use`` where it reports one; the process's max RSS on CPU).
Goal on one H100: the full grid in under 30 minutes (the paper: ~20 min for one run on an RTX 3080 Ti).
"""

from __future__ import annotations

import dataclasses
import json
import platform
import resource
import sys
import tempfile
import time
from pathlib import Path

import _quiet  # noqa: F401  (first: the quiet start)
import tyro

PAPER_STEPS = 1_000_000


@dataclasses.dataclass
class Args:
    chunks: int = 4
    """Evaluation periods to run (the first includes compilation and is not used for the rate)."""
    eval_every: int = 5_000
    tiny: bool = False
    """CPU smoke: 2 τ × 2 η × 2 seeds on the point task, 2 chunks of 500 steps, 10⁴-row dataset."""
    out: Path = Path(__file__).resolve().parent / "results" / "gpu_grid.json"


def sweep_argv(args: Args, out: Path) -> list[str]:
    if args.tiny:
        return ["--preset", "smoke", "--env", "point", "--tau", "0.0025", "0.005", "--eta", "0.8", "1.0",
                "--alpha0", "2.0", "--seeds", "0", "1", "--steps", str(2 * 500), "--eval-every", "500", "--no-report",
                "--out", str(out)]
    return ["--preset", "paper-mujoco", "--env", "hopper", "--dataset", "hopper-medium", "--dataset-size", "1000000",
            "--tau", "0.0025", "0.005", "0.01", "--eta", "0.8", "0.9", "1.0", "--seeds", "0", "1", "2", "3", "4",
            "--steps", str(args.chunks * args.eval_every), "--eval-every", str(args.eval_every),
            "--anneal-horizon", str(float(PAPER_STEPS)), "--no-report", "--out", str(out)]


def peak_memory_bytes(device) -> tuple[int, str]:
    stats = device.memory_stats() if hasattr(device, "memory_stats") else None
    if stats and "peak_bytes_in_use" in stats:
        return int(stats["peak_bytes_in_use"]), "device peak_bytes_in_use"
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024, "process max RSS"


def main(args: Args) -> dict:
    from proto_brax.train.grid import use_host_devices

    use_host_devices(None)  # on a CPU, one host device per core (as the sweep's CLI); before JAX starts
    import jax

    from proto_brax import sweep
    from proto_brax.files import read_jsonl, write_json_atomic

    with tempfile.TemporaryDirectory() as tmp:
        argv = sweep_argv(args, Path(tmp) / "sweep")
        sargs = sweep.parse_args(argv)
        t0 = time.time()
        sweep.run_sweep(sargs)
        seconds = time.time() - t0
        rows = [r for r in read_jsonl(sargs.out / "metrics.jsonl")[0] if not r.get("initial")]
        summary = json.loads((sargs.out / "summary.json").read_text())
    runs = len({r["run"] for r in rows})
    per_chunk = {r["chunk"]: r["grid_updates_per_s"] for r in rows}
    steady = [v for c, v in sorted(per_chunk.items()) if c > 0]
    rate = float(sum(steady) / len(steady)) if steady else float("nan")  # grid updates/s = runs × steps/s (UTD 1)
    steps_per_chunk = sargs.eval_every
    chunk_seconds = runs * steps_per_chunk / rate
    first = float(summary["first_chunk_seconds_incl_compile"])
    full_chunks = PAPER_STEPS // steps_per_chunk
    memory, memory_kind = peak_memory_bytes(jax.devices()[0])
    result = {
        "device": str(jax.devices()[0].device_kind), "platform": jax.devices()[0].platform,
        "devices": jax.device_count(), "runs": runs, "steps_measured_per_run": sargs.steps,
        "runs_x_steps_per_s": rate, "seconds_per_chunk": chunk_seconds,
        "first_chunk_seconds_incl_compile": first,
        "projected_full_grid_seconds": first + (full_chunks - 1) * chunk_seconds if not args.tiny else None,
        "peak_memory_bytes": memory, "peak_memory_kind": memory_kind, "seconds_total": seconds,
        "tiny": args.tiny, "jax": jax.__version__, "python": platform.python_version(),
        "command": "python benchmarks/gpu_grid.py " + " ".join(sys.argv[1:]),
    }
    write_json_atomic(args.out, result)
    print(json.dumps(result, indent=2))
    if result["projected_full_grid_seconds"] is not None:
        print(f"{runs} runs × 10⁶ steps projected: {result['projected_full_grid_seconds'] / 60:.1f} min on "
              f"{result['device']} (goal on one H100: < 30 min)")
    return result


if __name__ == "__main__":
    main(tyro.cli(Args))
