"""What one PROTO update costs and how a grid of runs scales (``benchmarks/throughput.py``): the programs it times
(update-alone scans, the online chunk of one run and of a grid, a matmul chain), the measurements built from them, the
issue's goals and the summary table. The timing itself is ``proto_brax.analysis.timing``."""

from __future__ import annotations

import dataclasses
import datetime
import math
import os
import platform
import statistics
import sys
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from proto_brax import envs
from proto_brax.agents.learner import init_learner
from proto_brax.agents.registry import agent
from proto_brax.analysis.timing import Case, aot, flops_of, log, run_interleaved, synthetic_transitions, versions
from proto_brax.config import FinetuneConfig
from proto_brax.data.dataset import Transition
from proto_brax.data.replay import replay_init, replay_insert, replay_sample
from proto_brax.networks import NetworkConfig, make_networks
from proto_brax.train.grid import (
    compile_grid,
    grid_mesh,
    make_grid,
    pad_leading,
    padded_size,
    replicate,
    seed_keys,
    shard,
)
from proto_brax.train.online import make_finetune

GOALS = {  # issue 37's goals (the FLOP/s ratio's long-term goal is 0.8; the sharded 8-run grid is the sweep's program)
    "proto_vs_sac_time_ratio": ("<=", 1.10),
    "achieved_vs_matmul_gflops_ratio": (">=", 0.6),
    "grid_vmap_1dev_vs_single_ratio": (">=", 1.2),
    "grid_vmap_sharded_vs_single_ratio": (">=", 1.5),
    "online_step_vs_update_time_ratio": ("<=", 1.15),
}
# The measurement whose results hold each goal's ratio (under the goal's own name).
RATIO_SOURCES = {
    "proto_vs_sac_time_ratio": "1_proto_vs_sac",
    "achieved_vs_matmul_gflops_ratio": "2_gflops",
    "grid_vmap_1dev_vs_single_ratio": "3_grid_scaling",
    "grid_vmap_sharded_vs_single_ratio": "3_grid_scaling",
    "online_step_vs_update_time_ratio": "4_online_step_vs_update",
}


@dataclasses.dataclass(frozen=True)
class Sizes:
    hidden: tuple[int, ...]
    batch_size: int
    dataset_rows: int  # synthetic offline dataset
    buffer_rows: int  # rows inserted into the replay buffer of the update-alone scans
    n_updates: int  # updates per call of the update-alone scans
    chunk_steps: int  # env steps (= updates) per chunk call of the single run
    grid_size: int
    grid_chunk_steps: int  # env steps per run per chunk call of the grids
    run_steps: int  # FinetuneConfig.steps of the online configs (sets the replay capacity)
    matmul_n: int
    matmul_chain: int  # matmuls per call
    reps: int
    warmup: int


FULL = Sizes(hidden=(256, 256), batch_size=256, dataset_rows=100_000, buffer_rows=5_000, n_updates=2_000,
             chunk_steps=2_000, grid_size=8, grid_chunk_steps=500, run_steps=100_000, matmul_n=2048, matmul_chain=8,
             reps=3, warmup=1)
QUICK = Sizes(hidden=(32, 32), batch_size=32, dataset_rows=5_000, buffer_rows=1_000, n_updates=200, chunk_steps=100,
              grid_size=4, grid_chunk_steps=50, run_steps=2_000, matmul_n=512, matmul_chain=4, reps=2, warmup=1)


def environment(mode: str, sizes: Sizes) -> dict:
    """The run's circumstances for the JSON report: date, command, versions, devices, load and CPUs, XLA flags."""
    return {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "command": " ".join([os.path.basename(sys.executable)] + sys.argv),
        "mode": mode,
        "versions": versions(),
        "devices": [str(d) for d in jax.devices()],
        "default_backend": jax.default_backend(),
        "cpu_count": os.cpu_count(),
        "affinity_cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "loadavg_start": list(os.getloadavg()),
        "platform": platform.platform(),
        "processor": platform.processor(),
        "XLA_FLAGS": os.environ.get("XLA_FLAGS"),
        "sizes": dataclasses.asdict(sizes),
    }


# ----------------------------------------------------------------------------------------------------------------
# Update-alone programs (sample + update, as in the online loop but without the env)


