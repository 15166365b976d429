"""Speed of our MJX AntMaze against gymnasium-robotics' native MuJoCo AntMaze, in one run.

    python benchmarks/antmaze_speed.py                          # umaze, batch 1 and 128, -> benchmarks/results/
    python benchmarks/antmaze_speed.py --maze large --out /tmp/antmaze_speed.json

MJX: ``jit(vmap(reset))`` then a jitted ``lax.scan`` of ``steps`` vmapped control steps with uniform random actions
(drawn inside the scan), compiled ahead of time (compile seconds recorded), run once to warm up, then timed ``reps``
times; the median gives control steps/s = batch x steps / seconds (physics steps/s = 5 x that, frame_skip 5).
Native: gymnasium-robotics ``AntMaze_UMaze-v5`` (or Medium / Large; ``continuing_task=True``,
``include_cfrc_ext_in_observation=False``), one env, ``native_steps`` random-action ``env.step`` calls per rep, same
median. Both sides run in this one process on one thread (the XLA flags below), so a shared machine's load hits both;
the load average is recorded with the result.
"""

from __future__ import annotations

import dataclasses
import datetime
import os
import statistics
import sys
import time
from pathlib import Path

import _quiet  # noqa: F401  (first: the quiet start)

ROOT = Path(__file__).resolve().parents[1]

NATIVE_IDS = {"umaze": "AntMaze_UMaze-v5", "medium": "AntMaze_Medium-v5", "large": "AntMaze_Large-v5"}


@dataclasses.dataclass
class Args:
    maze: str = "umaze"  # umaze | medium | large (proto_brax.envs.antmaze.MAZES)
    batches: tuple[int, ...] = (1, 128)  # vmapped batch sizes of the MJX measurement
    steps: int = 100  # control steps per jitted scan
    reps: int = 3  # timed calls per measurement (median)
    native_steps: int = 1000  # native env.step calls per rep
    integrators: tuple[str, ...] = ("RK4",)  # add Euler to see what the faster integrator would cost (not default)
    out: Path = ROOT / "benchmarks" / "results" / "antmaze_speed.json"


def mjx_speed(env, batch: int, steps: int, reps: int) -> dict:
    import jax
    import jax.numpy as jnp

    from proto_brax.envs.antmaze import FRAME_SKIP

    def rollout(keys):
        state = jax.vmap(env.reset)(keys)

        def body(s, k):
            a = jax.random.uniform(k, (batch, env.action_size), minval=-1.0, maxval=1.0)
            return jax.vmap(env.step)(s, a), None

        state, _ = jax.lax.scan(body, state, jax.random.split(jax.random.fold_in(keys[0], 1), steps))
        return jnp.sum(state.reward), state.pipeline_state.q

    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    t0 = time.perf_counter()
    compiled = jax.jit(rollout).lower(keys).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(keys))
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        _, q = jax.block_until_ready(compiled(keys))
        times.append(time.perf_counter() - t0)
    seconds = statistics.median(times)
    return {
        "batch": batch,
        "steps": steps,
        "compile_s": compile_s,
        "seconds_per_call": times,
        "control_steps_per_s": batch * steps / seconds,
        "physics_steps_per_s": FRAME_SKIP * batch * steps / seconds,
        "final_state_finite": bool(jnp.isfinite(q).all()),
    }


def native_speed(maze: str, n: int, reps: int) -> dict:
    import gymnasium as gym
    import gymnasium_robotics

    from proto_brax.analysis.crosscheck import native_step_times
    from proto_brax.envs.antmaze import FRAME_SKIP, maze_map

    gym.register_envs(gymnasium_robotics)
    env = gym.make(NATIVE_IDS[maze], maze_map=maze_map(maze), continuing_task=True,
                   include_cfrc_ext_in_observation=False, max_episode_steps=10**9)
    os.remove(env.unwrapped.tmp_xml_file_path)  # gymnasium-robotics leaves its generated maze XML in the temp dir
    times = native_step_times(env, 8, n, reps)
    seconds = statistics.median(times)
    return {"steps": n, "seconds_per_rep": times, "control_steps_per_s": n / seconds,
            "physics_steps_per_s": FRAME_SKIP * n / seconds}


def main(args: Args) -> dict:
    from proto_brax.envs import machine_info, single_thread_mjx_xla_flags

    os.environ["XLA_FLAGS"] = single_thread_mjx_xla_flags()

    from proto_brax.envs import antmaze
    from proto_brax.files import write_json_atomic

    result = {
        "command": " ".join(sys.argv),
        "date": datetime.datetime.now().isoformat(timespec="seconds"),
        "maze": args.maze,
        "machine": machine_info(),
        "mjx_settings": {"max_geom_pairs": antmaze.MAX_GEOM_PAIRS, "max_contact_points": antmaze.MAX_CONTACT_POINTS,
                         "solver_iterations": antmaze.SOLVER_ITERATIONS, "ls_iterations": antmaze.LS_ITERATIONS,
                         "integrator": "RK4 (unless named)", "upper_leg_contacts": False},
        "mjx": {},
    }
    for integrator in args.integrators:
        env = antmaze.AntMaze(args.maze, integrator=integrator)
        for batch in args.batches:
            r = mjx_speed(env, batch, args.steps, args.reps)
            result["mjx"][f"{integrator}_batch{batch}"] = r
            print(f"mjx {integrator} batch {batch}: {r['control_steps_per_s']:.0f} control steps/s "
                  f"(compile {r['compile_s']:.0f} s)", flush=True)
    result["native"] = native_speed(args.maze, args.native_steps, args.reps)
    print(f"native {NATIVE_IDS[args.maze]}: {result['native']['control_steps_per_s']:.0f} control steps/s", flush=True)
    result["machine"]["loadavg_end"] = os.getloadavg()
    write_json_atomic(args.out, result)
    print(f"wrote {args.out}")
    return result


if __name__ == "__main__":
    import tyro

    main(tyro.cli(Args))
