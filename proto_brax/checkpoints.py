"""Checkpoints with orbax: pytrees saved beside a metadata JSON (format version), written atomically.

A checkpoint directory holds ``state/`` (orbax ``StandardCheckpointer``: orbax writes into a temporary directory and
renames it on commit) and ``metadata.json`` (written to a temp file, then ``os.replace``). ``metadata.json`` is written
last, so a directory without it is an interrupted save and is never read.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

FORMAT_VERSION = 1


class CheckpointError(ValueError):
    """A missing, corrupt or mismatched checkpoint."""


def write_json_atomic(path: str | os.PathLike, obj: Any) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(obj, f, indent=2, sort_keys=True, default=_json_default)
            f.write("\n")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _json_default(x):
    if isinstance(x, (np.generic, np.ndarray)):
        return x.tolist()
    raise TypeError(f"not JSON serializable: {type(x)}")


def save(path: str | os.PathLike, tree: Any, metadata: dict[str, Any]) -> None:
    """Save ``tree`` and ``metadata`` to directory ``path`` (replacing an older checkpoint there)."""
    path = Path(path).absolute()
    if path.exists():
        shutil.rmtree(path)
    path.mkdir(parents=True)
    ckptr = ocp.StandardCheckpointer()
    ckptr.save(path / "state", jax.device_get(tree))
    ckptr.wait_until_finished()
    write_json_atomic(path / "metadata.json", {**metadata, "format_version": FORMAT_VERSION})


def read_metadata(path: str | os.PathLike) -> dict[str, Any]:
    path = Path(path)
    meta_file = path / "metadata.json"
    if not meta_file.exists():
        raise CheckpointError(
            f"No checkpoint at {path} (no metadata.json: missing, or an interrupted save). "
            "Check the path, or re-create the checkpoint."
        )
    try:
        meta = json.loads(meta_file.read_text())
    except json.JSONDecodeError as e:
        raise CheckpointError(f"Corrupt metadata in {meta_file}: {e}. Re-create the checkpoint.") from e
    if meta.get("format_version") != FORMAT_VERSION:
        raise CheckpointError(
            f"Checkpoint {path} has format version {meta.get('format_version')}, this code reads {FORMAT_VERSION}."
        )
    return meta


def restore(path: str | os.PathLike, target: Any) -> tuple[Any, dict[str, Any]]:
    """Restore into the structure, shapes and dtypes of ``target`` (an example pytree); returns (tree, metadata)."""
    path = Path(path).absolute()
    meta = read_metadata(path)
    abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, target)
    try:
        tree = ocp.StandardCheckpointer().restore(path / "state", abstract)
    except Exception as e:  # orbax raises several types for missing/corrupt/mismatched arrays
        raise CheckpointError(
            f"Could not restore {path}: {type(e).__name__}: {e}. The checkpoint is corrupt or was saved with a "
            "different network/env configuration; re-create it or match the configuration."
        ) from e
    return tree, meta
