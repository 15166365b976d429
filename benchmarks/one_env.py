"""One env, batch of one: unbatched physics against a batch-of-one ``vmap``, and evaluation episodes one at a time
against side by side.

    python benchmarks/one_env.py                      # pen door hopper halfcheetah walker2d ant hopper-v5; ~15 min
    python benchmarks/one_env.py --envs pen hopper --out /tmp/one_env.json

Why: a one-run sweep steps one env (``num_envs`` 1). XLA:CPU runs a batch-of-one ``vmap`` of MJX's and Brax's
physics slower than the same step unbatched, so ``online.make_finetune`` steps a single env unbatched; and the MJX
hands run ten evaluation episodes faster one after another, each unbatched, than side by side, so their
``EnvSpec.eval_one_at_a_time`` is set (``train.evaluate.run_episode_stats``).

What runs, per env, on one XLA thread (as ``--single-core`` sweeps run), each program compiled first and the two sides
of a ratio timed interleaved, best of ``--reps``:

1. ``--steps`` calls of ``envs.env_step`` (auto-reset included) in one ``fori_loop``, uniform random actions: the env
   unbatched against a batch-of-one vmap.
2. ``--episodes`` evaluation episodes (``run_episode_stats``) of a fixed noisy linear policy, tanh(o·W + 0.3 ε):
   side by side against one at a time.

Prints each ratio and writes JSON (atomically) under benchmarks/results/. Measure on a quiet machine.
"""

from __future__ import annotations

import dataclasses
import datetime
import os
import sys
import time
from pathlib import Path

import _quiet  # noqa: F401  (first: the quiet start)
import tyro

ROOT = Path(__file__).resolve().parents[1]


@dataclasses.dataclass
class Args:
    envs: tuple[str, ...] = ("pen", "door", "hopper", "halfcheetah", "walker2d", "ant", "hopper-v5")
    steps: int = 200
    """env_step calls per timed program."""
    episodes: int = 10
    """Evaluation episodes (the sweeps' --eval-episodes)."""
    reps: int = 3
    out: Path = ROOT / "benchmarks" / "results" / "one_env.json"


def best_of(fns: dict, arg, reps: int) -> dict[str, float]:
    """Seconds of each compiled ``fns[name](arg)``, timed interleaved, best of ``reps``."""
    import jax

    for f in fns.values():
        jax.block_until_ready(f(arg))
    times = {name: [] for name in fns}
    for _ in range(reps):
        for name, f in fns.items():
            t = time.perf_counter()
            jax.block_until_ready(f(arg))
            times[name].append(time.perf_counter() - t)
    return {name: min(ts) for name, ts in times.items()}


def measure(name: str, args: Args) -> dict:
    import jax
    import jax.numpy as jnp
    from jax import lax

    from proto_brax import envs
    from proto_brax.train.evaluate import run_episode_stats

    env, spec = envs.make_env(name), envs.get_spec(name)
    horizon, n = spec.episode_length, args.steps

    def act(i):
        return jax.random.uniform(jax.random.PRNGKey(i), (env.action_size,), minval=-1.0, maxval=1.0)

    def unbatched(s):
        return lax.fori_loop(0, n, lambda i, s: envs.env_step(env, horizon, s, act(i), jax.random.PRNGKey(i))[0], s)

    def batch_of_one(s):
        step = jax.vmap(lambda s, a, k: envs.env_step(env, horizon, s, a, k)[0])
        return lax.fori_loop(0, n, lambda i, s: step(s, act(i)[None], jax.random.PRNGKey(i)[None]), s)

    s0 = envs.env_reset(env, jax.random.PRNGKey(0))
    step_s = best_of({"unbatched": jax.jit(unbatched),
                      "batch_of_one": jax.jit(lambda s: batch_of_one(jax.tree.map(lambda x: x[None], s)))},
                     s0, args.reps)
    w = 0.3 * jax.random.normal(jax.random.PRNGKey(3), (env.observation_size, env.action_size))

    def policy(obs, k):
        return jnp.tanh(obs @ w + 0.3 * jax.random.normal(k, (obs.shape[0], env.action_size)))

    evals = {mode: jax.jit(lambda k, m=m: run_episode_stats(env, horizon, policy, k, args.episodes, m))
             for mode, m in (("side_by_side", False), ("one_at_a_time", True))}
    eval_s = best_of(evals, jax.random.PRNGKey(1), args.reps)
    lengths = evals["side_by_side"](jax.random.PRNGKey(1)).lengths
    return {
        "env_step_ms": {k: 1e3 * v / n for k, v in step_s.items()},
        "batch_of_one_over_unbatched": step_s["batch_of_one"] / step_s["unbatched"],
        "eval_s": eval_s,
        "eval_mean_length": float(jnp.mean(lengths)),
        "side_by_side_over_one_at_a_time": eval_s["side_by_side"] / eval_s["one_at_a_time"],
        "eval_one_at_a_time_is_set": spec.eval_one_at_a_time,
    }


def main(args: Args) -> dict:
    from proto_brax.envs import machine_info, single_thread_mjx_xla_flags

    os.environ["XLA_FLAGS"] = single_thread_mjx_xla_flags()  # before JAX starts: one thread, MJX's scheduler fix
    from proto_brax.files import write_json_atomic

    result = {"command": " ".join(sys.argv), "date": datetime.datetime.now().isoformat(timespec="seconds"),
              "settings": dataclasses.asdict(args) | {"out": str(args.out)}, "machine": machine_info(), "envs": {}}
    print(f"{'env':12} {'step ms: unbatched':>19} {'batch of 1':>10} {'ratio':>6}   "
          f"{'eval s: side by side':>20} {'one at a time':>13} {'ratio':>6} {'length':>6} {'set':>4}", flush=True)
    for name in args.envs:
        r = result["envs"][name] = measure(name, args)
        ms, ev = r["env_step_ms"], r["eval_s"]
        print(f"{name:12} {ms['unbatched']:19.3f} {ms['batch_of_one']:10.3f} {r['batch_of_one_over_unbatched']:6.2f}"
              f"   {ev['side_by_side']:20.2f} {ev['one_at_a_time']:13.2f} {r['side_by_side_over_one_at_a_time']:6.2f}"
              f" {r['eval_mean_length']:6.0f} {str(r['eval_one_at_a_time_is_set']):>4}", flush=True)
        result["machine"]["loadavg_end"] = os.getloadavg()
        write_json_atomic(args.out, result)  # after each env: a partial run still leaves its numbers
    print(f"wrote {args.out}")
    return result


if __name__ == "__main__":
    main(tyro.cli(Args))
