"""Checkpoints with orbax: pytrees saved beside a metadata JSON (format version), written atomically.

A checkpoint directory holds ``state/`` (orbax ``StandardCheckpointer``: orbax writes into a temporary directory and
renames it on commit) and ``metadata.json`` (written to a temp file, then ``os.replace``). ``metadata.json`` is written
last, so a directory without it is an interrupted save and is never read.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import shutil
from pathlib import Path
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

from proto_brax.files import write_json_atomic

FORMAT_VERSION = 1


class CheckpointError(ValueError):
    """A missing, corrupt or mismatched checkpoint."""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def remove_stale_temporaries(directory: Path, pattern: str) -> list[Path]:
    """Remove the hidden ``…tmp-PID`` / ``…old-PID`` directories (matching ``pattern``) that a save killed midway left
    behind; a directory whose process still runs is left alone. Returns what was removed."""
    removed = []
    for p in sorted(Path(directory).glob(pattern)):
        pid = p.name.rpartition("-")[2]
        if not pid.isdigit() or int(pid) == os.getpid() or _alive(int(pid)):
            continue
        shutil.rmtree(p, ignore_errors=True)
        removed.append(p)
    return removed


def tree_content_hash(tree: Any) -> str:
    """sha256 (hex) of a pytree's array content: each non-empty leaf, in tree order, contributes its path, dtype and
    shape and then its bytes. What a bundle records as ``content_sha256`` and ``load_bundle`` checks."""
    h = hashlib.sha256()
    for key, leaf in jax.tree_util.tree_leaves_with_path(jax.device_get(tree)):
        a = np.ascontiguousarray(np.asarray(leaf))
        if a.size == 0:  # (saved as None: see _drop_empty)
            continue
        h.update(f"{jax.tree_util.keystr(key)}|{a.dtype.str}|{list(a.shape)}\n".encode())
        h.update(a.tobytes(order="C"))
    return h.hexdigest()


def save(path: str | os.PathLike, tree: Any, metadata: dict[str, Any]) -> None:
    """Save ``tree`` and ``metadata`` to directory ``path``, replacing an older checkpoint there atomically.

    Everything is written into a hidden sibling directory first and renamed into place, so a reader (or a resume after
    SIGKILL) sees the old checkpoint or the new one, never a partial one. A non-empty ``path`` that is not a
    checkpoint (no metadata.json) is refused, never replaced.
    """
    path = Path(path).absolute()
    if path.exists() and (not path.is_dir() or (any(path.iterdir()) and not (path / "metadata.json").exists())):
        what = ", ".join(sorted(p.name for p in path.iterdir())[:5]) if path.is_dir() else "a file"
        raise CheckpointError(f"Refusing to replace {path}: it is not a checkpoint (no metadata.json; it holds "
                              f"{what}). Choose another path.")
    remove_stale_temporaries(path.parent, f".{path.name}.tmp-*")
    remove_stale_temporaries(path.parent, f".{path.name}.old-*")
    tmp = path.parent / f".{path.name}.tmp-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    ckptr = ocp.StandardCheckpointer()
    ckptr.save(tmp / "state", _drop_empty(jax.device_get(tree)))
    ckptr.wait_until_finished()
    write_json_atomic(tmp / "metadata.json", {**metadata, "format_version": FORMAT_VERSION})
    if path.exists():
        old = path.parent / f".{path.name}.old-{os.getpid()}"
        os.rename(path, old)
        os.rename(tmp, path)
        shutil.rmtree(old)
    else:
        os.rename(tmp, path)


def save_step(root: str | os.PathLike, step: int, tree: Any, metadata: dict[str, Any], keep: int = 2) -> Path:
    """Step-numbered checkpoint ``root/step_XXXXXXXX``; older ones beyond the newest ``keep`` are removed after the
    new one is complete (a crash at any point leaves at least one complete checkpoint). Temporaries of saves that a
    kill interrupted (``.step_*.tmp-PID``) are removed."""
    root = Path(root)
    if root.is_dir():
        remove_stale_temporaries(root, ".step_*.tmp-*")
        remove_stale_temporaries(root, ".step_*.old-*")
    path = root / f"step_{step:08d}"
    save(path, tree, {**metadata, "step": step})
    for old in sorted(root.glob("step_*"))[:-keep]:
        shutil.rmtree(old, ignore_errors=True)
    return path


def latest_step(root: str | os.PathLike) -> Path | None:
    """The newest complete step checkpoint under ``root`` (None if there is none)."""
    done = [p for p in sorted(Path(root).glob("step_*")) if (p / "metadata.json").exists()]
    return done[-1] if done else None


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


def _drop_empty(tree):
    """Zero-size arrays (MJX states hold some, e.g. ``act`` without actuator activations) as None: orbax refuses to
    save them, and they carry no data; ``restore`` recreates them from the target's shapes."""
    return jax.tree.map(lambda x: None if np.size(x) == 0 else x, tree)


