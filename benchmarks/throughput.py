"""Throughput benchmark of the PROTO engine on this machine: what one update costs and how a grid of runs scales.

Run (from the repository root, venv active)::

    python benchmarks/throughput.py                       # paper sizes; ~10-15 min on the 2-core CPU; quiet machine!
    python benchmarks/throughput.py --quick --out /tmp/tp.json   # tiny sizes, end-to-end check in a few minutes

Everything runs in ONE process with two host CPU devices (``use_host_devices(2)``, before any backend exists):

1. PROTO-SAC vs plain SAC update cost (halfcheetah sizes 17/6, MLP 2x256, batch 256): a jitted ``lax.scan`` of N
   (symmetric replay sample + ``sac.update``) with ``regularizer=True`` vs ``False``.
   Goal: time(PROTO) / time(SAC) <= 1.10.
2. Achieved GFLOP/s of one PROTO-SAC update (FLOPs from XLA's cost analysis / measured seconds per update) vs the
   GFLOP/s of a chain of large f32 matmuls measured in the same process. Goal: achieved / matmul >= 0.6 (0.8 long-term).
3. Grid scaling of the full online step on hopper (11/3): total updates/s of (a) one run alone (jit of the single-run
   chunk on one device), (b) a G-run grid vmapped on one device, (c) the same grid vmapped and sharded over both host
   devices. Goal: (b) / (a) >= 1.2 and (c) / (a) >= 1.5.
4. Full online step vs update alone on hopper: seconds per env step of (a) / seconds per update of the update-alone
   scan at hopper sizes (same networks, batch, sampling). Goal <= 1.15.

Timing: each program is compiled ahead of time (``lower().compile()``, compile seconds recorded), run ``warmup`` times,
then the programs of a measurement are timed *interleaved* (A B C A B C ...) ``reps`` times and the median taken, so
slow drift of a shared machine hits every side of a ratio alike. Every call ends with ``jax.block_until_ready``.
The evaluation at the end of a chunk is made negligible with ``episode_length`` = 10 and ``eval_episodes`` = 1 (the
time limit only changes when the env resets; ``env_step`` computes the reset state every step anyway).

Writes JSON atomically (temp file + ``os.replace``) with raw timings, ratios, goals, pass/fail and the environment.
"""

from __future__ import annotations

import dataclasses
import os
import time

import _quiet  # noqa: F401  (first: the quiet start)
import jax
import tyro

from proto_brax.analysis import throughput as tp
from proto_brax.analysis.timing import log
from proto_brax.files import strict_json, write_json_atomic
from proto_brax.train.grid import use_host_devices


@dataclasses.dataclass
class Args:
    """PROTO throughput benchmark (see the module docstring)."""

    quick: bool = False  # tiny sizes: checks the script end to end in a few minutes; timings are meaningless
    out: str = "benchmarks/results/throughput.json"  # JSON report (written atomically)
    reps: int | None = None  # timed repetitions per program (default: 3, quick: 2)
    host_devices: int = 2  # jax_num_cpu_devices (the grid of 3c is sharded over all of them)


def main(args: Args) -> dict:
    # Before anything initializes a JAX backend: two host CPU devices for the sharded grid (3c).
    n_dev = use_host_devices(args.host_devices)
    sizes = tp.QUICK if args.quick else tp.FULL
    if args.reps is not None:
        sizes = dataclasses.replace(sizes, reps=args.reps)
    t_start = time.perf_counter()
    env_info = tp.environment("quick" if args.quick else "full", sizes)
    log(f"mode {env_info['mode']}, devices {env_info['devices']}, loadavg {env_info['loadavg_start']}")
    if n_dev < args.host_devices and jax.default_backend() == "cpu":
        log(f"WARNING: only {n_dev} device(s); a backend was initialized before use_host_devices()")

    log("== 1/2: PROTO-SAC vs SAC update (halfcheetah sizes) and GFLOP/s vs matmul")
    results = tp.measure_update_cost(sizes)
    log("== 3/4: online chunk on hopper: single run, grid vmapped on 1 device, grid sharded; update alone")
    results |= tp.measure_online(sizes, jax.devices())
    goals = tp.goals_of(results)
    rows = tp.summary_rows(results, goals, sizes)
    env_info["loadavg_end"] = list(os.getloadavg())
    env_info["total_wall_s"] = time.perf_counter() - t_start
    payload = {"environment": env_info, "goals": goals, "results": results}
    write_json_atomic(args.out, strict_json(payload))  # NaN -> null: strict JSON

    w = max(len(r[0]) for r in rows)
    print()
    print(f"{'measurement':<{w}}  {'value':>10}  {'goal':>8}  result")
    print("-" * (w + 32))
    for name, value, goal, res in rows:
        print(f"{name:<{w}}  {value:>10}  {goal:>8}  {res}")
    print("-" * (w + 32))
    print(f"mode {env_info['mode']}; {env_info['total_wall_s']:.0f} s; loadavg start {env_info['loadavg_start']} "
          f"end {env_info['loadavg_end']}; wrote {args.out}")
    print("process cpu/wall (median; ~1 = one core busy, ~2 = both): " + tp.cpu_per_wall(results))
    if results["2_gflops"]["scan_counted_once"]:
        print("note: XLA's cost analysis counts the scan's loop body once (not N times); FLOPs/update come from a "
              "separately compiled single-update program.")
    if args.quick:
        print("(--quick: tiny networks and few steps; the verdicts are not meaningful)")
    return payload


if __name__ == "__main__":
    main(tyro.cli(Args))
