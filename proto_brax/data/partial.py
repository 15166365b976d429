"""Resumable segmented builds: an interrupted ``python -m proto_brax.datasets make`` continues where it stopped.

A dataset build is a deterministic loop of jitted segments: segment ``i`` draws its keys from ``fold_in(key, i + 1)``
and threads the env state on. Saving each segment's transitions and the env state after it, and restarting the loop
at the next index from that state, therefore reproduces the uninterrupted build bit for bit (tested). AntMaze builds
take 40-70 minutes on a CPU core, so a stopped session or a killed process no longer throws that away.

On disk (a directory beside the dataset file): ``fingerprint.json`` (what is being built: a resume with another
fingerprint starts afresh), ``seg-NNNNNN.npz`` (one segment's transition leaves) and ``state.npz`` (the env state's
leaves and the next segment index), each written atomically, transitions before the state that counts them.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from proto_brax.files import atomic_write, write_text_atomic


def _save_leaves(path: Path, leaves, **extra) -> None:
    with atomic_write(path, "wb") as f:
        np.savez(f, **{f"leaf_{i}": np.asarray(x) for i, x in enumerate(leaves)}, **extra)


def _load_leaves(path: Path) -> tuple[list[np.ndarray], dict]:
    with np.load(path) as z:
        leaves = [z[f"leaf_{i}"] for i in range(sum(k.startswith("leaf_") for k in z.files))]
        extra = {k: z[k] for k in z.files if not k.startswith("leaf_")}
    return leaves, extra


def _canonical(fingerprint: dict | None) -> dict:
    """As it reads back from JSON (tuples become lists, numpy scalars strings), so that a comparison is fair."""
    return json.loads(json.dumps(fingerprint or {}, sort_keys=True, default=str))


def _resume(directory: Path, fingerprint: dict | None, state, count: int):
    """(next index, state, transition leaves per segment) from ``directory``, or None with the reason printed."""
    fp = directory / "fingerprint.json"
    if not fp.exists():
        return None
    try:
        if json.loads(fp.read_text()) != _canonical(fingerprint):
            print(f"{directory}: a partial build of something else (another size, seed, controller or XLA flags); "
                  "starting afresh", flush=True)
            return None
        if not (directory / "state.npz").exists():
            return None
        leaves, extra = _load_leaves(directory / "state.npz")
        start = int(extra["next"])
        template, treedef = jax.tree.flatten(state)
        if len(leaves) != len(template) or any(a.shape != np.shape(b) or a.dtype != np.asarray(b).dtype
                                               for a, b in zip(leaves, template)) or not 0 < start <= count:
            print(f"{directory}: its saved env state does not fit this build; starting afresh", flush=True)
            return None
        parts = [_load_leaves(directory / f"seg-{i:06d}.npz")[0] for i in range(start)]
    except (OSError, ValueError, KeyError, json.JSONDecodeError) as e:  # a truncated or corrupt file
        print(f"{directory}: unreadable partial build ({e}); starting afresh", flush=True)
        return None
    return start, jax.tree.unflatten(treedef, [jnp.asarray(x) for x in leaves]), parts


def run_segments(count: int, init: Callable[[], object], segment: Callable[[int, object], tuple[object, object]],
                 checkpoint: Path | None = None, fingerprint: dict | None = None,
                 tick: Callable[[], None] | None = None) -> object:
    """``segment(i, state) -> (transitions, state)`` for ``i < count`` from ``init()``; the transitions of all
    segments concatenated along their leading (time) axis, as numpy.

    With ``checkpoint`` (a directory), progress is saved after every segment and a later call with the same
    ``fingerprint`` (a JSON-able description of the build) resumes from it; call ``discard(checkpoint)`` once the
    result is safely written. ``tick()`` is called once per segment, resumed ones included (a progress bar).
    When every segment is resumed, ``segment`` is traced once (``jax.eval_shape``, nothing runs) for the
    transitions' structure, so it must be traceable in ``state``."""
    state, start, parts, treedef = init(), 0, [], None
    if checkpoint is not None:
        checkpoint = Path(checkpoint)
        resumed = _resume(checkpoint, fingerprint, state, count)
        if resumed is None:
            shutil.rmtree(checkpoint, ignore_errors=True)
            checkpoint.mkdir(parents=True)
            write_text_atomic(checkpoint / "fingerprint.json", json.dumps(_canonical(fingerprint)))
        else:
            start, state, parts = resumed
            print(f"{checkpoint}: resuming at segment {start} of {count}", flush=True)
    if tick:
        for _ in range(start):
            tick()
    for i in range(start, count):
        tr, state = segment(i, state)
        leaves, treedef = jax.tree.flatten(jax.device_get(tr))
        parts.append(leaves)
        if checkpoint is not None:
            _save_leaves(checkpoint / f"seg-{i:06d}.npz", leaves)
            _save_leaves(checkpoint / "state.npz", jax.tree.leaves(jax.device_get(state)), next=np.int64(i + 1))
        if tick:
            tick()
    if treedef is None:  # everything was resumed: the transitions' structure without running a segment
        treedef = jax.tree.structure(jax.eval_shape(lambda s: segment(count - 1, s), state)[0])
    return jax.tree.unflatten(treedef, [np.concatenate(xs) for xs in zip(*parts)])


def discard(checkpoint: Path | None) -> None:
    if checkpoint is not None:
        shutil.rmtree(checkpoint, ignore_errors=True)
