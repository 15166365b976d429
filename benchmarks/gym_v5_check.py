"""Fidelity and speed of our MJX gymnasium v5 locomotion (proto_brax/envs/gym_v5.py) against gymnasium's native envs.

    python benchmarks/gym_v5_check.py                  # all four -> benchmarks/results/gym_v5_check.json
    python benchmarks/gym_v5_check.py --tasks hopper --episodes 32 --out /tmp/h.json

Per task:

1. **Lockstep**: from ``starts`` of gymnasium's resets, ours is set to the same (qpos, qvel) and both step the same
   uniform random actions for ``lockstep_steps`` steps (continuing past terminations). Reported: max |Δqpos|,
   |Δobs|, |Δreward| at steps 1, 10, 50, and the first step where |Δqpos| exceeds 1e-3 / 1e-1 (median over starts):
   how long float32 MJX and float64 MuJoCo agree before contacts amplify the difference.
2. **Return statistics** of one fixed policy, the uniform random one: ``episodes`` full episodes (time limit 1000,
   ends at termination) of ours (vmapped, one ``lax.scan``) and of gymnasium's ``gym.make(gym_id)``; mean, standard
   error, 95% CI, and whether the difference of means lies within its 95% CI (Welch's z). D4RL's random reference
   (measured with the same policy on the v2 envs) is printed beside.
3. **Speed**: env steps/s after compile of a jitted ``lax.scan`` of ``speed_steps`` random-action steps at batch 1 and
   at ``batch`` (vmapped; all envs together; ours at batch ``episodes``: the timed return rollout of 2., every env
   scanning all 1000 steps), for ours and for Brax's own env at the suite's default backend
   (``proto_brax.envs.REGISTRY``), and native gymnasium (one env, Python loop). Finetuning is update-bound here: the
   JSON sets the batch-1 step time beside one SAC update (FACTS.md: ~195 updates/s on this CPU, ~5.1 ms).

The machine is shared (2 cores, background jobs): the load average is recorded; speeds are ±30%.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import os
import time
from pathlib import Path

import _quiet  # noqa: F401  (first: the quiet start)
import tyro

ROOT = Path(__file__).resolve().parents[1]


@dataclasses.dataclass
class Args:
    tasks: tuple[str, ...] = ("hopper", "walker2d", "halfcheetah", "ant")
    """gymnasium v5 tasks (proto_brax.envs.gym_v5.TASKS)."""
    starts: int = 4
    """Lockstep starts (gymnasium resets, seeds 0..starts-1)."""
    lockstep_steps: int = 100
    """Steps of each lockstep run."""
    episodes: int = 64
    """Episodes of the random policy per implementation (ours: one vmapped batch)."""
    batch: int = 64
    """Batch of Brax's second speed measurement (ours: the ``episodes`` batch of the return rollout)."""
    speed_steps: int = 200
    """Steps of each timed scan."""
    brax: bool = True
    """Also time Brax's own env (the registry's default backend) at batch 1 and ``batch``."""
    seed: int = 0
    out: Path = ROOT / "benchmarks" / "results" / "gym_v5_check.json"


def main(args: Args) -> None:
    from proto_brax import envs

    os.environ["XLA_FLAGS"] = envs.mjx_xla_flags()  # before jax starts (FACTS.md: batched MJX hangs without it)
    from proto_brax.train.grid import size_cpu_pool

    size_cpu_pool(1)  # one device, one pool thread: batched MJX episodes never split a LAPACK batch onto a blocked pool
    import jax

    from proto_brax.analysis import crosscheck
    from proto_brax.files import write_json_atomic

    result = {"date": datetime.date.today().isoformat(), "machine": envs.machine_info(),
              "args": {k: str(v) if isinstance(v, Path) else v for k, v in dataclasses.asdict(args).items()},
              "sac_update_s_assumed": crosscheck.SAC_UPDATE_S, "tasks": {}}
    key = jax.random.PRNGKey(args.seed)
    for task in args.tasks:
        env = envs.make_env(f"{task}-v5")
        row: dict = {}
        t0 = time.perf_counter()
        step = jax.jit(env.step)
        row["lockstep"] = crosscheck.lockstep_stats(task, env, step, args.starts, args.lockstep_steps)
        row["lockstep"]["wall_s"] = time.perf_counter() - t0
        print(task, "lockstep", json.dumps(row["lockstep"]), flush=True)

        row["random_policy"], ours_batch, native_sps = crosscheck.random_policy(
            task, env, args.episodes, args.seed, jax.random.fold_in(key, 1))
        print(task, "random policy", json.dumps(row["random_policy"]), flush=True)

        row["speed"] = crosscheck.gym_v5_speed(task, env, args.speed_steps, key, ours_batch, native_sps, args.brax,
                                               args.batch)
        print(task, "speed", json.dumps(row["speed"]), flush=True)
        result["tasks"][task] = row
    result["machine"]["loadavg_end"] = os.getloadavg()
    write_json_atomic(args.out, result)
    print("wrote", args.out)


if __name__ == "__main__":
    main(tyro.cli(Args))
