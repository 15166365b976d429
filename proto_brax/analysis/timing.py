"""Timing for the cost benchmarks (``benchmarks/throughput.py``, ``methods_cost.py``): programs compiled ahead of
time, timed interleaved (A B C A B C ...) so that a shared machine's drift hits every side of a ratio alike, with the
process's CPU ÷ wall per call (≈ the cores a program keeps busy), XLA's FLOP count, and the library versions."""

from __future__ import annotations

import dataclasses
import platform
import resource
import statistics
import time
from typing import Any, Callable

import jax
import jax.numpy as jnp

from proto_brax.data.dataset import Transition


def log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


def synthetic_transitions(key: jax.Array, n: int, obs: int, act: int) -> Transition:
    k = jax.random.split(key, 5)
    return Transition(
        observations=jax.random.normal(k[0], (n, obs)),
        actions=jax.random.uniform(k[1], (n, act), minval=-1.0, maxval=1.0),
        rewards=jax.random.normal(k[2], (n,)),
        next_observations=jax.random.normal(k[3], (n, obs)),
        terminals=(jax.random.uniform(k[4], (n,)) < 0.01).astype(jnp.float32),
        timeouts=jnp.zeros((n,)),
    )


def flops_of(compiled) -> float | None:
    """FLOPs from ``Compiled.cost_analysis()``, which is a dict in recent JAX and a list of dicts in older ones."""
    try:
        ca = compiled.cost_analysis()
    except Exception as e:  # noqa: BLE001 - some backends do not implement it
        log(f"cost_analysis() failed: {e!r}")
        return None
    if ca is None:
        return None
    if isinstance(ca, dict):
        ca = [ca]
    vals = [float(d["flops"]) for d in ca if isinstance(d, dict) and "flops" in d]
    return sum(vals) if vals else None


@dataclasses.dataclass
class Case:
    """One timed program: ``step(state) -> (state, aux)``; ``units`` updates (or FLOPs) of work per call."""

    name: str
    step: Callable[[Any], tuple[Any, Any]]
    state: Any
    units: float
    compile_s: float
    times: list[float] = dataclasses.field(default_factory=list)
    cpu_util: list[float] = dataclasses.field(default_factory=list)  # process CPU seconds / wall seconds per call

    @property
    def median(self) -> float:
        return statistics.median(self.times)

    @property
    def rate(self) -> float:
        return self.units / self.median

    def record(self) -> dict:
        return {"units_per_call": self.units, "compile_s": self.compile_s, "times_s": self.times,
                "median_s": self.median, "units_per_s": self.rate, "process_cpu_per_wall": self.cpu_util}


def _cpu_seconds() -> float:
    """User + system CPU seconds of this process (all threads): cpu/wall ~ number of cores a program keeps busy."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def run_interleaved(cases: list[Case], reps: int, warmup: int) -> None:
    """Warm every case up, then time them round-robin ``reps`` times (median taken later)."""
    for _ in range(warmup):
        for c in cases:
            t0 = time.perf_counter()
            c.state, aux = c.step(c.state)
            jax.block_until_ready((c.state, aux))
            log(f"  warm-up {c.name}: {time.perf_counter() - t0:.2f} s")
    for r in range(reps):
        for c in cases:
            cpu0 = _cpu_seconds()
            t0 = time.perf_counter()
            c.state, aux = c.step(c.state)
            jax.block_until_ready((c.state, aux))
            c.times.append(time.perf_counter() - t0)
            c.cpu_util.append((_cpu_seconds() - cpu0) / c.times[-1])
            log(f"  rep {r + 1}/{reps} {c.name}: {c.times[-1]:.3f} s ({c.units / c.times[-1]:.4g} /s, "
                f"cpu/wall {c.cpu_util[-1]:.2f})")


def aot(fn, *args, **jit_kwargs):
    """jit + lower + compile ahead of time; returns (compiled, seconds)."""
    t0 = time.perf_counter()
    compiled = jax.jit(fn, **jit_kwargs).lower(*args).compile()
    return compiled, time.perf_counter() - t0


def versions() -> dict:
    import importlib.metadata as md

    out = {"python": platform.python_version()}
    for pkg in ("jax", "jaxlib", "brax", "flax", "optax", "mujoco", "numpy"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            out[pkg] = None
    return out


def steady_rate(marks: list[tuple[int, float]]) -> float:
    """Env steps per second between the first and the last of ``marks`` ((env step, wall time) pairs)."""
    (s0, t0), (s1, t1) = marks[0], marks[-1]
    return (s1 - s0) / (t1 - t0)


def brax_sac_marks(env: str, periods: int, eval_every: int, eval_episodes: int) -> list[tuple[int, float]]:
    """Run Brax's own SAC trainer (``brax.training.agents.sac.train``: one env, batch 256, one update per env step,
    1000 prefill steps, 2×256 MLPs without LayerNorm, deterministic evaluation) for ``periods`` evaluation periods of
    ``eval_every`` env steps; returns the (env step, wall time) of each evaluation (the first is before training).
    ``benchmarks/peer_brax_sac.py`` runs it in a process of its own."""
    import functools

    if not hasattr(jax, "device_put_replicated"):  # removed in jax 0.10; brax 0.14's SAC still calls it
        def device_put_replicated(x, devices):
            if len(devices) != 1:
                raise NotImplementedError("the shim replicates over one device only")
            return jax.device_put(jax.tree.map(lambda a: jnp.expand_dims(a, 0), x), devices[0])

        jax.device_put_replicated = device_put_replicated
    from brax import envs as brax_envs
    from brax.training.agents.sac import networks as sac_networks
    from brax.training.agents.sac import train as sac

    from proto_brax.envs import get_spec

    spec = get_spec(env)
    marks: list[tuple[int, float]] = []
    sac.train(
        environment=brax_envs.get_environment(env, backend=spec.default_backend),
        num_timesteps=1000 + periods * eval_every,
        episode_length=spec.episode_length, num_envs=1, num_eval_envs=eval_episodes, learning_rate=3e-4,
        discounting=0.99, batch_size=256, num_evals=periods + 1, min_replay_size=1000,
        grad_updates_per_step=1, deterministic_eval=True, max_devices_per_host=1, seed=0,
        network_factory=functools.partial(sac_networks.make_sac_networks, hidden_layer_sizes=(256, 256)),
        progress_fn=lambda step, metrics: marks.append((int(step), time.time())))
    return marks
