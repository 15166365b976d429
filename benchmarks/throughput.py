"""Throughput benchmark of the PROTO engine on this machine: what one update costs and how a grid of runs scales.

Run (from the repository root, venv active)::

    python benchmarks/throughput.py                       # paper sizes; ~10-15 min on the 2-core CPU; quiet machine!
    python benchmarks/throughput.py --quick --out /tmp/tp.json   # tiny sizes, end-to-end check in a few minutes

Everything runs in ONE process with two host CPU devices (``use_host_devices(2)``, before any backend exists):

1. PROTO-SAC vs plain SAC update cost (halfcheetah sizes 17/6, MLP 2x256, batch 256): a jitted ``lax.scan`` of N
   (symmetric replay sample + ``sac.update``) with ``regularizer=True`` vs ``False``.
   Goal: time(PROTO) / time(SAC) <= 1.10.
2. Achieved GFLOP/s of one PROTO-SAC update (FLOPs from XLA's cost analysis / measured seconds per update) vs the
   GFLOP/s of a chain of large f32 matmuls measured in the same process. Goal: achieved / matmul >= 0.6 (0.8 long-term).
3. Grid scaling of the full online step on hopper (11/3): total updates/s of (a) one run alone (jit of the single-run
   chunk on one device), (b) a G-run grid vmapped on one device, (c) the same grid vmapped and sharded over both host
   devices. Goal: (b) / (a) >= 1.2 and (c) / (a) >= 1.5.
4. Full online step vs update alone on hopper: seconds per env step of (a) / seconds per update of the update-alone
   scan at hopper sizes (same networks, batch, sampling). Goal <= 1.15.

Timing: each program is compiled ahead of time (``lower().compile()``, compile seconds recorded), run ``warmup`` times,
then the programs of a measurement are timed *interleaved* (A B C A B C ...) ``reps`` times and the median taken, so
slow drift of a shared machine hits every side of a ratio alike. Every call ends with ``jax.block_until_ready``.
The evaluation at the end of a chunk is made negligible with ``episode_length`` = 10 and ``eval_episodes`` = 1 (the
time limit only changes when the env resets; ``env_step`` computes the reset state every step anyway).

Writes JSON atomically (temp file + ``os.replace``) with raw timings, ratios, goals, pass/fail and the environment.
"""

from __future__ import annotations

import dataclasses
import datetime
import inspect
import math
import os
import platform
import statistics
import sys
import time
from typing import Any

import _quiet  # noqa: F401  (first: the quiet start)
import jax
import jax.numpy as jnp
import numpy as np
import tyro
from jax import lax

from proto_brax import envs
from proto_brax.agents.learner import init_learner
from proto_brax.agents.registry import agent
from proto_brax.analysis.timing import Case, aot, flops_of, log, run_interleaved, synthetic_transitions, versions
from proto_brax.config import FinetuneConfig, HParams
from proto_brax.data.dataset import Transition
from proto_brax.data.replay import replay_init, replay_insert, replay_sample
from proto_brax.files import strict_json, write_json_atomic
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
    use_host_devices,
)
from proto_brax.train.online import make_finetune