def make_update_fns(cfg: FinetuneConfig, nets, n_updates: int):
    """(one update, a ``lax.scan`` of ``n_updates``): each a replay sample then the agent's update."""

    def one(learner, buffer, dataset, key, alpha, hp, i):
        k_sample, k_upd = jax.random.split(key)
        batch = replay_sample(k_sample, buffer, dataset, cfg.batch_size, cfg.sampling, cfg.offline_fraction)
        return agent(cfg.algo).update(learner, batch, k_upd, alpha, hp, nets, cfg, i)

    def single(learner, buffer, dataset, key, alpha, hp):
        return one(learner, buffer, dataset, key, alpha, hp, jnp.zeros((), jnp.int32))

    def scan(learner, buffer, dataset, key, alpha, hp):
        xs = (jnp.arange(n_updates), jax.random.split(key, n_updates))
        learner, m = lax.scan(lambda lrn, x: one(lrn, buffer, dataset, x[1], alpha, hp, x[0]), learner, xs)
        return learner, jax.tree.map(jnp.mean, m)  # metrics stay live, as in the online loop

    return single, scan


def update_setup(cfg: FinetuneConfig, sizes: Sizes, key: jax.Array):
    """Networks, hyper-parameters, learner, synthetic dataset and a part-filled replay buffer at ``cfg.env``'s sizes."""
    env = envs.make_env(cfg.env, cfg.backend)
    obs, act = env.observation_size, env.action_size
    nets = make_networks(cfg.net, act, deterministic=agent(cfg.algo).deterministic)
    hp = agent(cfg.algo).hparams.create()
    k_l, k_d, k_b = jax.random.split(key, 3)
    learner = init_learner(k_l, nets, agent(cfg.algo), hp, obs, act, None)
    dataset = synthetic_transitions(k_d, sizes.dataset_rows, obs, act)
    buffer = replay_insert(replay_init(2 * sizes.buffer_rows, obs, act),
                           synthetic_transitions(k_b, sizes.buffer_rows, obs, act))
    return nets, hp, learner, dataset, buffer, (obs, act)


def update_scan_case(name: str, cfg: FinetuneConfig, sizes: Sizes, key: jax.Array, with_flops: bool = False):
    """The compiled update-alone scan as a timed ``Case`` (``n_updates`` units per call), and its sizes and FLOPs."""
    nets, hp, learner, dataset, buffer, dims = update_setup(cfg, sizes, key)
    single, scan = make_update_fns(cfg, nets, sizes.n_updates)
    alpha = jnp.float32(2.0)
    args = (learner, buffer, dataset, jax.random.PRNGKey(1), alpha, hp)
    log(f"compiling {name} (scan of {sizes.n_updates} updates, obs/act {dims})")
    compiled, compile_s = aot(scan, *args)
    info: dict[str, Any] = {"obs_size": dims[0], "action_size": dims[1], "regularizer": cfg.regularizer}
    if with_flops:
        info["flops_scan_program"] = flops_of(compiled)
        one_compiled, _ = aot(single, *args)
        info["flops_single_update_program"] = flops_of(one_compiled)
    # Host (numpy) keys: indexing a device array per call would dispatch (and first compile) a slice op.
    keys = iter(np.asarray(jax.random.split(jax.random.PRNGKey(2), 10_000)))

    def step(lrn):
        return compiled(lrn, buffer, dataset, next(keys), alpha, hp)

    return Case(name, step, learner, sizes.n_updates, compile_s), info


# ----------------------------------------------------------------------------------------------------------------
# Online programs (env step + insert + sample + update, one chunk per call)


def online_cfg(sizes: Sizes, chunk_steps: int) -> FinetuneConfig:
    """Hopper online finetuning with ``chunk_steps`` per chunk; the 10-step episodes and one evaluation episode make
    the evaluation at a chunk's end negligible (the time limit only changes when the env resets)."""
    return FinetuneConfig(
        env="hopper", net=NetworkConfig(hidden=sizes.hidden), batch_size=sizes.batch_size,
        steps=sizes.run_steps, eval_every=chunk_steps, eval_episodes=1, learning_starts=1, sampling="symmetric",
        episode_length=10, regularizer=True,
    )


def single_run_case(cfg: FinetuneConfig, dataset: Transition) -> Case:
    """One run's compiled chunk (jit, one device) as a timed ``Case`` of ``eval_every`` updates per call."""
    ft = make_finetune(cfg)
    hp = ft.hparams.create()
    state = jax.jit(ft.init)(hp, jax.random.PRNGKey(3), None, dataset)
    start0 = jnp.asarray(0, jnp.int32)
    log(f"compiling single-run chunk ({cfg.eval_every} steps)")
    compiled, compile_s = aot(ft.chunk, state, hp, dataset, start0, donate_argnums=(0,))
    counter = {"c": 0}

    def step(s):
        counter["c"] += 1
        start = jnp.asarray((counter["c"] * cfg.eval_every) % cfg.steps, jnp.int32)
        return compiled(s, hp, dataset, start)

    return Case("3a single run (1 device)", step, state, cfg.eval_every, compile_s)


