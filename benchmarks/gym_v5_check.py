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

SAC_UPDATE_S = 1.0 / 195.0  # FACTS.md: one SAC update (2x256, batch 256) on this CPU, lax.scan, single run


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


def lockstep_stats(task: str, args: Args, env, step) -> dict:
    import numpy as np

    from proto_brax.envs import gym_v5

    native = gym_v5.native_env(task)
    runs = []
    for start in range(args.starts):
        native.reset(seed=start)
        actions = np.random.default_rng(1000 + start).uniform(-1, 1, (args.lockstep_steps, env.action_size))
        runs.append(gym_v5.lockstep(env, step, native, actions))

    def first_above(err, tol):
        above = np.nonzero(err > tol)[0]
        return int(above[0]) + 1 if above.size else None  # steps are 1-based

    out = {"steps": args.lockstep_steps, "starts": args.starts}
    for key in ("qpos_err", "obs_err", "reward_err"):
        errs = np.stack([r[key] for r in runs])
        out[key] = {f"step_{s}": float(errs[:, s - 1].max()) for s in (1, 10, 50) if s <= args.lockstep_steps}
    for tol in (1e-3, 1e-1):
        firsts = [first_above(r["qpos_err"], tol) for r in runs]
        out[f"first_step_qpos_err_above_{tol:g}"] = firsts
    out["first_done_step"] = [[int(np.argmax(r[k])) + 1 if r[k].any() else None for k in ("done", "native_done")]
                              for r in runs]
    return out


def our_returns(env, episodes: int, key, episode_length: int = 1000):
    """Random-policy returns and lengths of ``episodes`` envs run once to termination or the time limit."""
    import jax
    import jax.numpy as jnp

    def one(key):
        key_reset, key_act = jax.random.split(key)
        state = env.reset(key_reset)

        def body(carry, key_t):
            state, ret, length, alive = carry
            action = jax.random.uniform(key_t, (env.action_size,), minval=-1.0, maxval=1.0)
            nxt = env.step(state, action)
            ret = ret + jnp.where(alive, nxt.reward, 0.0)
            length = length + alive
            alive = alive & (nxt.done == 0)
            return (nxt, ret, length, alive), None

        keys = jax.random.split(key_act, episode_length)
        (_, ret, length, _), _ = jax.lax.scan(body, (state, jnp.zeros(()), jnp.zeros((), jnp.int32), True), keys)
        return ret, length

    fn = jax.jit(jax.vmap(one))
    t0 = time.perf_counter()
    compiled = fn.lower(jax.random.split(key, episodes)).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    ret, length = jax.block_until_ready(compiled(jax.random.split(key, episodes)))
    run_s = time.perf_counter() - t0
    return ret, length, compile_s, run_s


def native_returns(task: str, episodes: int, seed: int):
    import gymnasium as gym
    import numpy as np

    from proto_brax.envs import gym_v5

    env = gym.make(gym_v5.get_task(task).gym_id)  # with gymnasium's TimeLimit(1000)
    rng = np.random.default_rng(seed)
    returns, lengths, steps = [], [], 0
    t0 = time.perf_counter()
    for episode in range(episodes):
        env.reset(seed=seed + episode)
        total, n, done = 0.0, 0, False
        while not done:
            _, reward, terminated, truncated, _ = env.step(rng.uniform(-1.0, 1.0, env.action_space.shape))
            total, n, done = total + reward, n + 1, terminated or truncated
        returns.append(total)
        lengths.append(n)
        steps += n
    return np.asarray(returns), np.asarray(lengths), steps / (time.perf_counter() - t0)


def summary(x) -> dict:
    import numpy as np

    x = np.asarray(x, np.float64)
    se = float(x.std(ddof=1) / np.sqrt(len(x)))
    mean = float(x.mean())
    return {"n": len(x), "mean": mean, "std": float(x.std(ddof=1)), "se": se, "ci95": [mean - 1.96 * se,
                                                                                          mean + 1.96 * se]}


