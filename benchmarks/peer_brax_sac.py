"""Brax's own SAC trainer beside ours, at equal work and at our defaults (issue 37).

    python benchmarks/peer_brax_sac.py              # hopper, 3 repetitions, interleaved
    python benchmarks/peer_brax_sac.py --tiny       # a few hundred steps each: checks the script runs

Three programs, each in a process of its own, run in turn (A B C A B C ...) so that a change of machine load hits all
of them alike:

* ``brax``: ``brax.training.agents.sac.train`` (one env, batch 256, one update per env step, 1000 prefill steps, MLP
  2×256 actor and 2 critics without LayerNorm, ``num_eval_envs`` deterministic evaluation episodes per evaluation).
  brax 0.14 calls ``jax.device_put_replicated``, which jax 0.10 removed: the child process puts back a one-device
  version of it (the trainer pmaps over that one device).
* ``ours-equal``: ``python -m proto_brax.sweep --algo sac-scratch`` with the same work: one run on one device, no
  LayerNorm, 1000 warm-up steps, the same evaluation cadence and episodes.
* ``ours-default``: the same with the sweep's defaults for the critics (LayerNorm) and a checkpoint per chunk.

Each program's rate is env steps per second over its evaluation periods after the first (which includes
compilation), evaluation included. Writes ``benchmarks/results/peer_brax_sac.json``: per repetition and median, and
the ratios ours / Brax (goal: ≥ 1.2 at equal work, ≥ 1.0 at the defaults). Measure on a quiet machine.
"""

from __future__ import annotations

import dataclasses
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _quiet  # noqa: F401  (first: the quiet start)
import tyro

from proto_brax.analysis.timing import brax_sac_marks, steady_rate


@dataclasses.dataclass
class Args:
    env: str = "hopper"
    periods: int = 3
    """Evaluation periods per program and repetition (the first, which compiles, is not counted)."""
    eval_every: int = 5_000
    """Env steps per period: Brax's periods (after its 1000 prefill steps) and our chunks have the same length."""
    eval_episodes: int = 5
    reps: int = 3
    tiny: bool = False
    """A few hundred steps each (the script's own test; not a measurement)."""
    out: Path = Path(__file__).resolve().parent / "results" / "peer_brax_sac.json"
    child: str | None = None
    """(internal) run one program in this process: 'brax'."""


def brax_child(args: Args) -> None:
    """Brax's SAC trainer; prints one JSON line: the (env step, wall time) of each evaluation."""
    marks = brax_sac_marks(args.env, args.periods, args.eval_every, args.eval_episodes)
    print(json.dumps({"marks": marks}), flush=True)


def run_brax(args: Args) -> float:
    cmd = [sys.executable, __file__, "--child", "brax", "--env", args.env, "--periods", str(args.periods),
           "--eval-every", str(args.eval_every), "--eval-episodes", str(args.eval_episodes)]
    p = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "PYTHONWARNINGS": "ignore"})
    if p.returncode:
        raise SystemExit(f"brax run failed:\n{p.stderr[-3000:]}")
    marks = json.loads(p.stdout.strip().splitlines()[-1])["marks"]
    # progress_fn runs at step 0 (before training) and after each period: from the end of the first period, which
    # compiles, to the end of the last
    return steady_rate(marks[1:])


def run_ours(args: Args, defaults: bool) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "proto_brax.sweep", "--algo", "sac-scratch", "--env", args.env, "--seeds", "0",
               "--devices", "1", "--steps", str(args.periods * args.eval_every), "--eval-every", str(args.eval_every),
               "--eval-episodes", str(args.eval_episodes), "--learning-starts", "1000", "--no-report",
               "--out", str(Path(tmp) / "sweep")]
        if not defaults:
            cmd += ["--critic-layer-norm", "False"]
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode:
            raise SystemExit(f"our run failed:\n{p.stderr[-3000:]}")
        rows = [json.loads(line) for line in (Path(tmp) / "sweep" / "metrics.jsonl").read_text().splitlines()]
    # one run at one update per env step: grid updates/s = env steps/s; chunks after the first, full updates only
    rates = [r["grid_updates_per_s"] for r in rows if r["chunk"] > 0 and r.get("updates") == args.eval_every]
    return statistics.mean(rates)


def main(args: Args) -> dict:
    if args.child == "brax":
        brax_child(args)
        return {}
    if args.tiny:
        args = dataclasses.replace(args, periods=3, eval_every=500, eval_episodes=2, reps=1)
    programs = {"brax": lambda: run_brax(args), "ours-equal": lambda: run_ours(args, defaults=False),
                "ours-default": lambda: run_ours(args, defaults=True)}
    rates: dict[str, list[float]] = {k: [] for k in programs}
    for rep in range(args.reps):
        for name, fn in programs.items():
            rates[name].append(fn())
            print(f"rep {rep}: {name:>12s} {rates[name][-1]:8.1f} env steps/s", flush=True)
    med = {k: statistics.median(v) for k, v in rates.items()}
    from proto_brax.envs import host_cpu

    result = {
        "what": "env steps/s after compile, evaluation included: Brax's SAC trainer vs python -m proto_brax.sweep "
                "--algo sac-scratch (one run, one device) at equal work and at its defaults",
        "env": args.env, "periods": args.periods, "eval_every": args.eval_every, "eval_episodes": args.eval_episodes,
        "reps": args.reps, "tiny": args.tiny, "rates": rates, "median": med,
        "ratio_equal_work": med["ours-equal"] / med["brax"], "ratio_defaults": med["ours-default"] / med["brax"],
        "goals": {"ratio_equal_work": 1.2, "ratio_defaults": 1.0}, "cpu": host_cpu(),
        "load_before": os.getloadavg(), "date": time.strftime("%Y-%m-%dT%H:%M:%S"),
    }
    print(f"ours / Brax: {result['ratio_equal_work']:.2f} at equal work (goal 1.2), {result['ratio_defaults']:.2f} "
          "with our defaults (goal 1.0)")
    from proto_brax.files import write_json_atomic

    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out, result)
    return result


if __name__ == "__main__":
    main(tyro.cli(Args))