def _is_namedtuple(x) -> bool:
    return isinstance(x, tuple) and hasattr(x, "_fields")


def _tree_fields(x) -> list[str]:
    """A dataclass node's fields that are pytree children, the ones orbax stores. MJX's ``PyTreeNode`` and flax's
    ``struct`` keep the others as static metadata outside the tree (MJX's constraint counts ``Data._impl.ne``, …):
    never saved, and kept from the target on restore."""
    try:
        children, _ = jax.tree_util.flatten_one_level_with_keys(x)
    except ValueError:  # a dataclass that is not a registered pytree node: all of its fields
        return [f.name for f in dataclasses.fields(x)]
    return [k.name for k, _ in children]


def _plain(x):
    """Dataclass nodes as dicts of their pytree fields (None kept), the rest as is: the structure orbax stores them
    in."""
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return {name: _plain(getattr(x, name)) for name in _tree_fields(x)}
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if _is_namedtuple(x):
        return type(x)(*[_plain(v) for v in x])
    if isinstance(x, (list, tuple)):
        return type(x)(_plain(v) for v in x)
    return x


def _reconcile(t, disk, where: str = ""):
    """Align the target's dict keys with the checkpoint's: an optional (None) field the checkpoint predates is dropped,
    a None the checkpoint holds is kept; any other difference is a real mismatch, reported by orbax."""
    if isinstance(t, dict) and isinstance(disk, dict):
        out = {}
        for k in list(t) + [k for k in disk if k not in t]:
            if k not in disk and t[k] is None:
                continue  # a field added after this checkpoint was written; it stays None
            if k not in t and disk[k] is None:
                out[k] = None
                continue
            out[k] = _reconcile(t[k], disk[k], f"{where}.{k}") if k in t and k in disk else t.get(k)
        return out
    if _is_namedtuple(t) and isinstance(disk, dict):
        return type(t)(*[_reconcile(v, disk.get(f), f"{where}.{f}") for f, v in zip(t._fields, t)])
    if isinstance(t, (list, tuple)) and isinstance(disk, (list, tuple)) and len(t) == len(disk):
        vals = [_reconcile(a, b, f"{where}[{i}]") for i, (a, b) in enumerate(zip(t, disk))]
        return type(t)(*vals) if _is_namedtuple(t) else type(t)(vals)
    return t


def _rebuild(t, r):
    """Put restored values back into the target's own types (dataclasses, namedtuples); absent fields stay None;
    zero-size arrays (saved as None) come back as zeros of the target's shape."""
    if t is None:
        return None
    if isinstance(t, jax.ShapeDtypeStruct) and math.prod(t.shape) == 0:
        return np.zeros(t.shape, t.dtype)
    if dataclasses.is_dataclass(t) and not isinstance(t, type):  # (static fields stay the target's)
        return dataclasses.replace(t, **{name: _rebuild(getattr(t, name), (r or {}).get(name))
                                         for name in _tree_fields(t)})
    if isinstance(t, dict):
        return {k: _rebuild(v, r[k]) for k, v in t.items()}
    if _is_namedtuple(t):
        items = [r[f] for f in t._fields] if isinstance(r, dict) else list(r)
        return type(t)(*[_rebuild(a, b) for a, b in zip(t, items)])
    if isinstance(t, (list, tuple)):
        return type(t)(_rebuild(a, b) for a, b in zip(t, r))
    return r


