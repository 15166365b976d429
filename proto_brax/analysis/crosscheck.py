"""Cross-checks of our MJX envs against the native MuJoCo envs they reproduce: Adroit against gymnasium-robotics
(``benchmarks/adroit_check.py``) and the gymnasium v5 locomotion against gymnasium (``benchmarks/gym_v5_check.py``).
Both compare trajectories from the same state under the same actions, then time the jitted MJX rollout (compiled
ahead of time with ``timing.aot``) against the native env stepping in a Python loop.

Import it after setting ``XLA_FLAGS``: it imports JAX and MuJoCo (no backend starts before the first computation)."""

from __future__ import annotations

import statistics
import time

import gymnasium as gym
import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from proto_brax import envs
from proto_brax.analysis.timing import aot
from proto_brax.envs import adroit, gym_v5

SAC_UPDATE_S = 1.0 / 195.0  # FACTS.md: one SAC update (2x256, batch 256) on this CPU, lax.scan, single run


def timed_calls(compiled, *xs, reps: int) -> tuple[list[float], object]:
    """``reps`` timed calls of ``compiled(*xs)`` after one untimed warm-up call; (seconds per call, the warm output)."""
    out = jax.block_until_ready(compiled(*xs))
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(*xs))
        times.append(time.perf_counter() - t0)
    return times, out


# ----------------------------------------------------------------------------------------------------------------
# Adroit (pen, door, hammer) against gymnasium-robotics


def xml_kwargs(max_geom_pairs: int | None, max_contact_points: int | None) -> dict:
    """The MJX contact bounds to pass to ``adroit.Adroit``: None leaves the env's default; ``max_contact_points`` 0
    means unbounded (None, which would otherwise mean the default)."""
    kwargs = {k: v for k, v in (("max_geom_pairs", max_geom_pairs), ("max_contact_points", max_contact_points))
              if v is not None}
    if kwargs.get("max_contact_points") == 0:
        kwargs["max_contact_points"] = None  # unbounded
    return kwargs


def native_rollout(task: str, model, layout, actions):
    """Native MuJoCo rollout with gymnasium-robotics' reset and step; (obs [T+1], reward [T], qpos [T+1])."""
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
    """gymnasium-robotics' own env from the same layout and qpos0; (obs [T+1], reward [T], qpos [T+1])."""
    import gymnasium_robotics  # here: its import prints a notice, which the gymnasium v5 check has no use for

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


def mjx_rollout(env: adroit.Adroit):
    """``rollout(layout, actions)``: our env reset to ``layout`` and qpos0, then scanned over ``actions``;
    (obs [T+1], reward [T], qpos [T+1], done [T])."""

    def rollout(layout, actions):
        s = env.reset_to(layout, env.sys.qpos0, jnp.zeros(env.sys.nv))

        def body(s, a):
            s = env.step(s, a)
            return s, (s.obs, s.reward, s.pipeline_state.qpos, s.done)

        _, (obs, rew, qpos, done) = jax.lax.scan(body, s, actions)
        return (jnp.concatenate([s.obs[None], obs]), rew,
                jnp.concatenate([s.pipeline_state.qpos[None], qpos]), done)

    return rollout


def compare(a, b, early: int = 10) -> dict:
    """Max |Δ| of obs, qpos and reward between rollouts ``a`` and ``b`` (obs, reward, qpos), over all steps and
    over the first ``early``; both returns; ``b``'s own scale of motion (max |qpos_t − qpos_0|)."""
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


def native_speed(gym_id: str, act_size: int, n: int, reps: int) -> dict:
    """Control steps/s of one gymnasium-robotics env stepping ``n`` random actions (median of ``reps``)."""
    import gymnasium_robotics  # as in gym_rollout

    gym.register_envs(gymnasium_robotics)
    times = native_step_times(gym.make(gym_id, max_episode_steps=10**9), act_size, n, reps)
    return {"steps": n, "seconds_per_rep": times, "control_steps_per_s": n / statistics.median(times)}


