"""Atomic file writes: the one implementation behind the suite's datasets, JSON results, plots and indexes.

A reader (or a sweep resuming after a crash) sees either the previous complete file or the new complete file, never
a half-written one: the data go to a temporary file in the target's directory (same filesystem, so the final
``os.replace`` is atomic), which is flushed and fsynced first; if anything fails on the way the temporary file is
removed and the target is left as it was.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "w") -> Iterator[IO]:
    """``with atomic_write(path, "wb") as f: ...`` — ``f`` is a temporary file that replaces ``path`` on success.

    The parent directory is created if needed; the file gets the mode a plain ``open()`` would give it (mkstemp's
    0600 would hide results from other users of a shared machine)."""
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_write writes a whole file: mode 'w' or 'wb', not {mode!r}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, mode) as f:
            os.chmod(tmp, 0o666 & ~_umask())
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


LOCK_NAME = ".lock"
_LOCKS: dict[str, IO] = {}  # directory -> the open lock file this process holds (the lock lives with the open file)


class DirectoryBusy(FileExistsError):
    """Another live process holds the directory's lock (``lock_dir``)."""


def lock_dir(directory: str | os.PathLike, choose: str) -> None:
    """Make this process the one writer of ``directory`` for the rest of its life: an exclusive ``flock`` on
    ``directory/.lock``. The kernel drops it when the process ends, even on SIGKILL, so a killed run leaves no stale
    lock and its resume takes the directory over. A second process stops with a one-line error naming the first (its
    pid and host) and ``choose`` (what to pick instead), rather than interleaving its chunks with the first one's.
    Taking a lock this process already holds does nothing. (An flock is per host: two hosts sharing a network
    filesystem may not see each other's.)"""
    import fcntl
    import socket

    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    key = str(d.resolve())
    if key in _LOCKS and Path(_LOCKS[key].name).exists():
        return
    f = open(d / LOCK_NAME, "a+")
    try:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        f.seek(0)
        holder = f.read().strip() or "another process"
        f.close()
        raise DirectoryBusy(f"{d} is being written by {holder}: wait for it to end, or {choose}.") from None
    f.seek(0)
    f.truncate()
    f.write(f"pid {os.getpid()} on {socket.gethostname()}")
    f.flush()
    if key in _LOCKS:  # (the directory was replaced under an old lock of ours: that file is gone)
        _LOCKS.pop(key).close()
    _LOCKS[key] = f


def release_dir(directory: str | os.PathLike) -> None:
    """Drop this process's lock on ``directory`` (``lock_dir``), if it holds one: at the end of the work."""
    f = _LOCKS.pop(str(Path(directory).resolve()), None)
    if f is not None:
        f.close()


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    with atomic_write(path) as f:
        f.write(text)


def copy_atomic(src: str | os.PathLike, dst: str | os.PathLike) -> None:
    """Copy a file's bytes onto ``dst`` atomically (``shutil.copy2`` writes in place)."""
    import shutil

    with open(src, "rb") as s, atomic_write(dst, "wb") as d:
        shutil.copyfileobj(s, d)


def append_once(path: str | os.PathLike, text: str) -> None:
    """Append ``text`` with a single ``write`` system call on an ``O_APPEND`` descriptor.

    A kill (even SIGKILL) cannot land inside one ``write`` to a local file, so one call's bytes are appended whole
    or not at all; a reader must still tolerate a torn last line after a power loss (``read_jsonl``)."""
    data = text.encode()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
    try:
        written = os.write(fd, data)
        while written < len(data):  # a short write (disk full, signals on some filesystems): finish it
            written += os.write(fd, data[written:])
    finally:
        os.close(fd)


def strict_json(x):
    """NaN/inf -> None, numpy -> Python, recursively: what strict JSON parsers (``JSON.parse``) accept."""
    import math

    import numpy as np

    if isinstance(x, dict):
        return {k: strict_json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [strict_json(v) for v in x]
    if isinstance(x, np.ndarray):
        return strict_json(x.tolist())
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def nan_for_null(x):
    """The reader's side of :func:`strict_json` for numeric records (metrics rows, summary statistics): None -> NaN,
    recursively."""
    if isinstance(x, dict):
        return {k: nan_for_null(v) for k, v in x.items()}
    if isinstance(x, list):
        return [nan_for_null(v) for v in x]
    return float("nan") if x is None else x


def read_jsonl(path: str | os.PathLike, drop_torn_tail: bool = True) -> tuple[list[dict], int]:
    """Rows of a JSON-lines file of numeric records (null read as NaN), and the number of torn lines dropped.

    Only the last line may be torn (cut by a crash in the middle of an append: it has no final newline or does not
    parse); with ``drop_torn_tail`` it is dropped, any other unparsable line raises ValueError naming the line."""
    import json

    text = Path(path).read_text()
    lines = text.split("\n")  # a complete file ends with "\n": its last element is ""
    rows, torn = [], 0
    for n, line in enumerate(lines, 1):
        if not line.strip():
            continue
        last = n == len(lines) or (n == len(lines) - 1 and not lines[-1])
        try:
            row = json.loads(line)
            if not isinstance(row, dict):
                raise ValueError("not a JSON object")
        except ValueError as e:
            if drop_torn_tail and n == len(lines):  # no newline after it: a torn append
                torn += 1
                continue
            where = "its last line" if last else f"line {n}"
            raise ValueError(f"{path}: {where} is not a JSON row ({e}).") from None
        rows.append(nan_for_null(row))
    return rows, torn


def write_json_atomic(path: str | os.PathLike, obj: Any) -> None:
    with atomic_write(path) as f:
        json.dump(obj, f, indent=2, sort_keys=True, default=_json_default)
        f.write("\n")


def _json_default(x):
    if isinstance(x, (np.generic, np.ndarray)):
        return x.tolist()
    raise TypeError(f"not JSON serializable: {type(x)}")
