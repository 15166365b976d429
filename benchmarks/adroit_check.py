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
import statistics
import sys
import time
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
    """Also time (interleaved, batch 1) and cross-check the env as it was before the contact bound and the sensor
    pruning (``max_contact_points=None, all_sensors=True``)."""
    merge: bool = False
    """Keep the other tasks already in ``out`` (re-run one task without losing the rest)."""


def native_rollout(task: str, model, layout, actions):
    """Native MuJoCo rollout with gymnasium-robotics' reset and step; (obs [T+1], reward [T], qpos [T+1])."""
    import mujoco
    import numpy as np

    from proto_brax.envs import adroit

    field, body = adroit.LAYOUT[task]
    ids = adroit.task_ids(task, model)
    saved = getattr(model, field)[ids.body[body]].copy()
    getattr(model, field)[ids.body[body]] = layout
    try:
        data = mujoco.MjData(model)
        mujoco.mj_resetData(model, data)
        mujoco.mj_forward(model, data)
        act_mean = np.mean(model.actuator_ctrlrange, axis=1)
        act_rng = 0.5 * (model.actuator_ctrlrange[:, 1] - model.actuator_ctrlrange[:, 0])

        def obs():
            return adroit.observation(task, ids, data.qpos, data.qvel, data.xpos, data.xquat, data.site_xpos,
                                      data.sensordata, xp=np)

        observations, rewards, qpos = [obs()], [], [data.qpos.copy()]
        for a in actions:
            data.ctrl[:] = act_mean + np.clip(a, -1.0, 1.0) * act_rng
            mujoco.mj_step(model, data, nstep=adroit.FRAME_SKIP)
            mujoco.mj_rnePostConstraint(model, data)  # as gymnasium's do_simulation
            r, _, _ = adroit.reward_and_success(task, ids, data.qpos, data.qvel, data.xpos, data.site_xpos, xp=np)
            observations.append(obs())
            rewards.append(float(r))
            qpos.append(data.qpos.copy())
    finally:
        getattr(model, field)[ids.body[body]] = saved
    return np.array(observations), np.array(rewards), np.array(qpos)


def gym_rollout(task: str, layout, actions):
    """gymnasium-robotics' own env from the same layout and qpos0."""
    import gymnasium as gym
    import gymnasium_robotics
    import numpy as np

    from proto_brax.envs import adroit

    gym.register_envs(gymnasium_robotics)
    env = gym.make(adroit.get_task(task).gym_id, max_episode_steps=10**9).unwrapped
    env.reset(seed=0)
    key = {"pen": "desired_orien", "door": "door_body_pos", "hammer": "board_pos"}[task]
    env.set_env_state({"qpos": env.init_qpos.copy(), "qvel": env.init_qvel.copy(),
                       key: np.asarray(layout, np.float64)})
    observations, rewards, qpos = [env._get_obs()], [], [env.data.qpos.copy()]
    for a in actions:
        o, r, *_ = env.step(a)
        observations.append(o)
        rewards.append(float(r))
        qpos.append(env.data.qpos.copy())
    env.close()
    return np.array(observations), np.array(rewards), np.array(qpos)


def compare(a, b, early: int = 10) -> dict:
    import numpy as np

    (oa, ra, qa), (ob, rb, qb) = a, b
    return {
        "max_abs_obs": float(np.max(np.abs(oa - ob))),
        "max_abs_qpos": float(np.max(np.abs(qa - qb))),
        "max_abs_reward": float(np.max(np.abs(ra - rb))),
        f"max_abs_obs_first{early}": float(np.max(np.abs(oa[: early + 1] - ob[: early + 1]))),
        f"max_abs_qpos_first{early}": float(np.max(np.abs(qa[: early + 1] - qb[: early + 1]))),
        "return_a": float(np.sum(ra)),
        "return_b": float(np.sum(rb)),
        "qpos_excursion": float(np.max(np.abs(qb - qb[0]))),  # scale of the motion itself
    }