def native_step_times(env, act_size: int, n: int, reps: int) -> list[float]:
    """Seconds of ``n`` steps of a native gymnasium ``env`` on fixed uniform random actions, per repetition, after a
    50-step warm-up from ``reset(seed=0)``; the env is closed after."""
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
    return times


def check_adroit_task(task: str, *, steps: int, batch: int, reps: int, native_steps: int, seed: int,
                      max_geom_pairs: int | None, max_contact_points: int | None, baseline: bool) -> dict:
    """One Adroit task's cross-checks and speeds (``benchmarks/adroit_check.py``'s docstring): gymnasium vs our
    numpy formulas, capsule vs original XML, the chaos floor, MJX vs native; MJX at batch 1 and ``batch`` (0 skips
    it), with ``baseline`` the env before the contact bounds, the pruned colliders and the sensor pruning timed
    interleaved; native speed."""
    spec = adroit.get_task(task)
    kwargs = xml_kwargs(max_geom_pairs, max_contact_points)
    env = adroit.Adroit(task, **kwargs)
    own = np.asarray(getattr(env.sys, env._layout_field))[env._layout_body]
    layout = np.asarray(adroit.sample_layout(task, jax.random.PRNGKey(seed), jnp.asarray(own)), np.float64)
    actions = np.random.default_rng(seed).uniform(-1.0, 1.0, (steps, spec.act_size)).astype(np.float32)

    original = native_rollout(task, adroit.load_original_model(task), layout, actions)
    capsule = native_rollout(task, adroit.load_capsule_model(task, **kwargs), layout, actions)
    gym_run = gym_rollout(task, layout, actions)
    # Chaos floor: the original model again, actions nudged by 1e-6 (float32 round-off of an action in [-1, 1]).
    nudge = np.random.default_rng(seed + 7).choice([-1e-6, 1e-6], actions.shape)
    nudged = native_rollout(task, adroit.load_original_model(task), layout, actions + nudge)

    rollout = mjx_rollout(env)
    layout32, actions32 = jnp.asarray(layout, jnp.float32), jnp.asarray(actions)
    new_c, compile_s = aot(rollout, layout32, actions32)
    times, out = timed_calls(new_c, layout32, actions32, reps=reps)
    mjx = tuple(np.asarray(x, np.float64) for x in out[:3])
    speed = {"batch1": {"compile_s": compile_s, "seconds_per_call": times,
                        "control_steps_per_s": steps / statistics.median(times)}}
    baseline_check = None
    if baseline:  # the env before the contact bounds, pruned colliders and sensor pruning, interleaved with today's
        old = adroit.Adroit(task, **{**kwargs, "max_contact_points": None, "all_sensors": True,
                                     "prune_colliders": False})
        old_c, _ = aot(mjx_rollout(old), layout32, actions32)
        old_out = jax.block_until_ready(old_c(layout32, actions32))
        pair = {"baseline": [], "env": []}
        for _ in range(reps):
            for name, c in (("baseline", old_c), ("env", new_c)):
                t0 = time.perf_counter()
                jax.block_until_ready(c(layout32, actions32))
                pair[name].append(time.perf_counter() - t0)
        rate = {k: steps / statistics.median(v) for k, v in pair.items()}
        speed["batch1_interleaved"] = {"seconds_per_call": pair, "control_steps_per_s": rate,
                                       "env_over_baseline": rate["env"] / rate["baseline"]}
        baseline_check = compare(tuple(np.asarray(x, np.float64) for x in old_out[:3]), capsule)
    if batch:
        keys = jax.random.split(jax.random.PRNGKey(seed + 1), batch)
        layouts = jax.vmap(lambda k: adroit.sample_layout(task, k, jnp.asarray(own, jnp.float32)))(keys)
        acts = jnp.broadcast_to(actions32, (batch, *actions32.shape))
        batched, compile_b = aot(jax.vmap(rollout), layouts, acts)
        times_b, out_b = timed_calls(batched, layouts, acts, reps=reps)
        speed[f"batch{batch}"] = {"compile_s": compile_b, "seconds_per_call": times_b,
                                  "control_steps_per_s": batch * steps / statistics.median(times_b),
                                  "all_finite": bool(np.isfinite(np.asarray(out_b[0])).all())}
    speed["native_gymnasium"] = native_speed(spec.gym_id, spec.act_size, native_steps, reps)
    return {
        "settings": {"steps": steps, "batch": batch, "reps": reps, "seed": seed, "mjx_xml_kwargs": kwargs},
        "layout": layout.tolist(),
        "gym_vs_native_original": compare(gym_run, original),
        "nudged_vs_original_native": compare(nudged, original),
        "capsule_vs_original_native": compare(capsule, original),
        "mjx_vs_native_capsule": compare(mjx, capsule),
        "mjx_baseline_vs_native_capsule": baseline_check,
        "mjx_done_any": bool(np.asarray(out[3]).any()),
        "speed": speed,
    }


