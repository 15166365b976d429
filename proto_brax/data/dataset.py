"""Offline datasets as one struct of arrays with D4RL's field names, plus their on-disk formats.

Formats read and written here:

* our own ``.npz`` (:func:`save_npz` / :func:`load_npz`): the six arrays of :class:`Transition` as float32, plus a
  JSON metadata entry carrying a ``format_version`` and a ``content_hash`` that is checked on every load;
* D4RL-format HDF5 (:func:`load_d4rl_hdf5`), read-only;
* local Minari datasets (:func:`load_minari`) through minari's own reader (written by
  :mod:`proto_brax.data.minari_io`, minari's own writer).

Every loader returns ``(dataset, metadata)`` with the arrays as host ``numpy`` arrays (float32; ``rewards``,
``terminals`` and ``timeouts`` of shape ``[N]``, the others ``[N, d]``); put them on device once with
``jax.device_put(dataset)``. :func:`validate_for_env` checks a dataset against an environment's sizes,
:func:`episode_returns` recovers per-episode returns.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import pathlib
import zipfile
from collections.abc import Iterator, Mapping
from typing import Any, Union

import jax
import numpy as np
from flax import struct

from proto_brax.files import atomic_write

PathLike = Union[str, "os.PathLike[str]"]  # a file or directory path


@struct.dataclass
class Transition:
    """Transitions (one, or a batch along a leading axis); field names follow D4RL."""

    observations: jax.Array
    actions: jax.Array
    rewards: jax.Array
    next_observations: jax.Array
    terminals: jax.Array  # 1.0 only for a true termination: bootstrapping stops there
    timeouts: jax.Array  # 1.0 where the time limit cut the episode: bootstrapping continues
    # Cal-QL only: discounted Monte-Carlo return-to-go within the episode (derived from the rest, never stored;
    # ``with_returns_to_go`` offline, ``proto_brax.data.replay.replay_accumulate_returns`` online).
    mc_returns: jax.Array | None = None


# An offline dataset is a batch of transitions along its leading axis, shared (never copied) by every run of a grid.
OfflineDataset = Transition

# Fixed order of the arrays: the content hash and the on-disk layout depend on it.
FIELDS: tuple[str, ...] = ("observations", "actions", "rewards", "next_observations", "terminals", "timeouts")
_VECTOR_FIELDS = ("observations", "actions", "next_observations")  # [N, d]
_SCALAR_FIELDS = ("rewards", "terminals", "timeouts")  # [N]
_FLAG_FIELDS = ("terminals", "timeouts")  # 0.0 / 1.0
_DTYPE = np.dtype("<f4")  # little-endian float32, whatever the host

FORMAT_VERSION = 1
_METADATA_KEY = "metadata"


class CorruptDatasetError(ValueError):
    """A dataset file that cannot be read back as written (truncated, overwritten, or its hash does not match)."""


def dataset_size(dataset: OfflineDataset) -> int:
    return int(dataset.rewards.shape[0])


# --------------------------------------------------------------------------------------------------------------------
# Canonical form and content hash
# --------------------------------------------------------------------------------------------------------------------


def _canonical_arrays(dataset: OfflineDataset) -> dict[str, np.ndarray]:
    """The six arrays as contiguous little-endian float32 numpy arrays, in :data:`FIELDS` order.

    ``rewards``/``terminals``/``timeouts`` of shape ``[N, 1]`` are squeezed to ``[N]``; boolean flags become 0.0/1.0.
    Raises ValueError on arrays of the wrong rank, with different leading lengths, or flags other than 0/1.
    """
    arrays: dict[str, np.ndarray] = {}
    for name in FIELDS:
        arr = np.asarray(getattr(dataset, name))
        if name in _SCALAR_FIELDS:
            if arr.ndim == 2 and arr.shape[1] == 1:
                arr = arr[:, 0]
            if arr.ndim != 1:
                raise ValueError(f"dataset field {name!r} must have shape [N], got {arr.shape}")
        elif arr.ndim != 2:
            raise ValueError(f"dataset field {name!r} must have shape [N, d], got {arr.shape}")
        arrays[name] = np.ascontiguousarray(arr, dtype=_DTYPE)
    lengths = {name: int(a.shape[0]) for name, a in arrays.items()}
    if len(set(lengths.values())) != 1:
        raise ValueError(f"dataset arrays have different leading lengths: {lengths}")
    for name in _FLAG_FIELDS:
        if not np.all((arrays[name] == 0) | (arrays[name] == 1)):
            raise ValueError(f"dataset field {name!r} must hold only 0/1 flags")
    return arrays


def _hash_arrays(arrays: Mapping[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for name in FIELDS:
        arr = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{arr.dtype.str}|{list(arr.shape)}\n".encode())
        h.update(arr.tobytes(order="C"))
    return h.hexdigest()


def content_hash(dataset: OfflineDataset) -> str:
    """sha256 (hex) of the dataset's content, as stored by :func:`save_npz`.

    The arrays are first put in canonical form (little-endian float32, ``[N]`` scalars, 0/1 flags), then each field,
    in the fixed order of :data:`FIELDS`, contributes its name, dtype and shape and then its raw bytes. The hash of a
    dataset therefore equals the ``content_hash`` that :func:`save_npz` records for it and :func:`load_npz` checks.
    """
    return _hash_arrays(_canonical_arrays(dataset))


def _from_arrays(arrays: Mapping[str, np.ndarray]) -> OfflineDataset:
    return Transition(**{name: arrays[name] for name in FIELDS})


class NonFiniteDatasetError(ValueError):
    """A dataset holding NaN or ±inf values: refused when loaded (or saved), before anything else reads it."""


def check_finite(arrays: Mapping[str, np.ndarray], source: str, fix: str | None = None) -> None:
    """Raise :class:`NonFiniteDatasetError` naming each field of ``arrays`` that holds NaN or ±inf, with the count."""
    bad = {name: int(np.size(a) - np.count_nonzero(np.isfinite(a))) for name, a in arrays.items()
           if np.issubdtype(np.asarray(a).dtype, np.floating)}
    bad = {k: v for k, v in bad.items() if v}
    if bad:
        where = ", ".join(f"{n} in {k} (of {np.size(arrays[k])})" for k, v in bad.items() for n in [v])
        raise NonFiniteDatasetError(f"dataset {source} holds non-finite values (NaN or ±inf): {where}; "
                                    f"{fix or 'fix the data (or regenerate it) and try again'}.")


# --------------------------------------------------------------------------------------------------------------------
# Our .npz format
# --------------------------------------------------------------------------------------------------------------------


def save_npz(path: PathLike, dataset: OfflineDataset, metadata: Mapping[str, Any]) -> None:
    """Write ``dataset`` and ``metadata`` to one uncompressed ``.npz`` file at ``path`` (taken as given: no suffix).

    The file holds the six arrays (float32; ``rewards``/``terminals``/``timeouts`` of shape ``[N]``, flags as 0/1)
    and, under the key ``"metadata"``, a JSON string of ``metadata`` plus ``format_version`` and ``content_hash``
    (those two are always (re)computed here and override any stale values in ``metadata``). ``metadata`` must be
    JSON-serialisable (no NaN/inf); it comes back from :func:`load_npz` as JSON does (tuples become lists).
    ``metadata`` itself is not modified.

    The write is atomic (:func:`proto_brax.files.atomic_write`): if anything fails on the way, ``path`` is left as
    it was (absent, or the previous complete file).
    """
    path = os.fspath(path)
    arrays = _canonical_arrays(dataset)
    check_finite(arrays, repr(path), "nothing was written")
    full_metadata = dict(metadata)
    full_metadata["format_version"] = FORMAT_VERSION
    full_metadata["content_hash"] = _hash_arrays(arrays)
    metadata_json = json.dumps(full_metadata, sort_keys=True, allow_nan=False)  # fails before any file is touched

    with atomic_write(path, "wb") as f:
        np.savez(f, **arrays, **{_METADATA_KEY: np.array(metadata_json)})  # a unicode array: no pickling


def _corrupt(path: str, reason: str, rebuild_hint: str | None) -> CorruptDatasetError:
    how = f"rebuild it with: {rebuild_hint}" if rebuild_hint else "rebuild it with the command that created it"
    return CorruptDatasetError(f"dataset file {path!r} is corrupt or unreadable ({reason}); delete it and {how}")


def load_npz(
    path: PathLike, expected_hash: str | None = None, *, rebuild_hint: str | None = None
) -> tuple[OfflineDataset, dict[str, Any]]:
    """Read a file written by :func:`save_npz` and check its integrity.

    The content hash is recomputed from the arrays read and compared with the one stored in the file and, if given,
    with ``expected_hash``. A mismatch, or a file that cannot be parsed (truncated, bytes overwritten, missing
    entries, wrong shapes, unknown ``format_version``), raises :class:`CorruptDatasetError` naming the file and how
    to rebuild it (``rebuild_hint``, e.g. ``"python -m proto_brax.datasets make hopper-medium"``, is quoted in the
    message). A missing file raises FileNotFoundError, with the same hint.

    Returns the dataset (numpy float32 arrays) and its metadata, ``format_version`` and ``content_hash`` included.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        how = f"build it with: {rebuild_hint}" if rebuild_hint else "build it first"
        raise FileNotFoundError(f"dataset file {path!r} does not exist; {how}")
    try:
        with np.load(path, allow_pickle=False) as npz:
            missing = [k for k in (*FIELDS, _METADATA_KEY) if k not in npz.files]
            if missing:
                raise _corrupt(path, f"missing entries {missing}", rebuild_hint)
            arrays = {name: npz[name] for name in FIELDS}
            metadata = json.loads(str(npz[_METADATA_KEY][()]))
    except CorruptDatasetError:
        raise
    except (OSError, EOFError, ValueError, KeyError, TypeError, zipfile.BadZipFile, UnicodeDecodeError) as e:
        # json.JSONDecodeError is a ValueError; zlib/CRC errors surface as BadZipFile or OSError.
        raise _corrupt(path, f"{type(e).__name__}: {e}", rebuild_hint) from e

    if not isinstance(metadata, dict):
        raise _corrupt(path, "metadata entry is not a JSON object", rebuild_hint)
    version = metadata.get("format_version")
    if version != FORMAT_VERSION:
        raise _corrupt(path, f"format_version {version!r}, this code reads {FORMAT_VERSION}", rebuild_hint)
    for name, arr in arrays.items():
        if arr.dtype != _DTYPE:
            raise _corrupt(path, f"field {name!r} has dtype {arr.dtype}, expected float32", rebuild_hint)
    try:
        _canonical_arrays(_from_arrays(arrays))  # ranks and leading lengths
    except ValueError as e:
        raise _corrupt(path, str(e), rebuild_hint) from e

    actual = _hash_arrays(arrays)
    stored = metadata.get("content_hash")
    if actual != stored:
        raise _corrupt(path, f"content hash {actual} does not match the stored {stored}", rebuild_hint)
    if expected_hash is not None and actual != expected_hash:
        raise _corrupt(path, f"content hash {actual} does not match the expected {expected_hash}", rebuild_hint)
    check_finite(arrays, repr(path), f"rebuild it with: {rebuild_hint}" if rebuild_hint else None)
    return _from_arrays(arrays), metadata