def scan_speed(env, batch: int, steps: int, key) -> dict:
    """Env steps/s (all envs together) of a jitted lax.scan of random-action steps, after compile."""
    import jax

    def rollout(key):
        key_reset, key_act = jax.random.split(key)
        state = jax.vmap(env.reset)(jax.random.split(key_reset, batch))

        def body(state, key_t):
            action = jax.random.uniform(key_t, (batch, env.action_size), minval=-1.0, maxval=1.0)
            return jax.vmap(env.step)(state, action), None

        state, _ = jax.lax.scan(body, state, jax.random.split(key_act, steps))
        return state.obs

    fn = jax.jit(rollout)
    t0 = time.perf_counter()
    compiled = fn.lower(key).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(key))  # warm
    t0 = time.perf_counter()
    jax.block_until_ready(compiled(jax.random.fold_in(key, 1)))
    run_s = time.perf_counter() - t0
    return {"batch": batch, "steps": steps, "compile_s": compile_s, "steps_per_s": batch * steps / run_s}


def main(args: Args) -> None:
    from proto_brax import envs

    os.environ["XLA_FLAGS"] = envs.mjx_xla_flags()  # before jax starts (FACTS.md: batched MJX hangs without it)
    import jax


    result = {"date": datetime.date.today().isoformat(), "machine": envs.machine_info(),
              "args": {k: str(v) if isinstance(v, Path) else v for k, v in dataclasses.asdict(args).items()},
              "sac_update_s_assumed": SAC_UPDATE_S, "tasks": {}}
    key = jax.random.PRNGKey(args.seed)
    for task in args.tasks:
        name = f"{task}-v5"
        env = envs.make_env(name)
        spec = envs.get_spec(name)
        row: dict = {}
        t0 = time.perf_counter()
        step = jax.jit(env.step)
        row["lockstep"] = lockstep_stats(task, args, env, step)
        row["lockstep"]["wall_s"] = time.perf_counter() - t0
        print(task, "lockstep", json.dumps(row["lockstep"]), flush=True)

        ret, length, compile_s, run_s = our_returns(env, args.episodes, jax.random.fold_in(key, 1))
        nat_ret, nat_len, native_sps = native_returns(task, args.episodes, args.seed)
        ours, theirs = summary(ret), summary(nat_ret)
        diff = ours["mean"] - theirs["mean"]
        se = (ours["se"] ** 2 + theirs["se"] ** 2) ** 0.5
        row["random_policy"] = {
            "ours": {**ours, "mean_length": float(length.mean()), "compile_s": compile_s,
                     "steps_per_s": float(length.sum()) / run_s},
            "native": {**theirs, "mean_length": float(nat_len.mean()), "steps_per_s": native_sps},
            "diff": diff, "diff_se": se, "z": diff / se if se > 0 else 0.0, "within_ci95": abs(diff) <= 1.96 * se,
            "d4rl_random_ref_v2": spec.ref_random}
        print(task, "random policy", json.dumps(row["random_policy"]), flush=True)

        # Ours at batch ``episodes``: the return rollout above (every env runs all 1000 scanned steps, ended or not).
        speed = {"ours_b1": scan_speed(env, 1, args.speed_steps, key),
                 "ours_batch": {"batch": args.episodes, "steps": 1000, "compile_s": compile_s,
                                "steps_per_s": args.episodes * 1000 / run_s}}
        if args.brax:
            brax_env = envs.make_env(task)
            backend = envs.get_spec(task).default_backend
            speed["brax_b1"] = {"backend": backend, **scan_speed(brax_env, 1, args.speed_steps, key)}
            if args.batch > 1:
                speed["brax_batch"] = {"backend": backend, **scan_speed(brax_env, args.batch, args.speed_steps, key)}
        speed["native_one_env"] = native_sps
        step_s = 1.0 / speed["ours_b1"]["steps_per_s"]
        speed["ours_b1_step_ms"] = 1e3 * step_s
        speed["ours_b1_share_of_online_step"] = step_s / (step_s + SAC_UPDATE_S)
        row["speed"] = speed
        print(task, "speed", json.dumps(speed), flush=True)
        result["tasks"][task] = row
    result["machine"]["loadavg_end"] = os.getloadavg()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print("wrote", args.out)


if __name__ == "__main__":
    main(tyro.cli(Args))