# ----------------------------------------------------------------------------------------------------------------
# Gymnasium v5 locomotion against gymnasium


def first_above(err: np.ndarray, tol: float) -> int | None:
    """The first (1-based) step whose error exceeds ``tol``; None when none does."""
    above = np.nonzero(err > tol)[0]
    return int(above[0]) + 1 if above.size else None


def lockstep_stats(task: str, env, step, starts: int, lockstep_steps: int) -> dict:
    """Ours (jitted ``step``) and gymnasium's env in lockstep from ``starts`` of gymnasium's resets on random actions:
    the max errors at steps 1, 10, 50, the first steps where |Δqpos| exceeds 1e-3 and 1e-1, each side's first done."""
    native = gym_v5.gymnasium_env(task)
    runs = []
    for start in range(starts):
        native.reset(seed=start)
        actions = np.random.default_rng(1000 + start).uniform(-1, 1, (lockstep_steps, env.action_size))
        runs.append(gym_v5.lockstep(env, step, native, actions))

    out = {"steps": lockstep_steps, "starts": starts}
    for key in ("qpos_err", "obs_err", "reward_err"):
        errs = np.stack([r[key] for r in runs])
        out[key] = {f"step_{s}": float(errs[:, s - 1].max()) for s in (1, 10, 50) if s <= lockstep_steps}
    for tol in (1e-3, 1e-1):
        firsts = [first_above(r["qpos_err"], tol) for r in runs]
        out[f"first_step_qpos_err_above_{tol:g}"] = firsts
    out["first_done_step"] = [[int(np.argmax(r[k])) + 1 if r[k].any() else None for k in ("done", "native_done")]
                              for r in runs]
    return out


def our_returns(env, episodes: int, key, episode_length: int = 1000):
    """Random-policy returns and lengths of ``episodes`` envs run once to termination or the time limit (one
    vmapped ``lax.scan`` of all ``episode_length`` steps); (returns, lengths, compile seconds, run seconds)."""

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

    compiled, compile_s = aot(jax.vmap(one), jax.random.split(key, episodes))
    t0 = time.perf_counter()
    ret, length = jax.block_until_ready(compiled(jax.random.split(key, episodes)))
    run_s = time.perf_counter() - t0
    return ret, length, compile_s, run_s


def native_returns(task: str, episodes: int, seed: int):
    """Random-policy returns and lengths of ``episodes`` episodes of gymnasium's env (its 1000-step time limit), and
    its env steps/s."""
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
    """Sample size, mean, standard deviation, standard error and normal 95% CI of the mean of ``x``."""
    x = np.asarray(x, np.float64)
    se = float(x.std(ddof=1) / np.sqrt(len(x)))
    mean = float(x.mean())
    return {"n": len(x), "mean": mean, "std": float(x.std(ddof=1)), "se": se, "ci95": [mean - 1.96 * se,
                                                                                          mean + 1.96 * se]}


