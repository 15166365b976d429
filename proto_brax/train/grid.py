"""Grids of runs as one compiled program: flatten the product of hyper-parameter axes, vmap, shard over devices.

The grid axis is sharded with ``jax.sharding`` over every device JAX sees, so the same code runs on one CPU, on host
"devices" (``jax_num_cpu_devices``: on a 2-core CPU two single-threaded shards beat one vmapped program, FACTS.md),
on a GPU or on many hosts after ``jax.distributed.initialize()``. The algorithm never knows it is batched.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from typing import Any, Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from proto_brax.config import HParams, validate_hparams
from proto_brax.train.evaluate import EpisodeStats


@dataclasses.dataclass(frozen=True)
class Grid:
    """A flattened grid: ``points[i]`` holds the hyper-parameter values and seed of run i."""

    hparams: HParams  # leaves of shape [size]
    seeds: np.ndarray  # [size] int
    points: tuple[dict[str, Any], ...]

    @property
    def size(self) -> int:
        return len(self.points)


def make_grid(axes: dict[str, Sequence[float]], seeds: Sequence[int], base: dict[str, float] | None = None,
              hparams: type[HParams] = HParams) -> Grid:
    """Cartesian product of ``axes`` (hyper-parameter name -> values) × ``seeds``; seeds vary fastest. The leaves
    are the fields of ``hparams``: the agent's class (``Finetune.hparams``; ``HParams`` for SAC and RLPD).

    Validated on the host before anything compiles: empty axes, duplicate values and out-of-range values raise.
    """
    base = dict(base or {})
    if len(seeds) == 0:
        raise ValueError("The grid is empty: give at least one seed.")
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"Duplicate seeds {list(seeds)}: each seed must appear once.")
    for name, values in axes.items():
        if len(values) == 0:
            raise ValueError(f"The grid is empty: axis {name!r} has no values.")
        if len(set(values)) != len(values):
            raise ValueError(f"Duplicate values in axis {name!r}: {list(values)}.")
    names = list(axes)
    points = []
    for combo in itertools.product(*(axes[n] for n in names), seeds):
        points.append({**base, **dict(zip(names, map(float, combo[:-1]))), "seed": int(combo[-1])})
    fields = hparams.names()
    unknown = (set(names) | set(base)) - set(fields)
    if unknown:
        raise ValueError(f"Unknown hyper-parameter(s) {sorted(unknown)} of {hparams.__name__}: valid names are "
                         f"{sorted(fields)}.")
    defaults = hparams.create()
    leaves = {
        f: np.asarray([p.get(f, float(getattr(defaults, f))) for p in points], np.float32) for f in fields
    }
    hp = hparams(**leaves)
    validate_hparams(hp)
    return Grid(hparams=hp, seeds=np.asarray([p["seed"] for p in points]), points=tuple(points))


def grid_mesh(devices: Sequence[jax.Device] | None = None) -> Mesh:
    devices = list(devices if devices is not None else jax.devices())
    return Mesh(np.asarray(devices), ("grid",))


def padded_size(size: int, mesh: Mesh) -> int:
    """The grid is padded (repeating its last run) to a multiple of the device count; padding is dropped after."""
    n = mesh.devices.size
    return int(math.ceil(size / n) * n)


def pad_leading(tree, size: int):
    def pad(x):
        x = jnp.asarray(x)
        extra = size - x.shape[0]
        return x if extra == 0 else jnp.concatenate([x, jnp.repeat(x[-1:], extra, axis=0)])

    return jax.tree.map(pad, tree)


def shard(tree, mesh: Mesh):
    """Place a grid-batched pytree with its leading axis split across the mesh."""
    return jax.device_put(tree, NamedSharding(mesh, P("grid")))


def replicate(tree, mesh: Mesh):
    """Place a shared pytree (dataset, pretrained bundle) whole on every device."""
    return jax.device_put(tree, NamedSharding(mesh, P()))


def seed_keys(seeds: np.ndarray) -> jax.Array:
    return jax.vmap(jax.random.PRNGKey)(jnp.asarray(seeds, jnp.uint32))


def host_gather(tree):
    """Bring a grid-sharded pytree to the host; across processes (``jax.distributed``) every process gets all of it."""
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        return multihost_utils.process_allgather(tree, tiled=True)
    return jax.device_get(tree)


def use_host_devices(n: int | None = None, spare_worker: bool = False) -> int:
    """Expose ``n`` (default: one per core) CPU devices so a grid can be sharded across cores, and size XLA's CPU
    pool beside them (``cpu_pool_threads``; ``spare_worker`` where the program runs batched LAPACK kernels: MJX).

    Must run before JAX initializes its backends (an entry point calls it first); a no-op with a warning-free return
    of the current count when the backend already exists or when a GPU/TPU is present.
    """
    import os

    n = n or os.cpu_count() or 1
    try:
        jax.config.update("jax_num_cpu_devices", n)
    except RuntimeError:  # backends already initialized: keep what exists
        pass
    else:
        size_cpu_pool(n, spare_worker)  # read when the backend starts, just below
    return len(jax.devices())


def size_cpu_pool(devices: int, spare_worker: bool = False) -> None:
    """Set ``$NPROC`` to ``cpu_pool_threads(devices, spare_worker)`` unless the user set it (or leave XLA's default);
    before JAX starts its backend."""
    import os

    threads = cpu_pool_threads(devices, spare_worker)
    if threads is not None:
        os.environ.setdefault("NPROC", str(threads))


def cpu_pool_threads(devices: int, spare_worker: bool = False) -> int | None:
    """Threads for XLA's CPU intra-op pool beside ``devices`` host devices: ``$NPROC``, which XLA's CPU client reads
    when its backend starts, taking the larger of it and the device count (None: leave XLA's default, the core count).

    jaxlib's batched LAPACK kernels (Cholesky, triangular solve: MJX factors every env's mass matrix, and with the
    Newton solver its constraint Hessian, this way) split a batch worth more than ~2·10⁵ flops into chunks scheduled
    on that pool whenever it has more than one thread, then block until the chunks are done. The device programs run
    on the pool's workers, so when every worker is such a blocked kernel nobody runs the chunks: a 5-seed pen sweep
    hung so, on one device and on two (docs/MEASUREMENTS.md#adroit). One device gets one thread, where jaxlib never
    splits. Several devices get one spare worker for the chunks with ``spare_worker`` (``tests/test_engine.py`` hangs
    without it); elsewhere XLA's default, as a spare worker measured ~10% fewer updates/s on Brax hopper (noisy).
    """
    if devices == 1:
        return 1
    return devices + 1 if spare_worker else None


@dataclasses.dataclass(frozen=True)
class GridProgram:
    """The compiled grid program of one ``Finetune``: vmapped init and chunk, the dataset and bundle shared."""

    init: Callable  # (hparams[G], keys[G], pretrained, dataset) -> state[G]
    chunk: Callable  # (state[G], hparams[G], dataset, start) -> (state[G], metrics[G])
    initial_eval: Callable  # state[G] -> EpisodeStats, each [G, eval_episodes], of π₀ (before any online step)


BLOCKS = ("vmap", "map")  # how a device runs its block of runs (``run_batched``; the sweep's --block)


def run_batched(fn: Callable, in_axes: tuple, block: str = "vmap") -> Callable:
    """``fn`` over a block of runs (the arguments with ``in_axes`` 0 carry a leading run axis).

    ``block="vmap"``: one batched program (the accelerator's way), except that a block of ONE run calls ``fn`` on it
    directly: XLA:CPU runs a batch-of-one vmap of the LayerNorm critics at about half speed, slower than a batch of
    two (measured 2026-12-06, hopper, SAC from scratch, one run on one device: 92 updates/s with LayerNorm vmapped,
    135 unbatched; 178 and 200 without LayerNorm).
    ``block="map"``: ``lax.map``, the runs one after another through the unbatched program, still inside the one
    jitted chunk. On one CPU thread this is as fast per update as a single run, where a 5-run vmap is slower
    (``benchmarks/run_block.py``, docs/MEASUREMENTS.md#run-block), and every run's numbers are its single run's bit
    for bit."""
    if block not in BLOCKS:
        raise ValueError(f"block {block!r}: choose one of {BLOCKS}.")
    vmapped = jax.vmap(fn, in_axes=in_axes)

    def split(args):
        return [a for a, ax in zip(args, in_axes) if ax == 0], [a for a, ax in zip(args, in_axes) if ax != 0]

    def join(batched, shared):
        b, s = iter(batched), iter(shared)
        return [next(b) if ax == 0 else next(s) for ax in in_axes]

    def run_block(*args):
        sizes = {leaf.shape[0] for a, ax in zip(args, in_axes) if ax == 0 for leaf in jax.tree.leaves(a)}
        if sizes != {1}:
            if block == "map":
                batched, shared = split(args)
                return jax.lax.map(lambda xs: fn(*join(xs, shared)), batched)
            return vmapped(*args)
        one = [jax.tree.map(lambda x: x[0], a) if ax == 0 else a for a, ax in zip(args, in_axes)]
        return jax.tree.map(lambda x: jnp.expand_dims(x, 0), fn(*one))

    return run_block


def on_mesh(fn: Callable, in_axes: tuple, mesh: Mesh, block: str = "vmap") -> Callable:
    """``run_batched(fn)`` on each device's block of runs (``shard_map``): grid-batched arguments split over the mesh,
    the others whole on every device; every output is per run. (Outputs that depend on shared inputs only, such as a
    chunk's step count, are the same on every device: ``check_vma`` is off so they may be laid out per run.)"""
    specs = tuple(P("grid") if ax == 0 else P() for ax in in_axes)
    return jax.shard_map(run_batched(fn, in_axes, block), mesh=mesh, in_specs=specs, out_specs=P("grid"),
                         check_vma=False)


def compile_grid(ft, mesh: Mesh, per_run_pretrained: bool = False, block: str = "vmap") -> GridProgram:
    """jit of init and chunk over each device's block of runs (``on_mesh``) with explicit shardings: grid-batched
    values split over ``mesh``, the dataset, the pretrained bundle (unless it holds one entry per run) and the chunk's
    start step replicated. Fixing the output shardings keeps every chunk call on the first compilation (an inferred
    sharding that differed between init's and chunk's outputs would recompile).
    """
    g, r = NamedSharding(mesh, P("grid")), NamedSharding(mesh, P())
    pre_axis, pre_sharding = (0, g) if per_run_pretrained else (None, r)
    init = jax.jit(on_mesh(ft.init, (0, 0, pre_axis, None), mesh, block), in_shardings=(g, g, pre_sharding, r),
                   out_shardings=g)
    # The state (with its replay buffers) is donated: each chunk updates it in place instead of copying it.
    chunk = jax.jit(on_mesh(ft.chunk, (0, 0, None, None), mesh, block), in_shardings=(g, g, r, r),
                    out_shardings=(g, g), donate_argnums=(0,))
    # π₀'s evaluation at step 0 (the reference for the "initial drop"), with a key that the run itself never uses.
    initial_eval = jax.jit(on_mesh(lambda s: ft.evaluate(s.learner, jax.random.fold_in(s.key, 0x5EED)), (0,), mesh,
                                          block), in_shardings=(g,), out_shardings=g)
    return GridProgram(init=init, chunk=chunk, initial_eval=initial_eval)


def run_grid(
    ft, grid: Grid, pretrained=None, dataset=None, mesh: Mesh | None = None,
    program: GridProgram | None = None, callback: Callable[[int, dict, Any], None] | None = None,
    restore: Callable[[Any], tuple[Any, int]] | None = None, per_run_pretrained: bool = False,
    on_start: Callable[[EpisodeStats], None] | None = None, block: str = "vmap",
):
    """Run every point of ``grid`` to the end in one compiled program, sharded over ``mesh``.

    Returns (final state, metrics with leaves [chunks run, grid.size, ...]) with the padding runs removed.
    ``pretrained`` is shared by every run, or (``per_run_pretrained``) has a leading axis of grid.size entries.
    ``callback(chunk_index, metrics, state)`` sees each chunk's host metrics and the (padded, sharded) state, e.g. to
    log and checkpoint; ``restore(initial_state) -> (state, chunks_done)`` resumes an interrupted run;
    ``on_start(stats)`` receives π₀'s step-0 evaluation (``EpisodeStats`` of host arrays [grid.size, eval_episodes];
    not called on a resume). ``block``: how each device runs its runs (``run_batched``), when ``program`` is None.
    """
    mesh = mesh or grid_mesh()
    program = program or compile_grid(ft, mesh, per_run_pretrained, block)
    size = padded_size(grid.size, mesh)
    hp = shard(pad_leading(grid.hparams, size), mesh)
    keys = shard(pad_leading(seed_keys(grid.seeds), size), mesh)
    if per_run_pretrained:
        pretrained = shard(pad_leading(pretrained, size), mesh)
    else:
        pretrained = replicate(pretrained, mesh)
    shared = (pretrained, replicate(dataset, mesh))
    state = program.init(hp, keys, *shared)
    start = 0
    if restore is not None:
        state, start = restore(state)
    if on_start is not None and start == 0:
        stats = host_gather(program.initial_eval(state))
        on_start(EpisodeStats(*(np.asarray(x)[: grid.size] for x in stats)))
    history = []
    for c in range(start, ft.cfg.num_chunks):
        start_step = replicate(jnp.asarray(c * ft.cfg.eval_every, jnp.int32), mesh)
        state, m = program.chunk(state, hp, shared[1], start_step)
        m = jax.tree.map(lambda x: np.asarray(x)[: grid.size], host_gather(m))
        if callback is not None:
            callback(c, m, state)
        history.append(m)
    state = jax.tree.map(lambda x: x[: grid.size], state)
    return state, (jax.tree.map(lambda *xs: np.stack(xs), *history) if history else {})
