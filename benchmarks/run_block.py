"""How a device runs its block of grid runs on CPU (``grid.run_batched``, the sweep's ``--block``): ``vmap`` (one
batched program) against ``map`` (``lax.map``: the unbatched per-run program, one run after another, still one jitted
chunk).

    python benchmarks/run_block.py                                  # SAC with LayerNorm critics, hopper
    python benchmarks/run_block.py --algos rlpd --steps 300 --chunks 1   # RLPD: 10 LayerNorm critics

Each variant runs a grid of ``--runs`` seeds on one device (one XLA thread, as ``--devices 1`` sweeps run): the
first chunk compiles and warms up, the next ``--chunks`` are timed; a one-run grid (unbatched) is the reference.
Prints each grid's updates/s (summed over its runs; the ratio to the one-run program is the efficiency of batching)
and writes benchmarks/results/run_block.json. Measure on a quiet machine.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import _quiet  # noqa: F401  (first: the quiet start)
import jax
import numpy as np
import tyro

from proto_brax.config import FinetuneConfig, NetworkConfig
from proto_brax.envs import host_cpu, single_thread_xla_flags
from proto_brax.files import write_json_atomic
from proto_brax.train import grid as G
from proto_brax.train import online

ROOT = Path(__file__).resolve().parents[1]


@dataclasses.dataclass
class Args:
    runs: int = 5
    steps: int = 1000
    """Env steps (= updates) per timed chunk."""
    chunks: int = 2
    algos: tuple[str, ...] = ("sac",)
    out: Path = ROOT / "benchmarks" / "results" / "run_block.json"


def measure(algo: str, runs: int, block: str, args: Args) -> float:
    net = NetworkConfig(critic_layer_norm=True, num_qs=10 if algo == "rlpd" else 2)
    cfg = FinetuneConfig(env="hopper", algo=algo, net=net, steps=args.steps * (args.chunks + 1),
                         eval_every=args.steps, eval_episodes=1, sampling="online",
                         learning_starts=min(256, args.steps))  # warm-up inside the untimed first chunk
    ft = online.make_finetune(cfg)
    grid = G.make_grid({}, seeds=list(range(runs)), base={"alpha0": 0.0}, hparams=ft.hparams)
    times = []
    G.run_grid(ft, grid, mesh=G.grid_mesh(jax.devices()[:1]), block=block,
               callback=lambda c, m, s: times.append(time.perf_counter()))
    timed = np.diff(times)  # the chunks after the first (compile, warm-up)
    return float(args.steps * runs * len(timed) / timed.sum())


def main(args: Args) -> None:
    """Measure each of ``--algos``; its entry in ``--out`` is replaced, the others' kept (RLPD's 10 critics need
    shorter chunks: ``--algos rlpd --steps 300``)."""
    # one XLA thread and a one-thread pool, as --devices 1 sweeps run; before JAX starts its backend (measure)
    os.environ["XLA_FLAGS"] = single_thread_xla_flags()
    G.size_cpu_pool(1)
    record = json.loads(args.out.read_text()) if args.out.exists() else {"algos": {}}
    for algo in args.algos:
        variants = {"single (1 run, unbatched)": (1, "vmap"), f"vmap ({args.runs} runs)": (args.runs, "vmap"),
                    f"map ({args.runs} runs)": (args.runs, "map")}
        rates = {name: measure(algo, n, block, args) for name, (n, block) in variants.items()}
        for name, v in rates.items():
            ratio = v / rates["single (1 run, unbatched)"]
            print(f"{algo:5s} {name:26s} {v:7.1f} grid updates/s ({ratio:.2f} x one unbatched run)", flush=True)
        record["algos"][algo] = {"command": " ".join(["python benchmarks/run_block.py", *sys.argv[1:]]),
                                 "date": time.strftime("%Y-%m-%d"), "cpu": host_cpu(), "steps_per_chunk": args.steps,
                                 "timed_chunks": args.chunks, "grid_updates_per_s": rates}
        write_json_atomic(args.out, record)


if __name__ == "__main__":
    main(tyro.cli(Args))