def returns_comparison(ours: dict, theirs: dict) -> dict:
    """Difference of two ``summary`` means, its standard error, Welch's z and whether it lies within its 95% CI."""
    diff = ours["mean"] - theirs["mean"]
    se = (ours["se"] ** 2 + theirs["se"] ** 2) ** 0.5
    return {"diff": diff, "diff_se": se, "z": diff / se if se > 0 else 0.0, "within_ci95": abs(diff) <= 1.96 * se}


def random_policy(task: str, env, episodes: int, seed: int, key) -> tuple[dict, dict, float]:
    """The uniform random policy's returns, ours against gymnasium's, with D4RL's random reference (v2 envs); the
    timing of our return rollout as a speed at batch ``episodes``; native gymnasium's env steps/s."""
    ret, length, compile_s, run_s = our_returns(env, episodes, key)
    nat_ret, nat_len, native_sps = native_returns(task, episodes, seed)
    ours, theirs = summary(ret), summary(nat_ret)
    row = {
        "ours": {**ours, "mean_length": float(length.mean()), "compile_s": compile_s,
                 "steps_per_s": float(length.sum()) / run_s},
        "native": {**theirs, "mean_length": float(nat_len.mean()), "steps_per_s": native_sps},
        **returns_comparison(ours, theirs),
        "d4rl_random_ref_v2": envs.get_spec(f"{task}-v5").ref_random}
    # Every env of the return rollout runs all 1000 scanned steps, ended or not.
    ours_batch = {"batch": episodes, "steps": 1000, "compile_s": compile_s, "steps_per_s": episodes * 1000 / run_s}
    return row, ours_batch, native_sps


def scan_speed(env, batch: int, steps: int, key) -> dict:
    """Env steps/s (all envs together) of a jitted lax.scan of random-action steps, after compile."""

    def rollout(key):
        key_reset, key_act = jax.random.split(key)
        state = jax.vmap(env.reset)(jax.random.split(key_reset, batch))

        def body(state, key_t):
            action = jax.random.uniform(key_t, (batch, env.action_size), minval=-1.0, maxval=1.0)
            return jax.vmap(env.step)(state, action), None

        state, _ = jax.lax.scan(body, state, jax.random.split(key_act, steps))
        return state.obs

    compiled, compile_s = aot(rollout, key)
    jax.block_until_ready(compiled(key))  # warm
    t0 = time.perf_counter()
    jax.block_until_ready(compiled(jax.random.fold_in(key, 1)))
    run_s = time.perf_counter() - t0
    return {"batch": batch, "steps": steps, "compile_s": compile_s, "steps_per_s": batch * steps / run_s}


def gym_v5_speed(task: str, env, steps: int, key, ours_batch: dict, native_sps: float, brax: bool,
                 batch: int) -> dict:
    """Env steps/s of ours at batch 1 and (from ``random_policy``) at batch ``episodes``, of Brax's own env at the
    registry's default backend at batch 1 and ``batch`` (with ``brax``), of native gymnasium; ours' batch-1 step
    time and its share of an online step beside one SAC update (``SAC_UPDATE_S``)."""
    speed = {"ours_b1": scan_speed(env, 1, steps, key), "ours_batch": ours_batch}
    if brax:
        brax_env = envs.make_env(task)
        backend = envs.get_spec(task).default_backend
        speed["brax_b1"] = {"backend": backend, **scan_speed(brax_env, 1, steps, key)}
        if batch > 1:
            speed["brax_batch"] = {"backend": backend, **scan_speed(brax_env, batch, steps, key)}
    speed["native_one_env"] = native_sps
    step_s = 1.0 / speed["ours_b1"]["steps_per_s"]
    speed["ours_b1_step_ms"] = 1e3 * step_s
    speed["ours_b1_share_of_online_step"] = step_s / (step_s + SAC_UPDATE_S)
    return speed