def restore(path: str | os.PathLike, target: Any) -> tuple[Any, dict[str, Any]]:
    """Restore into the structure, shapes and dtypes of ``target`` (an example pytree); returns (tree, metadata).

    Checkpoints written before an optional (None) field was added to a state type still restore: the field stays
    None (orbax alone refuses any difference in the tree's keys).
    """
    path = Path(path).absolute()
    meta = read_metadata(path)
    abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, target)
    try:
        ckptr = ocp.StandardCheckpointer()
        on_disk = ckptr.metadata(path / "state").item_metadata.tree
        restored = ckptr.restore(path / "state", _reconcile(_plain(_drop_empty(abstract)), on_disk))
        tree = _rebuild(abstract, restored)
    except Exception as e:  # orbax raises several types for missing/corrupt/mismatched arrays
        raise CheckpointError(
            f"Could not restore {path}: {type(e).__name__}: {e}. The checkpoint is corrupt or was saved with a "
            "different network/env configuration; re-create it or match the configuration."
        ) from e
    # orbax restores what was saved even where the target's shapes differ: check them ourselves.
    got = jax.tree.map(lambda x: (tuple(x.shape), str(x.dtype)), tree)
    want = jax.tree.map(lambda x: (tuple(x.shape), str(x.dtype)), abstract)
    if got != want:
        bad = [f"{jax.tree_util.keystr(k)}: saved {g}, expected {w}"
               for (k, g), w in zip(jax.tree_util.tree_leaves_with_path(got, is_leaf=lambda x: isinstance(x, tuple)),
                                    jax.tree.leaves(want, is_leaf=lambda x: isinstance(x, tuple))) if g != w]
        raise CheckpointError(
            f"Could not restore {path}: the checkpoint is corrupt or was saved with a different network/env "
            f"configuration ({'; '.join(bad[:3])}{' …' if len(bad) > 3 else ''}); re-create it or match the "
            "configuration."
        )
    return tree, meta


# ------------------------------------------------------------------------------------------------------------------
# Pretrained bundles: an OfflineState (leading seed axis) + metadata, for finetune-only runs

BUNDLE_KIND = "pretrained-bundle"


def save_bundle(path: str | os.PathLike, state: Any, metadata: dict[str, Any]) -> None:
    """Save a pretrained bundle (actor, critics, target critics, value, optimizer states for every seed) with the
    content checksum of its arrays (``content_sha256``), which :func:`load_bundle` verifies."""
    required = ("algo", "env", "obs_size", "act_size", "net", "seeds", "steps", "hparams")
    missing = [k for k in required if k not in metadata]
    if missing:
        raise ValueError(f"Bundle metadata lacks {missing}.")
    save(path, state, {**metadata, "kind": BUNDLE_KIND, "content_sha256": tree_content_hash(_drop_empty(state))})


def rebuild_command(path: str | os.PathLike, meta: dict[str, Any]) -> str:
    """The command that makes the bundle at ``path`` again (from its metadata)."""
    hidden = " ".join(str(h) for h in (meta.get("net") or {}).get("hidden", ()))
    seeds = " ".join(str(s) for s in meta.get("seeds", ()))
    hp = ""
    try:  # the offline hyper-parameters that differ from the algorithm's defaults
        from proto_brax.agents.insample import OfflineHParams
        from proto_brax.agents.registry import PRETRAIN_HP

        default = {k: float(v) for k, v in dataclasses.asdict(
            OfflineHParams.create(**PRETRAIN_HP.get(meta.get("algo"), {}))).items()}
        pairs = [f"{k} {v:.6g}" for k, v in sorted((meta.get("hparams") or {}).items())
                 if k in default and not np.isclose(v, default[k], rtol=1e-6)]
        hp = f" --hp {' '.join(pairs)}" if pairs else ""  # one --hp: a repeated --hp replaces the earlier one
    except Exception:  # (a message helper: never fail because of it)
        pass
    policy = (meta.get("net") or {}).get("policy", "tanh_gaussian")
    policy = "" if policy == "tanh_gaussian" else f" --policy {policy}"
    return (f"python -m proto_brax.pretrain --dataset {meta.get('dataset', 'DATASET')} --algo {meta.get('algo')} "
            f"--seeds {seeds} --steps {meta.get('steps')} --hidden {hidden}{policy}{hp} --out {path} --overwrite")