def grid_case(name: str, cfg: FinetuneConfig, dataset: Transition, grid_size: int, devices) -> Case:
    """A ``grid_size``-seed grid's compiled chunk, vmapped and sharded over ``devices``, as a timed ``Case`` of the
    real runs' updates per call."""
    ft = make_finetune(cfg)
    mesh = grid_mesh(devices)
    grid = make_grid({}, seeds=list(range(grid_size)), hparams=ft.hparams)
    size = padded_size(grid.size, mesh)
    program = compile_grid(ft, mesh)
    hp = shard(pad_leading(grid.hparams, size), mesh)
    keys = shard(pad_leading(seed_keys(grid.seeds), size), mesh)
    pretrained, ds = replicate((None, dataset), mesh)
    state = program.init(hp, keys, pretrained, ds)
    log(f"compiling {name} ({size} runs x {cfg.eval_every} steps on {len(mesh.devices.flat)} device(s))")
    start0 = replicate(jnp.asarray(0, jnp.int32), mesh)
    t0 = time.perf_counter()
    compiled = program.chunk.lower(state, hp, ds, start0).compile()
    compile_s = time.perf_counter() - t0
    counter = {"c": 0}

    def step(s):
        counter["c"] += 1
        start = replicate(jnp.asarray((counter["c"] * cfg.eval_every) % cfg.steps, jnp.int32), mesh)
        return compiled(s, hp, ds, start)

    # Padding runs (none when the grid size divides the device count) are work too, but not useful work.
    return Case(name, step, state, grid.size * cfg.eval_every, compile_s)


def matmul_case(n: int, chain: int) -> tuple[Case, float | None]:
    """A chain of ``chain`` f32 ``n``×``n`` matmuls as a timed ``Case`` (units: analytic FLOPs), and XLA's count."""
    ka, kb = jax.random.split(jax.random.PRNGKey(4))
    a = jax.random.normal(ka, (n, n), jnp.float32)
    b = jax.random.normal(kb, (n, n), jnp.float32) / math.sqrt(n)  # keeps the chain's magnitudes ~O(1)

    def f(x, b):
        return lax.fori_loop(0, chain, lambda i, y: y @ b, x)

    log(f"compiling matmul chain ({chain} x {n}^3)")
    compiled, compile_s = aot(f, a, b)
    xla_flops = flops_of(compiled)

    def step(x):
        return compiled(x, b), None

    return Case(f"matmul {n}x{n} chain of {chain}", step, a, 2.0 * n**3 * chain, compile_s), xla_flops


# ----------------------------------------------------------------------------------------------------------------
# Measurements


def gflops(f_single: float | None, f_scan: float | None, sac_f_single: float | None, n_updates: int,
           scan_seconds: float) -> dict:
    """FLOPs per PROTO update and the GFLOP/s achieved by a scan of ``n_updates`` taking ``scan_seconds``, from XLA's
    counts of the single-update program (``f_single``), of the scan program (``f_scan``) and of SAC's single update."""
    f_scan_per = f_scan / n_updates if f_scan is not None else None
    # Primary: the single-update program (cost analysis may count a while-loop body once, not trip-count times).
    flops_per_update = f_single if f_single is not None else f_scan_per
    return {
        "flops_per_update_single_program": f_single,
        "flops_scan_program": f_scan,
        "flops_scan_program_div_n": f_scan_per,
        "scan_vs_single_flops_ratio": (f_scan_per / f_single) if (f_scan_per and f_single) else None,
        "sac_flops_per_update_single_program": sac_f_single,
        "proto_vs_sac_flops_ratio": (f_single / sac_f_single) if (f_single and sac_f_single) else None,
        "flops_per_update_used": flops_per_update,
        "flops_source": "single-update program" if f_single is not None else "scan program / N",
        "scan_counted_once": bool(f_scan and f_single and f_scan < 2 * f_single),  # loop body counted once
        "achieved_gflops": flops_per_update / (scan_seconds / n_updates) / 1e9 if flops_per_update else None,
    }


