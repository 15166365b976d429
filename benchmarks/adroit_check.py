"""Fidelity and speed of our MJX Adroit pen / door / hammer against gymnasium-robotics' native MuJoCo envs.

    python benchmarks/adroit_check.py                       # all three tasks -> benchmarks/results/adroit_check.json
    python benchmarks/adroit_check.py --tasks pen --max-geom-pairs 8 --max-contact-points 16 --out /tmp/a.json

Per task, from one random layout (the env's reset distribution, seed ``seed``) and qpos0, the same fixed uniform
random action sequence (``steps`` control steps) is run by

0. gymnasium-robotics' own env (``gymnasium.make(gym_id)``, ``set_env_state`` to the layout) and our numpy copy of
   its formulas on native MuJoCo with the *original* XML: should agree to float64 round-off (checks the formulas);
1. native MuJoCo, original XML vs capsule XML: the effect of turning cylinders into capsules;
1b. native MuJoCo, original XML, actions nudged by ±1e-6: the chaos floor, what any change of the physics does;
2. MJX (capsule XML, jitted, float32) vs native MuJoCo (capsule XML): the effect of MJX itself (float32, no noslip,
   its colliders).

Each comparison reports max |Δ obs|, max |Δ qpos| and max |Δ reward| over the steps, and the same at step 10 (early
divergence vs. chaotic growth), beside the trajectory's own scale (max |qpos_t − qpos_0|). Speed: control steps/s
of the jitted MJX rollout (reset + ``lax.scan``) at batch 1 and ``batch`` (vmapped), after compile, median of
``reps``, against one native gymnasium-robotics env stepping random actions on one thread. XLA runs single-threaded
here, like native MuJoCo.
"""

from __future__ import annotations

import dataclasses
import datetime
import os
import sys
from pathlib import Path

import _quiet  # noqa: F401  (first: the quiet start)
import tyro

ROOT = Path(__file__).resolve().parents[1]


@dataclasses.dataclass
class Args:
    tasks: tuple[str, ...] = ("pen", "door", "hammer")
    """Adroit tasks (proto_brax.envs.adroit.TASKS)."""
    steps: int = 50
    """Control steps of the cross-check rollouts (and of each timed MJX rollout)."""
    batch: int = 64
    """Vmapped batch of the second MJX speed measurement (0 skips it)."""
    reps: int = 3
    """Timed calls per speed measurement (median)."""
    native_steps: int = 1000
    """gymnasium env.step calls per native speed rep."""
    seed: int = 0
    max_geom_pairs: int | None = None
    """MJX contact bound (custom numeric); None = unbounded, the env's default."""
    max_contact_points: int | None = None
    """MJX contact bound (custom numeric); None = the env's default (``adroit.MAX_CONTACT_POINTS``), 0 = unbounded."""
    out: Path = ROOT / "benchmarks" / "results" / "adroit_check.json"
    baseline: bool = True
    """Also time (interleaved, batch 1) and cross-check the env as it was before the contact bounds, the pruned
    colliders and the sensor pruning (``max_contact_points=None, all_sensors=True, prune_colliders=False``)."""
    merge: bool = False
    """Keep the other tasks already in ``out`` (re-run one task without losing the rest)."""


def main(args: Args) -> dict:
    from proto_brax.envs import machine_info, single_thread_mjx_xla_flags

    os.environ["XLA_FLAGS"] = single_thread_mjx_xla_flags()
    from proto_brax.train.grid import size_cpu_pool

    size_cpu_pool(1)  # one device, one pool thread: batched MJX episodes never split a LAPACK batch onto a blocked pool

    from proto_brax.analysis.crosscheck import check_adroit_task  # after XLA_FLAGS, like everything that runs JAX
    from proto_brax.files import write_json_atomic

    result = {
        "command": " ".join(sys.argv),
        "date": datetime.datetime.now().isoformat(timespec="seconds"),
        "settings": dataclasses.asdict(args) | {"out": str(args.out)},
        "machine": machine_info(),
        "tasks": {},
    }
    if args.merge and Path(args.out).exists():
        import json

        previous = json.loads(Path(args.out).read_text())
        result["tasks"] = previous.get("tasks", {})
        result["previous_runs"] = previous.get("previous_runs", []) + [
            {k: previous.get(k) for k in ("command", "date", "settings", "machine")}]
    for task in args.tasks:
        r = check_adroit_task(task, steps=args.steps, batch=args.batch, reps=args.reps, native_steps=args.native_steps,
                              seed=args.seed, max_geom_pairs=args.max_geom_pairs,
                              max_contact_points=args.max_contact_points, baseline=args.baseline)
        result["tasks"][task] = r
        result["machine"]["loadavg_end"] = os.getloadavg()
        write_json_atomic(args.out, result)  # after each task: a partial run still leaves its numbers
    print(f"{'task':7} {'check':28} {'max|Δobs|':>10} {'max|Δqpos|':>10} {'max|Δrew|':>10} {'@10 obs':>9} "
          f"{'excursion':>9}")
    for task, r in result["tasks"].items():
        for name in ("gym_vs_native_original", "nudged_vs_original_native", "capsule_vs_original_native",
                     "mjx_vs_native_capsule", "mjx_baseline_vs_native_capsule"):
            c = r.get(name)
            if c is None:
                continue
            print(f"{task:7} {name:28} {c['max_abs_obs']:10.2e} {c['max_abs_qpos']:10.2e} "
                  f"{c['max_abs_reward']:10.2e} {c['max_abs_obs_first10']:9.1e} {c['qpos_excursion']:9.2f}")
    # each task's vmapped batch as it was measured (--merge keeps tasks measured with another --batch)
    print(f"\n{'task':7} {'mjx b1':>8} {'mjx vmapped':>14} {'native':>8}  (control steps/s; compile s)")
    for task, r in result["tasks"].items():
        s, batch = r["speed"], r["settings"]["batch"]
        b = s.get(f"batch{batch}", {})
        vmapped = f"{b.get('control_steps_per_s', float('nan')):.1f} (b{batch})" if b else "not run"
        print(f"{task:7} {s['batch1']['control_steps_per_s']:8.1f} {vmapped:>14} "
              f"{s['native_gymnasium']['control_steps_per_s']:8.0f}  ({s['batch1']['compile_s']:.0f}, "
              f"{b.get('compile_s', float('nan')):.0f})")
    for task, r in result["tasks"].items():
        inter = r["speed"].get("batch1_interleaved")
        if inter:
            rate = inter["control_steps_per_s"]
            print(f"{task:7} interleaved b1: unbounded, all sensors {rate['baseline']:.1f} -> env {rate['env']:.1f} "
                  f"control steps/s ({inter['env_over_baseline']:.2f}x)")
    print(f"wrote {args.out}")
    return result


if __name__ == "__main__":
    main(tyro.cli(Args))