def bundle_net(meta: dict[str, Any]):
    """The bundle's NetworkConfig, from its metadata (JSON keeps ``hidden`` as a list)."""
    from proto_brax.networks import NetworkConfig

    return NetworkConfig(**{**meta["net"], "hidden": tuple(meta["net"]["hidden"])})


def bundle_template(meta: dict[str, Any]):
    """An OfflineState of the bundle's shapes (leading seed axis), built from its metadata alone."""
    from proto_brax.agents.insample import OfflineHParams, init_offline_state
    from proto_brax.networks import make_networks

    nets = make_networks(bundle_net(meta), meta["act_size"])
    hp = OfflineHParams.create(**{k: v for k, v in meta["hparams"].items() if k in OfflineHParams.__dataclass_fields__})
    keys = jax.random.split(jax.random.PRNGKey(0), len(meta["seeds"]))
    from proto_brax.agents.registry import TEMPERATURE_ALGOS, VALUE_ALGOS

    init = lambda k: init_offline_state(k, nets, meta["obs_size"], meta["act_size"], hp,  # noqa: E731
                                        with_value=meta["algo"] in VALUE_ALGOS,
                                        with_temperature=meta["algo"] in TEMPERATURE_ALGOS)
    return jax.eval_shape(jax.vmap(init), keys)


def load_bundle(path: str | os.PathLike, legacy_note: bool = True) -> tuple[Any, dict[str, Any]]:
    """Restore a bundle and verify its content checksum; a missing, corrupt or non-bundle directory raises
    CheckpointError naming the problem (and, for a corrupt bundle, the command that rebuilds it).

    A bundle saved before checksums existed (no ``content_sha256``) is accepted when its arrays are finite, with a
    note naming ``python -m proto_brax.checkpoints checksum PATH``, which adds the checksum."""
    meta = read_metadata(path)
    if meta.get("kind") != BUNDLE_KIND:
        raise CheckpointError(f"{path} is not a pretrained bundle (kind {meta.get('kind')!r}); "
                              "create one with `python -m proto_brax.pretrain`.")
    template = bundle_template(meta)
    try:
        state, meta = restore(path, template)
    except CheckpointError as e:
        raise CheckpointError(f"{e} Rebuild the bundle: {rebuild_command(path, meta)}") from e
    want = meta.get("content_sha256")
    if want is not None:
        got = tree_content_hash(state)
        if got != want:
            raise CheckpointError(f"Bundle {path} is corrupt: the checksum of its arrays is {got[:16]}…, its "
                                  f"metadata.json records {want[:16]}…. Rebuild it: {rebuild_command(path, meta)}")
    else:
        bad = sum(int(np.size(x) - np.count_nonzero(np.isfinite(x))) for x in jax.tree.leaves(state)
                  if np.issubdtype(np.asarray(x).dtype, np.floating))
        if bad:
            raise CheckpointError(f"Bundle {path} is corrupt: {bad} non-finite values in its arrays. Rebuild it: "
                                  f"{rebuild_command(path, meta)}")
        if legacy_note:
            print(f"note: bundle {path} has no content checksum (saved by an older version): add one with `python -m "
                  f"proto_brax.checkpoints checksum {path}`", flush=True)
    return state, meta


def add_checksum(path: str | os.PathLike) -> str:
    """Record the content checksum of a bundle saved before checksums existed (its arrays must restore and be
    finite); returns it. A bundle that has one is verified instead."""
    meta = read_metadata(path)
    if meta.get("content_sha256") is not None:
        load_bundle(path)  # verifies it
        return meta["content_sha256"]
    state, _ = load_bundle(path, legacy_note=False)
    meta["content_sha256"] = tree_content_hash(state)
    write_json_atomic(Path(path) / "metadata.json", meta)
    return meta["content_sha256"]