def measure_update_cost(sizes: Sizes) -> dict:
    """Measurements 1 and 2: PROTO-SAC vs plain SAC update scans at halfcheetah sizes and the matmul chain, timed
    interleaved; the update cost ratio and the achieved GFLOP/s against the matmul's."""
    net = NetworkConfig(hidden=sizes.hidden)
    cfg_proto = FinetuneConfig(env="halfcheetah", net=net, batch_size=sizes.batch_size, sampling="symmetric",
                               regularizer=True)
    cfg_sac = dataclasses.replace(cfg_proto, regularizer=False)
    key = jax.random.PRNGKey(0)
    proto, proto_info = update_scan_case("1 PROTO-SAC update", cfg_proto, sizes, key, with_flops=True)
    plain, plain_info = update_scan_case("1 SAC update", cfg_sac, sizes, key, with_flops=True)
    mm, mm_xla_flops = matmul_case(sizes.matmul_n, sizes.matmul_chain)
    run_interleaved([proto, plain, mm], sizes.reps, sizes.warmup)

    flops = gflops(proto_info["flops_single_update_program"], proto_info["flops_scan_program"],
                   plain_info["flops_single_update_program"], sizes.n_updates, proto.median)
    mm_gflops = mm.rate / 1e9
    achieved = flops["achieved_gflops"]
    return {
        "1_proto_vs_sac": {
            "env_sizes": "halfcheetah", "hidden": sizes.hidden, "batch_size": sizes.batch_size,
            "sampling": "symmetric",
            "proto": {**proto.record(), **proto_info, "updates_per_s": proto.rate},
            "sac": {**plain.record(), **plain_info, "updates_per_s": plain.rate},
            "proto_vs_sac_time_ratio": proto.median / plain.median,
        },
        "2_gflops": {
            **flops,
            "matmul": {**mm.record(), "n": sizes.matmul_n, "chain": sizes.matmul_chain, "gflops": mm_gflops,
                       "xla_cost_analysis_flops": mm_xla_flops, "analytic_flops": mm.units},
            "achieved_vs_matmul_gflops_ratio": achieved / mm_gflops if achieved is not None else None,
        },
    }


def measure_online(sizes: Sizes, devices: list) -> dict:
    """Measurements 3 and 4 on hopper: updates/s of one run's chunk, of a grid vmapped on one device and sharded over
    ``devices``, and of the update-alone scan, timed interleaved; the grid's scaling and the online step's cost."""
    cfg_single = online_cfg(sizes, sizes.chunk_steps)
    cfg_grid = online_cfg(sizes, sizes.grid_chunk_steps)
    obs, act = envs.make_env("hopper").observation_size, envs.make_env("hopper").action_size
    dataset = synthetic_transitions(jax.random.PRNGKey(5), sizes.dataset_rows, obs, act)
    single = single_run_case(cfg_single, dataset)
    grid1 = grid_case(f"3b grid of {sizes.grid_size} vmapped, 1 device", cfg_grid, dataset, sizes.grid_size,
                      devices[:1])
    grid_all = grid_case(f"3c grid of {sizes.grid_size} vmapped, sharded over {len(devices)} devices", cfg_grid,
                         dataset, sizes.grid_size, devices)
    upd_hop, upd_hop_info = update_scan_case("4 update alone (hopper sizes)", cfg_single, sizes, jax.random.PRNGKey(6))
    run_interleaved([single, grid1, grid_all, upd_hop], sizes.reps, sizes.warmup)

    common = {"env": "hopper", "backend": envs.get_spec("hopper").default_backend, "obs_size": obs,
              "action_size": act, "hidden": sizes.hidden, "batch_size": sizes.batch_size, "sampling": "symmetric",
              "episode_length": cfg_single.horizon, "eval_episodes": 1, "replay_capacity": cfg_single.capacity}
    s_per_step = single.median / single.units
    s_per_update = upd_hop.median / upd_hop.units
    return {
        "3_grid_scaling": {
            **common,
            "single": {**single.record(), "chunk_steps": cfg_single.eval_every, "updates_per_s": single.rate,
                       "device": str(devices[0])},
            "grid_1_device": {**grid1.record(), "grid_size": sizes.grid_size, "chunk_steps": cfg_grid.eval_every,
                              "updates_per_s_total": grid1.rate, "devices": [str(devices[0])]},
            "grid_sharded": {**grid_all.record(), "grid_size": sizes.grid_size, "chunk_steps": cfg_grid.eval_every,
                             "updates_per_s_total": grid_all.rate, "devices": [str(d) for d in devices]},
            "grid_vmap_1dev_vs_single_ratio": grid1.rate / single.rate,
            "grid_vmap_sharded_vs_single_ratio": grid_all.rate / single.rate,
        },
        "4_online_step_vs_update": {
            **common,
            "seconds_per_env_step_single_run": s_per_step,
            "update_alone": {**upd_hop.record(), **upd_hop_info, "updates_per_s": upd_hop.rate},
            "seconds_per_update_alone": s_per_update,
            "online_step_vs_update_time_ratio": s_per_step / s_per_update,
        },
    }


