"""Minari export of the suite's datasets, written with minari's own writer, so that a build can be shared as the
field's format and read back bit-for-bit (same :func:`~proto_brax.data.dataset.content_hash`) on any machine.

Rows become Minari episodes: an episode ends after every row with ``terminals`` or ``timeouts`` set, after the last
row, and where the next row does not continue it (its ``observations`` is not bitwise the ``next_observations`` of
this row: a stored trajectory that was cut without either flag). Each episode of ``T`` rows stores ``T + 1``
observations (``observations`` of its rows, then the ``next_observations`` of its last row, so the final step of a
time-limited episode keeps its successor), ``T`` actions and rewards, ``terminations = terminals`` and ``truncations
= timeouts`` (as stored: an episode cut without a flag ends with both False), and ``infos["dataset_row"]``: the row
of the suite dataset whose ``observations`` each stored observation is (``-1`` for the final one, which is only the
last row's ``next_observations``). Reading the episodes back the way
:func:`proto_brax.data.dataset.load_minari` does restores the rows exactly.

The dataset's ``metadata.json`` carries Minari's own fields (``ref_min_score`` / ``ref_max_score``: the env's
normalized-score references, so ``minari.get_normalized_score`` gives the suite's normalized scores) and, under
``"proto_brax"``, the content hash, the suite env name (Brax envs have no Gymnasium id: ``env_spec`` is None) and the
dataset's full generation metadata.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from proto_brax.data.dataset import _MINARI_ENV as MINARI_ENV
from proto_brax.data.dataset import _MINARI_EXPORT_KEY as METADATA_KEY  # our block in a dataset's metadata.json
from proto_brax.data.dataset import (
    FIELDS,
    OfflineDataset,
    _canonical_arrays,
    _env_var,
    _hash_arrays,
    check_finite,
)

EXPORT_FORMAT_VERSION = 1
ROW_INFO = "dataset_row"
# What a dataset directory written by export_minari holds (and all that --force ever deletes).
_OUR_FILES = frozenset({"data", "data/metadata.json", "data/main_data.hdf5"})
_ID_RE = re.compile(r"(?:[A-Za-z0-9_][-\w]*/)*[A-Za-z0-9_][-\w]*?-v\d+")
ID_FORMAT = "[NAMESPACE/]NAME-vVERSION (letters, digits, '-', '_'; e.g. proto_brax/hopper/medium-v0)"
# minari warns about fields that a Brax env's dataset cannot have (no Gymnasium spec, no evaluation env, no email).
_EXPECTED_WARNINGS = (r"`author_email` is set to None", r"`eval_env` is set to None", r"env_spec is None")


def minari_root(root: str | os.PathLike[str] | None = None) -> Path:
    """``root``, else ``$MINARI_DATASETS_PATH``, else ``~/.minari/datasets`` (minari's own rule)."""
    if root is not None:
        return Path(root)
    return Path(os.environ.get(MINARI_ENV) or Path.home() / ".minari" / "datasets")


def exported_env(dataset_id_or_path: str | os.PathLike[str]) -> str | None:
    """The suite env an exported Minari dataset (a directory, or an id under :func:`minari_root`) names in its
    ``metadata.json``, read as JSON alone (no episode, no minari import); None for any other dataset or path."""
    path = Path(dataset_id_or_path)
    for d in (path.parent if path.name == "data" else path, minari_root() / path):  # a directory, else an id
        file = d / "data" / "metadata.json"
        if file.is_file():
            try:
                block = json.loads(file.read_text()).get(METADATA_KEY)
                block = json.loads(block) if isinstance(block, str) else block
                return block.get("env") if isinstance(block, dict) else None
            except (OSError, ValueError, AttributeError):
                return None  # unreadable here: loading it names the fix
    return None


def default_id(name: str, size: int | None = None, seed: int = 0) -> str:
    """The Minari id a registered dataset is exported under: ``proto_brax/<env>/<kind>-v0`` (size and seed, when not
    the defaults, join the name: ``proto_brax/point/medium-n2000-seed1-v0``)."""
    from proto_brax.data.generate import default_size, parse_name

    env, kind = parse_name(name)
    default = default_size(env, kind)
    suffix = "" if (size in (None, default) and seed == 0) else f"-n{size or default}-seed{seed}"
    return f"proto_brax/{env}/{kind}{suffix}-v0"


def check_id(dataset_id: str) -> str:
    """``dataset_id`` when it is a Minari id this exporter writes (versioned, no path tricks), else ValueError."""
    bad = ValueError(f"{dataset_id!r} is not a Minari dataset id: ids read {ID_FORMAT}; pass another --id.")
    if not _ID_RE.fullmatch(dataset_id):
        raise bad
    from minari.dataset.minari_dataset import parse_dataset_id
    from minari.namespace import validate_namespace

    try:  # and minari's own rules (e.g. a namespace of two characters or more)
        namespace = parse_dataset_id(dataset_id)[0]
        if namespace is not None:
            validate_namespace(namespace)
    except ValueError:
        raise bad from None
    return dataset_id


def episode_bounds(dataset: OfflineDataset) -> list[tuple[int, int]]:
    """``[start, stop)`` row ranges of the episodes, as the module docstring defines them (bitwise continuity)."""
    arrays = _canonical_arrays(dataset)
    n = arrays["rewards"].shape[0]
    if n == 0:
        return []
    ends = (arrays["terminals"] > 0) | (arrays["timeouts"] > 0)
    obs, nxt = arrays["observations"].view(np.uint32), arrays["next_observations"].view(np.uint32)
    ends[:-1] |= np.any(obs[1:] != nxt[:-1], axis=-1)
    ends[-1] = True
    stops = np.flatnonzero(ends) + 1
    starts = np.concatenate([[0], stops[:-1]])
    return [(int(a), int(b)) for a, b in zip(starts, stops)]


def episode_buffers(dataset: OfflineDataset) -> list:
    """The dataset as ``minari.data_collector.EpisodeBuffer`` s (float32 observations / actions / rewards)."""
    from minari.data_collector import EpisodeBuffer

    a = _canonical_arrays(dataset)
    out = []
    for i, (start, stop) in enumerate(episode_bounds(dataset)):
        rows = np.arange(start, stop + 1, dtype=np.int64)
        rows[-1] = -1
        out.append(EpisodeBuffer(
            id=i,
            observations=np.concatenate([a["observations"][start:stop], a["next_observations"][stop - 1:stop]]),
            actions=a["actions"][start:stop],
            rewards=a["rewards"][start:stop],
            terminations=a["terminals"][start:stop] > 0,
            truncations=a["timeouts"][start:stop] > 0,
            infos={ROW_INFO: rows},
        ))
    return out


def written_by_us(path: Path) -> bool:
    """Whether the dataset directory ``path`` is one :func:`export_minari` wrote and holds nothing else (a real
    directory, not a link; only ``data/metadata.json`` and ``data/main_data.hdf5``; our block in the metadata)."""
    if path.is_symlink() or not path.is_dir():
        return False
    held = {p.relative_to(path).as_posix() for p in path.rglob("*")}
    if not held <= _OUR_FILES or any(p.is_symlink() for p in path.rglob("*")):
        return False
    try:
        meta = json.loads((path / "data" / "metadata.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(meta, dict) and isinstance(meta.get(METADATA_KEY), dict)


def remove_export(path: Path) -> None:
    """Delete a dataset directory :func:`written_by_us` accepts, file by file (nothing it does not know); any other
    directory raises FileExistsError and is left alone."""
    if not written_by_us(path):
        raise FileExistsError(f"{path} is not a dataset proto_brax exported (or holds other files): not deleting it.")
    for rel in sorted(_OUR_FILES, key=len, reverse=True):
        p = path / rel
        if p.is_dir():
            p.rmdir()
        elif p.exists():
            p.unlink()
    path.rmdir()


def export_minari(
    dataset: OfflineDataset,
    metadata: Mapping[str, Any],
    dataset_id: str,
    *,
    root: str | os.PathLike[str] | None = None,
    force: bool = False,
    env: str | None = None,
    source: str | None = None,
    command: str | None = None,
) -> Path:
    """Write ``dataset`` as the local Minari dataset ``dataset_id`` under ``root`` (:func:`minari_root`) with
    ``minari.create_dataset_from_buffers``; returns its directory (``root/dataset_id``).

    ``metadata`` is the dataset's own (generation) metadata, stored whole under ``"proto_brax"``/``"generation"``;
    ``env`` (default ``metadata["env"]``) is the suite env, whose normalized-score references become
    ``ref_min_score`` / ``ref_max_score``; ``source`` names where the rows came from (a dataset name or file),
    ``command`` the command that exports them again (the reader quotes it when the rows no longer match the hash).

    An existing dataset at that id is replaced only with ``force`` and only when this function wrote it and it holds
    nothing else (:func:`written_by_us`); otherwise FileExistsError, and nothing is touched. The old copy is kept
    aside until the new one is complete, and put back if the write fails.
    """
    import minari

    from proto_brax import __version__, envs

    check_id(dataset_id)
    arrays = _canonical_arrays(dataset)
    if arrays["rewards"].shape[0] == 0:
        raise ValueError("cannot export an empty dataset")
    check_finite(arrays, repr(source or dataset_id), "nothing was written")
    env = env or metadata.get("env")
    spec = envs.get_spec(env) if env in envs.REGISTRY else None
    chash = _hash_arrays(arrays)
    generation = json.loads(json.dumps(dict(metadata), allow_nan=False))  # plain JSON, or fail before writing

    root = minari_root(root).absolute()
    target = root / dataset_id
    aside = None
    if target.exists() or target.is_symlink():
        if not force:
            raise FileExistsError(f"Minari dataset {dataset_id} already exists at {target}: pass --force to replace "
                                  "it (only a dataset this command wrote), or another --id / --out.")
        if not written_by_us(target):
            raise FileExistsError(f"{target} was not written by `python -m proto_brax.datasets export` (or holds "
                                  "other files): refusing to replace it even with --force; pass another --id or --out.")
        aside = target.with_name(f".{target.name}.replaced-{os.getpid()}")
        target.rename(aside)

    buffers = episode_buffers(dataset)
    obs_dim, act_dim = arrays["observations"].shape[1], arrays["actions"].shape[1]
    import gymnasium as gym

    block = {
        "format_version": EXPORT_FORMAT_VERSION,
        "content_hash": chash,
        "env": env,
        "source": source,
        "export_command": command,
        "fields": list(FIELDS),
        "episodes": "split after terminals, timeouts and rows the next row does not continue (bitwise); "
                    "terminations = terminals, truncations = timeouts",
        "infos": f"{ROW_INFO}: the suite row whose observations each stored observation is (-1: the final one)",
        "exported_by": f"proto_brax {__version__}",
        "generation": generation,
    }
    try:
        with _env_var(MINARI_ENV, str(root)), warnings.catch_warnings():
            for message in _EXPECTED_WARNINGS:
                warnings.filterwarnings("ignore", message=message, category=UserWarning)
            ds = minari.create_dataset_from_buffers(
                dataset_id=dataset_id,
                buffer=buffers,
                env=None,
                observation_space=gym.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float32),
                action_space=gym.spaces.Box(-1.0, 1.0, (act_dim,), np.float32),
                algorithm_name=str(generation.get("kind") or "unknown"),
                author="proto_brax",
                code_permalink=f"proto_brax {__version__} (python -m proto_brax.datasets export)",
                description=(f"proto_brax dataset {source or dataset_id} on the Brax env {env!r} (not a Gymnasium "
                             "env: env_spec is None), exported bit-for-bit; see metadata['proto_brax']."),
                data_format="hdf5",
            )
            extra: dict[str, Any] = {METADATA_KEY: block}
            if spec is not None and spec.ref_random is not None and spec.ref_expert is not None:
                extra.update(ref_min_score=float(spec.ref_random), ref_max_score=float(spec.ref_expert))
            ds.storage.update_metadata(extra)
    except BaseException:
        if target.exists() and not target.is_symlink():
            shutil.rmtree(target)  # the partial dataset this call created (target was absent or moved aside)
        if aside is not None:
            aside.rename(target)
        raise
    if aside is not None:
        remove_export(aside)
    return target