def validate_bundle(meta: dict[str, Any], env: str, obs_size: int, act_size: int, net) -> None:
    """Fail with a message naming the mismatch between a bundle and the finetuning configuration."""
    if meta.get("kind") != BUNDLE_KIND:
        raise CheckpointError(f"Not a pretrained bundle (kind {meta.get('kind')!r}): create one with "
                              "`python -m proto_brax.pretrain`.")
    problems = []
    if meta["env"] != env:
        problems.append(f"env {meta['env']!r} (finetune: {env!r})")
    if (meta["obs_size"], meta["act_size"]) != (obs_size, act_size):
        problems.append(f"observation/action sizes {meta['obs_size']}/{meta['act_size']} (env: {obs_size}/{act_size})")
    bnet = meta["net"]
    if tuple(bnet["hidden"]) != tuple(net.hidden):
        problems.append(f"hidden sizes {tuple(bnet['hidden'])} (finetune: {tuple(net.hidden)}; pass --hidden)")
    for k in ("critic_layer_norm", "actor_layer_norm", "num_qs"):
        if bnet[k] != getattr(net, k):
            problems.append(f"{k} {bnet[k]} (finetune: {getattr(net, k)})")
    if bnet.get("policy", "tanh_gaussian") != net.policy:  # bundles made before the switch hold tanh-Gaussians
        problems.append(f"policy {bnet.get('policy', 'tanh_gaussian')} (finetune: {net.policy}; pass --policy "
                        f"{bnet.get('policy', 'tanh_gaussian')})")
    if problems:
        raise CheckpointError("The checkpoint does not match the finetuning configuration: " + "; ".join(problems))


def dataset_label(name_or_path: str) -> str:
    """A dataset's name as a bundle records it: a registered name, or a file's stem."""
    return Path(name_or_path).stem if Path(name_or_path).suffix else name_or_path


def validate_bundle_dataset(meta: dict[str, Any], dataset: str, content_hash: str | None = None) -> None:
    """Refuse to finetune a bundle with another dataset in the buffer than it was pretrained on, naming the fix.

    The same rows under another name (e.g. a Minari export of the bundle's dataset) are the same dataset: with the
    loaded data's ``content_hash`` equal to the one the bundle was pretrained on, the names need not match."""
    ours, theirs = dataset_label(dataset), meta.get("dataset")
    if content_hash is not None and content_hash == meta.get("dataset_content_hash"):
        return
    if theirs is not None and theirs != ours:
        raise CheckpointError(f"The checkpoint was pretrained on dataset {theirs!r}, the finetune reads {ours!r}: pass "
                              f"--dataset {theirs}, or a bundle of {ours} (python -m proto_brax.pretrain --dataset "
                              f"{ours} ...).")


def bundle_dataset_record(meta: dict[str, Any], dataset_meta: dict[str, Any] | None) -> dict[str, Any]:
    """Whether the finetune's dataset holds the very rows the bundle was pretrained on (content hashes), for the
    sweep's config.json (``dataset_vs_bundle``) and RESULTS.md's *buffer data* column; a difference is announced
    (:func:`regenerated_note`), not refused. ``same_content`` is None when either hash is unknown.

    The same registered dataset can hold other rows when it was regenerated under other XLA threading
    (``datasets.generation_xla_flags``: on hopper and walker2d, whose episodes end on falls, the rounding changes the
    episodes): the buffer then holds other episodes of the same generator and behaviour policies."""
    want, have = meta.get("dataset_content_hash"), (dataset_meta or {}).get("content_hash")
    return {"dataset": meta.get("dataset"), "bundle_content_hash": want, "content_hash": have,
            "same_content": None if want is None or have is None else want == have}


def regenerated_note(record: dict[str, Any]) -> str | None:
    """The line a sweep prints when its dataset is a regenerated copy of its bundle's (else None)."""
    if record["same_content"] is not False:
        return None
    return (f"note: the bundle was pretrained on {record['dataset']} with content "
            f"{record['bundle_content_hash'][:12]}…, the cached dataset holds {record['content_hash'][:12]}… "
            "(regenerated): other episodes of the same generator; recorded as dataset_vs_bundle in config.json.")


def find_bundles(root: Path) -> list[Path]:
    return sorted(p.parent for p in Path(root).rglob("metadata.json")
                  if json.loads(p.read_text()).get("kind") == BUNDLE_KIND)