def check_task(task: str, args: Args) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from proto_brax.envs import adroit

    spec = adroit.get_task(task)
    xml_kwargs = {k: v for k, v in (("max_geom_pairs", args.max_geom_pairs),
                                    ("max_contact_points", args.max_contact_points)) if v is not None}
    if xml_kwargs.get("max_contact_points") == 0:
        xml_kwargs["max_contact_points"] = None  # unbounded
    env = adroit.Adroit(task, **xml_kwargs)
    own = np.asarray(getattr(env.sys, env._layout_field))[env._layout_body]
    layout = np.asarray(adroit.sample_layout(task, jax.random.PRNGKey(args.seed), jnp.asarray(own)), np.float64)
    actions = np.random.default_rng(args.seed).uniform(-1.0, 1.0, (args.steps, spec.act_size)).astype(np.float32)

    original = native_rollout(task, adroit.load_original_model(task), layout, actions)
    capsule = native_rollout(task, adroit.load_capsule_model(task, **xml_kwargs), layout, actions)
    gym = gym_rollout(task, layout, actions)
    # Chaos floor: the original model again, actions nudged by 1e-6 (float32 round-off of an action in [-1, 1]).
    nudge = np.random.default_rng(args.seed + 7).choice([-1e-6, 1e-6], actions.shape)
    nudged = native_rollout(task, adroit.load_original_model(task), layout, actions + nudge)

    def make_rollout(env):
        def rollout(layout, actions):
            s = env.reset_to(layout, env.sys.qpos0, jnp.zeros(env.sys.nv))

            def body(s, a):
                s = env.step(s, a)
                return s, (s.obs, s.reward, s.pipeline_state.qpos, s.done)

            _, (obs, rew, qpos, done) = jax.lax.scan(body, s, actions)
            return (jnp.concatenate([s.obs[None], obs]), rew,
                    jnp.concatenate([s.pipeline_state.qpos[None], qpos]), done)
        return rollout

    rollout = make_rollout(env)

    def timed(fn, *xs):
        t0 = time.perf_counter()
        compiled = jax.jit(fn).lower(*xs).compile()
        compile_s = time.perf_counter() - t0
        out = jax.block_until_ready(compiled(*xs))
        times = []
        for _ in range(args.reps):
            t0 = time.perf_counter()
            jax.block_until_ready(compiled(*xs))
            times.append(time.perf_counter() - t0)
        return out, compile_s, times, compiled

    layout32, actions32 = jnp.asarray(layout, jnp.float32), jnp.asarray(actions)
    out, compile_s, times, new_c = timed(rollout, layout32, actions32)
    mjx = tuple(np.asarray(x, np.float64) for x in out[:3])
    speed = {"batch1": {"compile_s": compile_s, "seconds_per_call": times,
                        "control_steps_per_s": args.steps / statistics.median(times)}}
    baseline = None
    if args.baseline:  # the env before the contact bound and sensor pruning, timed interleaved with today's
        old = adroit.Adroit(task, **{**xml_kwargs, "max_contact_points": None, "all_sensors": True})
        old_c = jax.jit(make_rollout(old)).lower(layout32, actions32).compile()
        old_out = jax.block_until_ready(old_c(layout32, actions32))
        pair = {"baseline": [], "env": []}
        for _ in range(args.reps):
            for name, c in (("baseline", old_c), ("env", new_c)):
                t0 = time.perf_counter()
                jax.block_until_ready(c(layout32, actions32))
                pair[name].append(time.perf_counter() - t0)
        rate = {k: args.steps / statistics.median(v) for k, v in pair.items()}
        speed["batch1_interleaved"] = {"seconds_per_call": pair, "control_steps_per_s": rate,
                                       "env_over_baseline": rate["env"] / rate["baseline"]}
        baseline = compare(tuple(np.asarray(x, np.float64) for x in old_out[:3]), capsule)
    if args.batch:
        keys = jax.random.split(jax.random.PRNGKey(args.seed + 1), args.batch)
        layouts = jax.vmap(lambda k: adroit.sample_layout(task, k, jnp.asarray(own, jnp.float32)))(keys)
        acts = jnp.broadcast_to(actions32, (args.batch, *actions32.shape))
        out_b, compile_b, times_b, _ = timed(jax.vmap(rollout), layouts, acts)
        speed[f"batch{args.batch}"] = {"compile_s": compile_b, "seconds_per_call": times_b,
                                       "control_steps_per_s": args.batch * args.steps / statistics.median(times_b),
                                       "all_finite": bool(np.isfinite(np.asarray(out_b[0])).all())}
    speed["native_gymnasium"] = native_speed(spec.gym_id, spec.act_size, args.native_steps, args.reps)
    return {
        "settings": {"steps": args.steps, "batch": args.batch, "reps": args.reps, "seed": args.seed,
                     "mjx_xml_kwargs": xml_kwargs},
        "layout": layout.tolist(),
        "gym_vs_native_original": compare(gym, original),
        "nudged_vs_original_native": compare(nudged, original),
        "capsule_vs_original_native": compare(capsule, original),
        "mjx_vs_native_capsule": compare(mjx, capsule),
        "mjx_baseline_vs_native_capsule": baseline,
        "mjx_done_any": bool(np.asarray(out[3]).any()),
        "speed": speed,
    }


def native_speed(gym_id: str, act_size: int, n: int, reps: int) -> dict:
    import gymnasium as gym
    import gymnasium_robotics
    import numpy as np

    gym.register_envs(gymnasium_robotics)
    env = gym.make(gym_id, max_episode_steps=10**9)
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1.0, 1.0, (n, act_size)).astype(np.float32)
    for a in actions[:50]:
        env.step(a)
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        for a in actions:
            env.step(a)
        times.append(time.perf_counter() - t0)
    env.close()
    return {"steps": n, "seconds_per_rep": times, "control_steps_per_s": n / statistics.median(times)}


def main(args: Args) -> dict:
    from proto_brax.envs import machine_info, single_thread_mjx_xla_flags

    os.environ["XLA_FLAGS"] = single_thread_mjx_xla_flags()

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
        r = check_task(task, args)
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