GOALS = {  # issue 37's goals (the FLOP/s ratio's long-term goal is 0.8; the sharded 8-run grid is the sweep's program)
    "proto_vs_sac_time_ratio": ("<=", 1.10),
    "achieved_vs_matmul_gflops_ratio": (">=", 0.6),
    "grid_vmap_1dev_vs_single_ratio": (">=", 1.2),
    "grid_vmap_sharded_vs_single_ratio": (">=", 1.5),
    "online_step_vs_update_time_ratio": ("<=", 1.15),
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


@dataclasses.dataclass
class Args:
    """PROTO throughput benchmark (see the module docstring)."""

    quick: bool = False  # tiny sizes: checks the script end to end in a few minutes; timings are meaningless
    out: str = "benchmarks/results/throughput.json"  # JSON report (written atomically)
    reps: int | None = None  # timed repetitions per program (default: 3, quick: 2)
    host_devices: int = 2  # jax_num_cpu_devices (the grid of 3c is sharded over all of them)


# ----------------------------------------------------------------------------------------------------------------
# Update-alone programs (sample + update, as in the online loop but without the env)


def make_update_fns(cfg: FinetuneConfig, nets, n_updates: int):
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
    env = envs.make_env(cfg.env, cfg.backend)
    obs, act = env.observation_size, env.action_size
    nets = make_networks(cfg.net, act, deterministic=agent(cfg.algo).deterministic)
    hp = HParams.create()
    k_l, k_d, k_b = jax.random.split(key, 3)
    learner = init_learner(k_l, nets, agent(cfg.algo), hp, obs, act, None)
    dataset = synthetic_transitions(k_d, sizes.dataset_rows, obs, act)
    buffer = replay_insert(replay_init(2 * sizes.buffer_rows, obs, act),
                           synthetic_transitions(k_b, sizes.buffer_rows, obs, act))
    return nets, hp, learner, dataset, buffer, (obs, act)


def update_scan_case(name: str, cfg: FinetuneConfig, sizes: Sizes, key: jax.Array, with_flops: bool = False):
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
    return FinetuneConfig(
        env="hopper", net=NetworkConfig(hidden=sizes.hidden), batch_size=sizes.batch_size,
        steps=sizes.run_steps, eval_every=chunk_steps, eval_episodes=1, learning_starts=1, sampling="symmetric",
        episode_length=10, regularizer=True,
    )


def single_run_case(cfg: FinetuneConfig, dataset: Transition) -> Case:
    ft = make_finetune(cfg)
    hp = HParams.create()
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
    ft = make_finetune(cfg)
    mesh = grid_mesh(devices)
    grid = make_grid({}, seeds=list(range(grid_size)))
    size = padded_size(grid.size, mesh)
    # compile_grid(ft, mesh) fixes in/out shardings on the mesh; older versions took only ft.
    takes_mesh = "mesh" in inspect.signature(compile_grid).parameters
    program = compile_grid(ft, mesh) if takes_mesh else compile_grid(ft)
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


def verdict(name: str, value: float | None) -> str:
    if value is None or not math.isfinite(value):
        return "n/a"
    op, goal = GOALS[name]
    ok = value <= goal if op == "<=" else value >= goal
    return "PASS" if ok else "FAIL"


def main(args: Args) -> dict:
    # Before anything initializes a JAX backend: two host CPU devices for the sharded grid (3c).
    n_dev = use_host_devices(args.host_devices)
    sizes = QUICK if args.quick else FULL
    if args.reps is not None:
        sizes = dataclasses.replace(sizes, reps=args.reps)
    t_start = time.perf_counter()
    env_info = {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "command": " ".join([os.path.basename(sys.executable)] + sys.argv),
        "mode": "quick" if args.quick else "full",
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
    log(f"mode {env_info['mode']}, devices {env_info['devices']}, loadavg {env_info['loadavg_start']}")
    if n_dev < args.host_devices and jax.default_backend() == "cpu":
        log(f"WARNING: only {n_dev} device(s); a backend was initialized before use_host_devices()")
    results: dict[str, Any] = {}
    net = NetworkConfig(hidden=sizes.hidden)

    # 1 + 2: PROTO-SAC vs SAC update cost (halfcheetah sizes), achieved GFLOP/s vs matmul --------------------------
    log("== 1/2: PROTO-SAC vs SAC update (halfcheetah sizes) and GFLOP/s vs matmul")
    cfg_proto = FinetuneConfig(env="halfcheetah", net=net, batch_size=sizes.batch_size, sampling="symmetric",
                               regularizer=True)
    cfg_sac = dataclasses.replace(cfg_proto, regularizer=False)
    key = jax.random.PRNGKey(0)
    proto, proto_info = update_scan_case("1 PROTO-SAC update", cfg_proto, sizes, key, with_flops=True)
    plain, plain_info = update_scan_case("1 SAC update", cfg_sac, sizes, key, with_flops=True)
    mm, mm_xla_flops = matmul_case(sizes.matmul_n, sizes.matmul_chain)
    run_interleaved([proto, plain, mm], sizes.reps, sizes.warmup)

    ratio1 = proto.median / plain.median
    results["1_proto_vs_sac"] = {
        "env_sizes": "halfcheetah", "hidden": sizes.hidden, "batch_size": sizes.batch_size, "sampling": "symmetric",
        "proto": {**proto.record(), **proto_info, "updates_per_s": proto.rate},
        "sac": {**plain.record(), **plain_info, "updates_per_s": plain.rate},
        "proto_vs_sac_time_ratio": ratio1,
    }
    f_single = proto_info["flops_single_update_program"]
    f_scan = proto_info["flops_scan_program"]
    f_scan_per = f_scan / sizes.n_updates if f_scan is not None else None
    # Primary: the single-update program (cost analysis may count a while-loop body once, not trip-count times).
    flops_per_update = f_single if f_single is not None else f_scan_per
    achieved = flops_per_update / (proto.median / sizes.n_updates) / 1e9 if flops_per_update else None
    mm_gflops = mm.rate / 1e9
    ratio2 = achieved / mm_gflops if achieved is not None else None
    results["2_gflops"] = {
        "flops_per_update_single_program": f_single,
        "flops_scan_program": f_scan,
        "flops_scan_program_div_n": f_scan_per,
        "scan_vs_single_flops_ratio": (f_scan_per / f_single) if (f_scan_per and f_single) else None,
        "sac_flops_per_update_single_program": plain_info["flops_single_update_program"],
        "proto_vs_sac_flops_ratio": (f_single / plain_info["flops_single_update_program"])
        if (f_single and plain_info["flops_single_update_program"]) else None,
        "flops_per_update_used": flops_per_update,
        "flops_source": "single-update program" if f_single is not None else "scan program / N",
        "scan_counted_once": bool(f_scan and f_single and f_scan < 2 * f_single),  # loop body counted once
        "achieved_gflops": achieved,
        "matmul": {**mm.record(), "n": sizes.matmul_n, "chain": sizes.matmul_chain, "gflops": mm_gflops,
                   "xla_cost_analysis_flops": mm_xla_flops, "analytic_flops": mm.units},
        "achieved_vs_matmul_gflops_ratio": ratio2,
    }

    # 3 + 4: grid scaling and online step vs update alone (hopper) ------------------------------------------------
    log("== 3/4: online chunk on hopper: single run, grid vmapped on 1 device, grid sharded; update alone")
    cfg_single = online_cfg(sizes, sizes.chunk_steps)
    cfg_grid = online_cfg(sizes, sizes.grid_chunk_steps)
    obs, act = envs.make_env("hopper").observation_size, envs.make_env("hopper").action_size
    dataset = synthetic_transitions(jax.random.PRNGKey(5), sizes.dataset_rows, obs, act)
    devices = jax.devices()
    single = single_run_case(cfg_single, dataset)
    grid1 = grid_case(f"3b grid of {sizes.grid_size} vmapped, 1 device", cfg_grid, dataset, sizes.grid_size,
                      devices[:1])
    grid_all = grid_case(f"3c grid of {sizes.grid_size} vmapped, sharded over {len(devices)} devices", cfg_grid,
                         dataset, sizes.grid_size, devices)
    upd_hop, upd_hop_info = update_scan_case("4 update alone (hopper sizes)", cfg_single, sizes, jax.random.PRNGKey(6))
    run_interleaved([single, grid1, grid_all, upd_hop], sizes.reps, sizes.warmup)

    ratio3b = grid1.rate / single.rate
    ratio3c = grid_all.rate / single.rate
    common = {"env": "hopper", "backend": envs.get_spec("hopper").default_backend, "obs_size": obs,
              "action_size": act, "hidden": sizes.hidden, "batch_size": sizes.batch_size, "sampling": "symmetric",
              "episode_length": cfg_single.horizon, "eval_episodes": 1, "replay_capacity": cfg_single.capacity}
    results["3_grid_scaling"] = {
        **common,
        "single": {**single.record(), "chunk_steps": cfg_single.eval_every, "updates_per_s": single.rate,
                   "device": str(devices[0])},
        "grid_1_device": {**grid1.record(), "grid_size": sizes.grid_size, "chunk_steps": cfg_grid.eval_every,
                          "updates_per_s_total": grid1.rate, "devices": [str(devices[0])]},
        "grid_sharded": {**grid_all.record(), "grid_size": sizes.grid_size, "chunk_steps": cfg_grid.eval_every,
                         "updates_per_s_total": grid_all.rate, "devices": [str(d) for d in devices]},
        "grid_vmap_1dev_vs_single_ratio": ratio3b,
        "grid_vmap_sharded_vs_single_ratio": ratio3c,
    }
    s_per_step = single.median / single.units
    s_per_update = upd_hop.median / upd_hop.units
    ratio4 = s_per_step / s_per_update
    results["4_online_step_vs_update"] = {
        **common,
        "seconds_per_env_step_single_run": s_per_step,
        "update_alone": {**upd_hop.record(), **upd_hop_info, "updates_per_s": upd_hop.rate},
        "seconds_per_update_alone": s_per_update,
        "online_step_vs_update_time_ratio": ratio4,
    }

    ratios = {
        "proto_vs_sac_time_ratio": ratio1,
        "achieved_vs_matmul_gflops_ratio": ratio2,
        "grid_vmap_1dev_vs_single_ratio": ratio3b,
        "grid_vmap_sharded_vs_single_ratio": ratio3c,
        "online_step_vs_update_time_ratio": ratio4,
    }
    goals = {k: {"value": v, "op": GOALS[k][0], "goal": GOALS[k][1], "verdict": verdict(k, v)}
             for k, v in ratios.items()}

    rows = [
        ("1  PROTO-SAC updates/s (halfcheetah)", f"{proto.rate:.1f}", "", ""),
        ("1  SAC updates/s (halfcheetah)", f"{plain.rate:.1f}", "", ""),
        ("1  time PROTO / time SAC", f"{ratio1:.3f}", "<= 1.10", goals["proto_vs_sac_time_ratio"]["verdict"]),
        ("2  MFLOP per PROTO update (XLA)", f"{flops_per_update / 1e6:.1f}" if flops_per_update else "n/a", "", ""),
        ("2  achieved GFLOP/s (PROTO update)", f"{achieved:.1f}" if achieved else "n/a", "", ""),
        (f"2  matmul GFLOP/s ({sizes.matmul_n}^3 x {sizes.matmul_chain})", f"{mm_gflops:.1f}", "", ""),
        ("2  achieved / matmul", f"{ratio2:.3f}" if ratio2 is not None else "n/a", ">= 0.6",
         goals["achieved_vs_matmul_gflops_ratio"]["verdict"]),
        ("3a single run updates/s (hopper, full step)", f"{single.rate:.1f}", "", ""),
        (f"3b grid {sizes.grid_size} vmapped 1 dev, total updates/s", f"{grid1.rate:.1f}", "", ""),
        (f"3c grid {sizes.grid_size} sharded {len(devices)} dev, total updates/s", f"{grid_all.rate:.1f}", "", ""),
        ("3b grid(1 dev) / single", f"{ratio3b:.3f}", ">= 1.2", goals["grid_vmap_1dev_vs_single_ratio"]["verdict"]),
        ("3c grid(sharded) / single", f"{ratio3c:.3f}", ">= 1.5",
         goals["grid_vmap_sharded_vs_single_ratio"]["verdict"]),
        ("4  update alone updates/s (hopper)", f"{upd_hop.rate:.1f}", "", ""),
        ("4  s/env step / s/update", f"{ratio4:.3f}", "<= 1.15", goals["online_step_vs_update_time_ratio"]["verdict"]),
    ]
    env_info["loadavg_end"] = list(os.getloadavg())
    env_info["total_wall_s"] = time.perf_counter() - t_start
    payload = {"environment": env_info, "goals": goals, "results": results}
    write_json_atomic(args.out, strict_json(payload))  # NaN -> null: strict JSON

    w = max(len(r[0]) for r in rows)
    print()
    print(f"{'measurement':<{w}}  {'value':>10}  {'goal':>8}  result")
    print("-" * (w + 32))
    for name, value, goal, res in rows:
        print(f"{name:<{w}}  {value:>10}  {goal:>8}  {res}")
    print("-" * (w + 32))
    print(f"mode {env_info['mode']}; {env_info['total_wall_s']:.0f} s; loadavg start {env_info['loadavg_start']} "
          f"end {env_info['loadavg_end']}; wrote {args.out}")
    print("process cpu/wall (median; ~1 = one core busy, ~2 = both): "
          + ", ".join(f"{label} {statistics.median(c.cpu_util):.2f}" for label, c in (
              ("PROTO", proto), ("SAC", plain), ("matmul", mm), ("3a", single), ("3b", grid1), ("3c", grid_all),
              ("4", upd_hop))))
    if results["2_gflops"]["scan_counted_once"]:
        print("note: XLA's cost analysis counts the scan's loop body once (not N times); FLOPs/update come from a "
              "separately compiled single-update program.")
    if args.quick:
        print("(--quick: tiny networks and few steps; the verdicts are not meaningful)")
    return payload


if __name__ == "__main__":
    main(tyro.cli(Args))