# --------------------------------------------------------------------------------------------------------------------
# D4RL HDF5
# --------------------------------------------------------------------------------------------------------------------

_MAX_METADATA_ARRAY_SIZE = 64  # larger arrays in an HDF5 metadata group (e.g. policy weights) are left out


def _jsonable(value: Any) -> Any:
    """An HDF5 attribute/dataset value as plain JSON-able Python (bytes decoded, numpy scalars unwrapped)."""
    if isinstance(value, bytes):
        return value.decode("utf-8", errors="replace")
    if isinstance(value, np.ndarray):
        return [_jsonable(v) for v in value.tolist()] if value.ndim else _jsonable(value[()])
    if isinstance(value, np.generic):
        return _jsonable(value.item())
    if isinstance(value, list):
        return [_jsonable(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def _hdf5_metadata(file: Any) -> dict[str, Any]:
    """The file's root attributes, plus the attributes and (small) datasets of its ``metadata/`` group.

    Entries of the group are keyed by their path inside it (``"algorithm"``, ``"policy/nonlinearity"``); arrays of
    more than 64 elements (policy weights) are skipped.
    """
    import h5py

    out: dict[str, Any] = {str(k): _jsonable(v) for k, v in file.attrs.items()}
    group = file.get("metadata")
    if isinstance(group, h5py.Group):
        out.update({str(k): _jsonable(v) for k, v in group.attrs.items()})

        def visit(name: str, obj: Any) -> None:
            if isinstance(obj, h5py.Dataset) and obj.size <= _MAX_METADATA_ARRAY_SIZE:
                out[name] = _jsonable(obj[()])
            for k, v in obj.attrs.items():
                out[f"{name}/{k}"] = _jsonable(v)

        group.visititems(visit)
    return out


def load_d4rl_hdf5(path: PathLike) -> tuple[OfflineDataset, dict[str, Any]]:
    """Read a D4RL-format HDF5 file.

    Required datasets: ``observations``, ``actions``, ``rewards``, ``terminals``; optional: ``timeouts`` (zeros if
    absent) and ``next_observations``. Rows are steps of consecutive episodes.

    * With ``next_observations`` in the file, every row is one transition, taken as is.
    * Without it, successors are rebuilt as D4RL's ``qlearning_dataset`` does (``terminate_on_end=False``): row ``i``
      becomes ``(obs[i], act[i], rew[i], obs[i+1], terminals[i])`` for ``i < N-1``, and the rows with ``timeouts[i]``
      set are dropped (the last step of a time-limited episode has no stored successor: ``obs[i+1]`` starts the next
      episode), as is the final row. Like D4RL, a row with both flags set is dropped too. So that episode boundaries
      survive the drop, ``timeouts`` is set to 1 on the last kept transition before a dropped timeout row and on the
      last kept transition of a final, unfinished episode: "the stored trajectory breaks here without a true
      termination" (bootstrapping from ``next_observations`` stays valid there).

    Metadata: the file's root attributes and its ``metadata/`` group (see :func:`_hdf5_metadata`), plus
    ``source: "d4rl-hdf5"``, ``path`` and ``rebuilt_next_observations``.
    """
    import h5py

    path_str = os.fspath(path)
    required = ("observations", "actions", "rewards", "terminals")
    with h5py.File(path_str, "r") as f:
        missing = [k for k in required if k not in f]
        if missing:
            raise ValueError(f"D4RL HDF5 file {path_str!r} lacks the datasets {missing} (has {sorted(f.keys())})")
        raw = {k: np.asarray(f[k][()]) for k in (*required, "timeouts", "next_observations") if k in f}
        metadata = _hdf5_metadata(f)

    n = int(raw["rewards"].shape[0])
    for name, arr in raw.items():
        if arr.ndim == 0 or arr.shape[0] != n:
            raise ValueError(f"D4RL HDF5 file {path_str!r}: {name} has shape {arr.shape}, rewards has {n} rows")
    obs = raw["observations"].reshape(n, -1).astype(np.float32)
    act = raw["actions"].reshape(n, -1).astype(np.float32)
    rew = raw["rewards"].reshape(n).astype(np.float32)
    term = (raw["terminals"].reshape(n) != 0).astype(np.float32)
    tout = (raw["timeouts"].reshape(n) != 0).astype(np.float32) if "timeouts" in raw else np.zeros(n, np.float32)

    if "next_observations" in raw:
        next_obs = raw["next_observations"].reshape(n, -1).astype(np.float32)
        if next_obs.shape != obs.shape:
            raise ValueError(
                f"D4RL HDF5 file {path_str!r}: next_observations {next_obs.shape} vs observations {obs.shape}"
            )
        arrays = dict(
            observations=obs, actions=act, rewards=rew, next_observations=next_obs, terminals=term, timeouts=tout
        )
        rebuilt = False
    else:
        keep = np.zeros(n, dtype=bool)
        keep[: max(n - 1, 0)] = tout[: max(n - 1, 0)] == 0
        idx = np.flatnonzero(keep)
        # A kept row ends its stored trajectory when it is not terminal and the row after it is not kept (dropped
        # timeout row, or the final row of the file).
        next_kept = np.zeros(n, dtype=bool)
        next_kept[:-1] = keep[1:]
        boundary = (~next_kept) & (term == 0)
        arrays = dict(
            observations=obs[idx],
            actions=act[idx],
            rewards=rew[idx],
            next_observations=obs[idx + 1],
            terminals=term[idx],
            timeouts=boundary[idx].astype(np.float32),
        )
        rebuilt = True

    arrays = {name: np.ascontiguousarray(arrays[name], dtype=_DTYPE) for name in FIELDS}
    check_finite(arrays, repr(path_str))
    metadata.update(source="d4rl-hdf5", path=os.path.abspath(path_str), rebuilt_next_observations=rebuilt)
    return _from_arrays(arrays), metadata


# --------------------------------------------------------------------------------------------------------------------
# Minari
# --------------------------------------------------------------------------------------------------------------------

_MINARI_ENV = "MINARI_DATASETS_PATH"
_GOAL_KEYS = ("observation", "desired_goal")
_MINARI_EXPORT_KEY = "proto_brax"  # our block in the metadata.json of an exported dataset (minari_io.METADATA_KEY)


@contextlib.contextmanager
def _env_var(name: str, value: str) -> Iterator[None]:
    """Set an environment variable for the duration of a ``with`` block, then restore (or unset) it."""
    old = os.environ.get(name)
    os.environ[name] = value
    try:
        yield
    finally:
        if old is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = old


def _flatten_minari_obs(obs: Any, where: str) -> np.ndarray:
    """Episode observations ``[T+1, ...]`` as float32 ``[T+1, d]``.

    Dict observations must be goal-conditioned (keys ``observation`` and ``desired_goal``, e.g. AntMaze/PointMaze):
    they become ``concat(observation, desired_goal)`` along the last axis (``achieved_goal`` is dropped: it is part
    of the state already). Other dict or tuple spaces are rejected.
    """
    if isinstance(obs, dict):
        if not all(k in obs for k in _GOAL_KEYS):
            raise ValueError(
                f"{where}: dict observations with keys {sorted(obs)} are not supported; only goal-conditioned ones "
                f"with keys {list(_GOAL_KEYS)} (flattened to concat(observation, desired_goal))"
            )
        parts = [np.asarray(obs[k]) for k in _GOAL_KEYS]
        parts = [p.reshape(p.shape[0], -1) for p in parts]
        return np.concatenate(parts, axis=-1).astype(np.float32)
    if isinstance(obs, (tuple, list)):
        raise ValueError(f"{where}: tuple observation spaces are not supported")
    arr = np.asarray(obs)
    return arr.reshape(arr.shape[0], -1).astype(np.float32)


def _resolve_minari_dir(path: pathlib.Path) -> tuple[pathlib.Path, str]:
    """(datasets root, dataset id) for a dataset directory (``.../<id>`` holding ``data/``, or its ``data/``)."""
    if path.name == "data" and (path / "metadata.json").is_file():
        path = path.parent
    metadata_file = path / "data" / "metadata.json"
    if not metadata_file.is_file():
        raise FileNotFoundError(f"{str(path)!r} is not a Minari dataset directory (no data/metadata.json in it)")
    with open(metadata_file) as f:
        dataset_id = str(json.load(f)["dataset_id"])
    parts = pathlib.PurePosixPath(dataset_id).parts
    resolved = path.resolve()
    if tuple(resolved.parts[-len(parts) :]) != tuple(parts):
        raise ValueError(
            f"Minari dataset directory {str(path)!r} holds dataset {dataset_id!r} but is not laid out as "
            f"<root>/{dataset_id}; move it there so that minari can find it"
        )
    return resolved.parents[len(parts) - 1], dataset_id


def load_minari(dataset_id_or_path: PathLike) -> tuple[OfflineDataset, dict[str, Any]]:
    """Read a local Minari dataset (never downloads) with minari's own reader and flatten it into transitions.

    ``dataset_id_or_path`` is either a dataset id (``"D4RL/door/human-v2"``), looked up by ``minari.load_dataset``
    under ``$MINARI_DATASETS_PATH`` (default ``~/.minari/datasets``), or the path of a dataset directory (the one
    holding ``data/``, or that ``data/`` itself; a ``pathlib.Path`` is always taken as a path, a string when it names
    an existing directory). For a path, ``MINARI_DATASETS_PATH`` is pointed at its datasets root for the duration of
    the call only and restored afterwards (not thread-safe).

    Each episode of ``T`` steps (``T+1`` observations) gives ``T`` transitions: ``observations[:-1]`` →
    ``observations``, ``observations[1:]`` → ``next_observations``, ``terminations`` → ``terminals``,
    ``truncations`` → ``timeouts``. Goal-conditioned dict observations (AntMaze: ``observation`` / ``achieved_goal``
    / ``desired_goal``) are flattened to ``concat(observation, desired_goal)``; image-like observations are flattened
    per step. Metadata: ``source: "minari"``, ``dataset_id``, ``path`` (the data directory), ``minari_version``,
    ``total_episodes``, ``total_steps``, ``env_id``, ``content_hash`` (:func:`content_hash` of the rows read) and the
    reference scores when recorded, and ``observation_layout`` when dict observations were flattened.

    A dataset exported by :mod:`proto_brax.data.minari_io` reads back to exactly the rows it was written from: its
    recorded content hash is checked (:class:`CorruptDatasetError` on a mismatch), and its ``proto_brax`` block
    (the generation metadata) and suite ``env`` join the metadata.
    """
    import minari

    is_path = isinstance(dataset_id_or_path, os.PathLike) or os.path.isdir(os.fspath(dataset_id_or_path))
    if is_path:
        root, dataset_id = _resolve_minari_dir(pathlib.Path(os.fspath(dataset_id_or_path)))
        with _env_var(_MINARI_ENV, str(root)):
            ds = minari.load_dataset(dataset_id, download=False)
    else:
        dataset_id = os.fspath(dataset_id_or_path)
        ds = minari.load_dataset(dataset_id, download=False)

    parts: dict[str, list[np.ndarray]] = {name: [] for name in FIELDS}
    dict_obs = False
    for ep in ds.iterate_episodes():
        where = f"Minari dataset {dataset_id!r}, episode {ep.id}"
        dict_obs = dict_obs or isinstance(ep.observations, dict)
        obs = _flatten_minari_obs(ep.observations, where)
        t = len(ep.rewards)
        if obs.shape[0] != t + 1:
            raise ValueError(f"{where}: {obs.shape[0]} observations for {t} steps (expected {t + 1})")
        parts["observations"].append(obs[:-1])
        parts["next_observations"].append(obs[1:])
        act = np.asarray(ep.actions)
        parts["actions"].append(act.reshape(t, -1).astype(np.float32))
        parts["rewards"].append(np.asarray(ep.rewards, np.float32).reshape(t))
        parts["terminals"].append((np.asarray(ep.terminations).reshape(t) != 0).astype(np.float32))
        parts["timeouts"].append((np.asarray(ep.truncations).reshape(t) != 0).astype(np.float32))
    if not parts["rewards"]:
        raise ValueError(f"Minari dataset {dataset_id!r} has no episodes")
    arrays = {name: np.ascontiguousarray(np.concatenate(parts[name]), dtype=_DTYPE) for name in FIELDS}
    check_finite(arrays, f"Minari {dataset_id!r}")

    raw = ds.storage.metadata
    env_spec = ds.env_spec
    data_path = os.path.abspath(str(ds.spec.data_path))
    metadata: dict[str, Any] = {
        "source": "minari",
        "dataset_id": ds.id,
        "path": data_path,
        "minari_version": ds.minari_version,
        "total_episodes": int(ds.total_episodes),
        "total_steps": int(ds.total_steps),
        "env_id": env_spec.id if env_spec is not None else None,
        "content_hash": _hash_arrays(arrays),
    }
    for key in ("ref_min_score", "ref_max_score", "algorithm_name"):
        if raw.get(key) is not None:
            metadata[key] = _jsonable(raw[key])
    if dict_obs:
        metadata["observation_layout"] = "concat(observation, desired_goal)"
    exported = raw.get(_MINARI_EXPORT_KEY)
    if isinstance(exported, dict):  # written by `python -m proto_brax.datasets export` (proto_brax.data.minari_io)
        stored = exported.get("content_hash")
        if stored != metadata["content_hash"]:
            raise CorruptDatasetError(
                f"Minari dataset {dataset_id!r} ({data_path}) reads back with content hash {metadata['content_hash']}, "
                f"but it was exported with {stored}: it was modified or truncated; export it again with "
                f"{exported.get('export_command') or 'python -m proto_brax.datasets export NAME --minari --force'}")
        metadata["env"] = exported.get("env")  # the suite env (a Brax env: there is no Gymnasium env_spec)
        metadata[_MINARI_EXPORT_KEY] = exported
    return _from_arrays(arrays), metadata


# --------------------------------------------------------------------------------------------------------------------
# Checks and statistics
# --------------------------------------------------------------------------------------------------------------------


def validate_for_env(
    dataset: OfflineDataset,
    observation_size: int,
    action_size: int,
    name: str,
    *,
    env_name: str | None = None,
    action_tolerance: float = 1e-6,
) -> None:
    """Check that ``dataset`` (called ``name`` in messages) fits an environment; raise ValueError otherwise.

    Checks, in order: ranks, a common leading length of all six arrays and 0/1 flags; ``observations`` and
    ``next_observations`` of size ``observation_size`` and ``actions`` of size ``action_size`` (the message gives
    both sizes, the dataset name and ``env_name``); finite values; actions within ``[-1, 1]`` (up to
    ``action_tolerance``), as the squashed (tanh) policies assume.
    """
    env = f"environment {env_name!r}" if env_name else "the environment"
    try:
        arrays = _canonical_arrays(dataset)
    except ValueError as e:
        raise ValueError(f"dataset {name!r}: {e}") from e
    n = arrays["rewards"].shape[0]
    if n == 0:
        raise ValueError(f"dataset {name!r} is empty")
    for field in ("observations", "next_observations"):
        size = arrays[field].shape[1]
        if size != observation_size:
            raise ValueError(
                f"dataset {name!r} has {field} of size {size} but {env} expects observation size "
                f"{observation_size}: the dataset was recorded for a different environment or observation layout"
            )
    size = arrays["actions"].shape[1]
    if size != action_size:
        raise ValueError(
            f"dataset {name!r} has actions of size {size} but {env} expects action size {action_size}: "
            "the dataset was recorded for a different environment"
        )
    for field, arr in arrays.items():
        bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
        if bad:
            raise ValueError(f"dataset {name!r} has {bad} non-finite values in {field}")
    act = arrays["actions"]
    out = np.abs(act) > 1.0 + action_tolerance
    if out.any():
        raise ValueError(
            f"dataset {name!r} has {int(out.sum())} action entries outside [-1, 1] (min {float(act.min())}, max "
            f"{float(act.max())}); {env} expects actions in [-1, 1]: rescale the dataset's actions to that range"
        )


def episode_returns(dataset: OfflineDataset) -> np.ndarray:
    """Undiscounted return (float64) of each stored episode, in order.

    Episodes end after every transition with ``terminals`` or ``timeouts`` set, and at the end of the dataset (an
    unfinished last episode counts as one). An empty dataset gives an empty array.
    """
    rewards = np.asarray(dataset.rewards, dtype=np.float64).reshape(-1)
    n = rewards.shape[0]
    if n == 0:
        return np.zeros(0, np.float64)
    ends = (np.asarray(dataset.terminals).reshape(n) != 0) | (np.asarray(dataset.timeouts).reshape(n) != 0)
    episode_id = np.concatenate([[0], np.cumsum(ends[:-1])])
    return np.bincount(episode_id, weights=rewards, minlength=int(episode_id[-1]) + 1)


def return_range_scale(dataset: OfflineDataset) -> float:
    """1000 / (max − min episode return): the reward scale IQL's, IVR's and PROTO's reference code apply to D4RL
    locomotion data (and to the online rewards that join it), so that returns span ~1000 whatever the task."""
    returns = episode_returns(dataset)
    spread = float(returns.max() - returns.min()) if returns.size else 0.0
    if returns.size < 2 or not spread > 0:
        raise ValueError(f"Cannot normalize rewards by the return range of a dataset with {returns.size} episode(s) "
                         f"and return spread {spread}: pass an explicit reward scale (--reward-scale).")
    return 1000.0 / spread


def transform_rewards(dataset: OfflineDataset, scale: float, shift: float) -> OfflineDataset:
    """The dataset with rewards scale · r + shift (float32; returns-to-go must be computed after this)."""
    if scale == 1.0 and shift == 0.0:
        return dataset
    if dataset.mc_returns is not None:
        raise ValueError("transform_rewards before with_returns_to_go: the returns-to-go would keep the old rewards.")
    rewards = np.asarray(dataset.rewards, np.float32) * np.float32(scale) + np.float32(shift)
    return dataset.replace(rewards=rewards)


def episode_return_stats(dataset: OfflineDataset) -> dict[str, float | int]:
    """Summary of :func:`episode_returns` for ``info`` commands: ``num_episodes``, ``mean``, ``min``, ``max``.

    ``num_transitions`` too; the statistics are NaN for an empty dataset.
    """
    returns = episode_returns(dataset)
    empty = returns.size == 0
    return {
        "num_transitions": dataset_size(dataset),
        "num_episodes": int(returns.size),
        "mean": float("nan") if empty else float(returns.mean()),
        "min": float("nan") if empty else float(returns.min()),
        "max": float("nan") if empty else float(returns.max()),
    }


# --------------------------------------------------------------------------------------------------------------------
# Monte-Carlo returns-to-go (Cal-QL's calibration bound)
# --------------------------------------------------------------------------------------------------------------------


def episode_ends(dataset: OfflineDataset) -> np.ndarray:
    """Boolean [N]: row i ends an episode (terminal, timeout, the next row does not continue it, or the last row)."""
    obs = np.asarray(dataset.observations)
    nxt = np.asarray(dataset.next_observations)
    ends = (np.asarray(dataset.terminals) > 0) | (np.asarray(dataset.timeouts) > 0)
    ends[:-1] |= np.any(np.abs(obs[1:] - nxt[:-1]) > 1e-6, axis=-1)
    ends[-1] = True
    return ends


def returns_to_go(dataset: OfflineDataset, gamma: float) -> np.ndarray:
    """G_t = r_t + γ G_{t+1} within each episode, G = r at its last row (Cal-QL's reference: a truncated episode is
    not bootstrapped). float64 accumulation, float32 result [N]."""
    rewards = np.asarray(dataset.rewards, np.float64)
    ends = episode_ends(dataset)
    out = np.empty_like(rewards)
    g = 0.0
    for i in range(len(rewards) - 1, -1, -1):
        g = rewards[i] + (0.0 if ends[i] else gamma * g)
        out[i] = g
    return out.astype(np.float32)


def with_returns_to_go(dataset: OfflineDataset, gamma: float) -> OfflineDataset:
    return dataset.replace(mc_returns=returns_to_go(dataset, gamma))
