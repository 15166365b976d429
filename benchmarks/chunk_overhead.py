"""What a sweep spends per chunk beside training (issue 37, goal 4): evaluation, metrics rows and the resume
checkpoint, as fractions of a chunk, at the sweep's defaults.

    python benchmarks/chunk_overhead.py            # hopper, the default grid (2 τ × 2 η), 2000-step chunks; ~10 min
    python benchmarks/chunk_overhead.py --tiny     # the point task, tiny networks: checks the script runs

The sweep's own plan (``proto_brax.experiment.plan.plan_sweep``: the default method, dataset, bundle, grid,
devices) runs through ``train.grid.run_grid`` with a callback that times, per chunk after the first (which compiles):

* ``chunk_s``: the compiled chunk (its ``eval_every`` training steps and the evaluation at its end) until its metrics
  are on the host;
* ``eval_s``: the same evaluation alone (the grid's own evaluation program, ``GridProgram.initial_eval``, on the
  chunk's final state, timed apart; its share of ``chunk_s``);
* ``rows_s``: metrics rows built and appended to ``metrics.jsonl``, as ``experiment.run.execute`` does;
* ``save_s``: the resume checkpoint (``checkpoints.save_step`` of the whole grid state, replay buffers included).

Host overhead per chunk = rows + checkpoint; with the evaluation, overhead = (eval + rows + save) / (chunk + rows +
save). The checkpoint's share at ``--save-every K`` is save_s / K. Writes ``benchmarks/results/chunk_overhead.json``.
"""

from __future__ import annotations

import dataclasses
import datetime
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import _quiet  # noqa: F401  (first: the quiet start)
import tyro


@dataclasses.dataclass
class Args:
    chunks: int = 6
    """Chunks to run (the first compiles and is not counted)."""
    tiny: bool = False
    """The point task with tiny networks (the script's own test; not a measurement)."""
    out: Path = Path(__file__).resolve().parent / "results" / "chunk_overhead.json"


def main(args: Args) -> dict:
    from proto_brax.train.grid import use_host_devices

    use_host_devices()  # as the sweep: one host device per core (before JAX starts its backend)
    import jax

    from proto_brax import checkpoints
    from proto_brax.cli.sweep import parse_args
    from proto_brax.experiment.outdir import append_rows, prepare_out
    from proto_brax.experiment.plan import plan_sweep
    from proto_brax.experiment.run import metric_rows, train_dataset
    from proto_brax.files import write_json_atomic
    from proto_brax.train.grid import compile_grid, grid_mesh, run_grid

    with tempfile.TemporaryDirectory() as tmp:
        flags = ["--out", f"{tmp}/sweep", "--no-report"]
        if args.tiny:
            flags += ["--env", "point", "--dataset", "none", "--checkpoint", "none", "--hidden", "32", "32",
                      "--batch-size", "32", "--eval-every", "200", "--learning-starts", "100", "--eval-episodes", "2"]
        sa = parse_args(flags)
        sa = dataclasses.replace(sa, steps=sa.eval_every * args.chunks)
        plan = plan_sweep(sa)
        prepare_out(sa, plan.config)
        mesh = grid_mesh()
        program = compile_grid(plan.ft, mesh, plan.per_run)
        timing = {k: [] for k in ("chunk_s", "eval_s", "rows_s", "save_s")}
        clock = {"t": time.perf_counter()}

        def on_chunk(c, m, state):
            chunk_s = time.perf_counter() - clock["t"]
            t0 = time.perf_counter()
            rows = metric_rows(c, m, plan.grid, plan.cfg.env, 0.0)
            append_rows(Path(sa.out) / "metrics.jsonl", rows)
            t1 = time.perf_counter()
            checkpoints.save_step(Path(sa.out) / "state", c + 1, state, {"chunks_done": c + 1})
            t2 = time.perf_counter()
            t3 = time.perf_counter()  # (chunk 0, which is not counted, includes its compilation)
            jax.block_until_ready(program.initial_eval(state))
            eval_s = time.perf_counter() - t3
            print(f"chunk {c}: {chunk_s:.2f} s (evaluation {eval_s:.2f} s), rows {t1 - t0:.3f} s, checkpoint "
                  f"{t2 - t1:.3f} s", flush=True)
            if c > 0:
                for k, v in zip(timing, (chunk_s, eval_s, t1 - t0, t2 - t1)):
                    timing[k].append(v)
            clock["t"] = time.perf_counter()

        run_grid(plan.ft, plan.grid, plan.pretrained, train_dataset(plan), mesh=mesh, program=program,
                 callback=on_chunk, per_run_pretrained=plan.per_run)
        latest = checkpoints.latest_step(Path(sa.out) / "state")
        state_mb = sum(p.stat().st_size for p in latest.rglob("*") if p.is_file()) / 2 ** 20

    med = {k: statistics.median(v) for k, v in timing.items()}
    total = med["chunk_s"] + med["rows_s"] + med["save_s"]
    shares = {"evaluation": med["eval_s"] / total, "rows": med["rows_s"] / total, "checkpoint": med["save_s"] / total}
    overhead = {"host (rows + checkpoint every chunk)": (med["rows_s"] + med["save_s"]) / total,
                "with evaluation": (med["eval_s"] + med["rows_s"] + med["save_s"]) / total}
    for k in (2, 5, 10):
        overhead[f"with evaluation, checkpoint every {k} chunks"] = (
            (med["eval_s"] + med["rows_s"] + med["save_s"] / k) / (med["chunk_s"] + med["rows_s"] + med["save_s"] / k))
    print(f"\nper chunk (median of {len(timing['chunk_s'])}; {plan.grid.size} runs, {sa.eval_every} steps, "
          f"{sa.eval_episodes} evaluation episodes, checkpoint {state_mb:.1f} MB):")
    for k, v in med.items():
        print(f"  {k:<8} {v:8.3f}")
    for k, v in {**shares, **overhead}.items():
        print(f"  {k:<52} {100 * v:5.1f}% of a chunk")
    payload = {"benchmark": "chunk_overhead", "command": " ".join(["python benchmarks/chunk_overhead.py",
                                                                   *sys.argv[1:]]),
               "date": datetime.datetime.now().isoformat(timespec="seconds"), "machine": platform.machine(),
               "sweep": {"env": sa.env, "algo": sa.algo, "runs": plan.grid.size, "eval_every": sa.eval_every,
                         "eval_episodes": sa.eval_episodes, "devices": int(mesh.devices.size),
                         "checkpoint_mb": state_mb},
               "per_chunk_s": timing, "median_s": med, "share_of_chunk": shares, "overhead": overhead,
               "goal": "host overhead (metrics, checkpoint, evaluation) <= 5% of a chunk", "tiny": args.tiny,
               "loadavg": [round(x, 2) for x in os.getloadavg()]}
    write_json_atomic(args.out, payload)
    print(f"wrote {args.out}")
    return payload


if __name__ == "__main__":
    main(tyro.cli(Args))