# ----------------------------------------------------------------------------------------------------------------
# Verdicts and the summary


def verdict(name: str, value: float | None) -> str:
    """PASS / FAIL of goal ``name`` for ``value``; n/a when it could not be measured (None, NaN or inf)."""
    if value is None or not math.isfinite(value):
        return "n/a"
    op, goal = GOALS[name]
    ok = value <= goal if op == "<=" else value >= goal
    return "PASS" if ok else "FAIL"


def goals_of(results: dict) -> dict:
    """Each goal's measured ratio, its comparison, its threshold and the verdict."""
    ratios = {k: results[RATIO_SOURCES[k]][k] for k in GOALS}
    return {k: {"value": v, "op": GOALS[k][0], "goal": GOALS[k][1], "verdict": verdict(k, v)}
            for k, v in ratios.items()}


def summary_rows(results: dict, goals: dict, sizes: Sizes) -> list[tuple[str, str, str, str]]:
    """The printed table's rows (measurement, value, goal, verdict) from the results of the four measurements."""
    r1, r2, r3, r4 = (results[k] for k in ("1_proto_vs_sac", "2_gflops", "3_grid_scaling", "4_online_step_vs_update"))
    flops, achieved, ratio2 = r2["flops_per_update_used"], r2["achieved_gflops"], r2["achieved_vs_matmul_gflops_ratio"]
    n_dev = len(r3["grid_sharded"]["devices"])
    return [
        ("1  PROTO-SAC updates/s (halfcheetah)", f"{r1['proto']['updates_per_s']:.1f}", "", ""),
        ("1  SAC updates/s (halfcheetah)", f"{r1['sac']['updates_per_s']:.1f}", "", ""),
        ("1  time PROTO / time SAC", f"{r1['proto_vs_sac_time_ratio']:.3f}", "<= 1.10",
         goals["proto_vs_sac_time_ratio"]["verdict"]),
        ("2  MFLOP per PROTO update (XLA)", f"{flops / 1e6:.1f}" if flops else "n/a", "", ""),
        ("2  achieved GFLOP/s (PROTO update)", f"{achieved:.1f}" if achieved else "n/a", "", ""),
        (f"2  matmul GFLOP/s ({sizes.matmul_n}^3 x {sizes.matmul_chain})", f"{r2['matmul']['gflops']:.1f}", "", ""),
        ("2  achieved / matmul", f"{ratio2:.3f}" if ratio2 is not None else "n/a", ">= 0.6",
         goals["achieved_vs_matmul_gflops_ratio"]["verdict"]),
        ("3a single run updates/s (hopper, full step)", f"{r3['single']['updates_per_s']:.1f}", "", ""),
        (f"3b grid {sizes.grid_size} vmapped 1 dev, total updates/s",
         f"{r3['grid_1_device']['updates_per_s_total']:.1f}", "", ""),
        (f"3c grid {sizes.grid_size} sharded {n_dev} dev, total updates/s",
         f"{r3['grid_sharded']['updates_per_s_total']:.1f}", "", ""),
        ("3b grid(1 dev) / single", f"{r3['grid_vmap_1dev_vs_single_ratio']:.3f}", ">= 1.2",
         goals["grid_vmap_1dev_vs_single_ratio"]["verdict"]),
        ("3c grid(sharded) / single", f"{r3['grid_vmap_sharded_vs_single_ratio']:.3f}", ">= 1.5",
         goals["grid_vmap_sharded_vs_single_ratio"]["verdict"]),
        ("4  update alone updates/s (hopper)", f"{r4['update_alone']['updates_per_s']:.1f}", "", ""),
        ("4  s/env step / s/update", f"{r4['online_step_vs_update_time_ratio']:.3f}", "<= 1.15",
         goals["online_step_vs_update_time_ratio"]["verdict"]),
    ]


def cpu_per_wall(results: dict) -> str:
    """Each program's median process CPU ÷ wall seconds per call (≈ the cores it keeps busy), for the summary."""
    records = (("PROTO", results["1_proto_vs_sac"]["proto"]), ("SAC", results["1_proto_vs_sac"]["sac"]),
               ("matmul", results["2_gflops"]["matmul"]), ("3a", results["3_grid_scaling"]["single"]),
               ("3b", results["3_grid_scaling"]["grid_1_device"]), ("3c", results["3_grid_scaling"]["grid_sharded"]),
               ("4", results["4_online_step_vs_update"]["update_alone"]))
    return ", ".join(f"{label} {statistics.median(r['process_cpu_per_wall']):.2f}" for label, r in records)
