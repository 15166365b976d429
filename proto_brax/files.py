"""Atomic file writes: the one implementation behind the suite's datasets, JSON results, plots and indexes.

A reader (or a sweep resuming after a crash) sees either the previous complete file or the new complete file, never
a half-written one: the data go to a temporary file in the target's directory (same filesystem, so the final
``os.replace`` is atomic), which is flushed and fsynced first; if anything fails on the way the temporary file is
removed and the target is left as it was.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO


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


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    with atomic_write(path) as f:
        f.write(text)


def copy_atomic(src: str | os.PathLike, dst: str | os.PathLike) -> None:
    """Copy a file's bytes onto ``dst`` atomically (``shutil.copy2`` writes in place)."""
    import shutil

    with open(src, "rb") as s, atomic_write(dst, "wb") as d:
        shutil.copyfileobj(s, d)
