"""A sweep's output directory: what it may hold, when --resume and --overwrite may use it (nothing a user owns
is ever deleted), and its metrics file (appends of whole chunks, truncation to the checkpointed ones)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from proto_brax.experiment.args import SweepArgs, sweep_record, with_later_defaults
from proto_brax.files import (
    LOCK_NAME,
    append_once,
    lock_dir,
    read_jsonl,
    strict_json,
    write_json_atomic,
    write_text_atomic,
)

# What a sweep writes into --out (and nothing else): only a directory holding these is replaced by --overwrite.
SWEEP_ENTRIES = frozenset({"config.json", "metrics.jsonl", "summary.json", "state", "report", "tensorboard",
                           "pretrained"})
CHOOSE_OUT = "choose another --out"


def _our_temporary(name: str) -> bool:
    """Hidden temporaries of our atomic writes (``.NAME.XXXX.tmp``) and checkpoint saves (``.NAME.tmp-PID``), and
    the writer's lock (``files.lock_dir``)."""
    return name == LOCK_NAME or name.startswith(".") and (name.endswith(".tmp") or ".tmp-" in name
                                                          or ".old-" in name)


def _read_config(out: Path) -> dict | None:
    """``out/config.json`` when it is a sweep's (a JSON object with its ``sweep`` and ``finetune`` records)."""
    try:
        config = json.loads((out / "config.json").read_text())
    except (OSError, ValueError):
        return None
    return config if isinstance(config, dict) and {"sweep", "finetune"} <= set(config) else None


def not_a_sweep(out: Path) -> str | None:
    """Why the existing, non-empty directory ``out`` is not a sweep's output (then --overwrite must not delete it),
    or None when it is one: a sweep's config.json and nothing but what a sweep writes."""
    names = sorted(p.name for p in out.iterdir())
    foreign = [n for n in names if n not in SWEEP_ENTRIES and not _our_temporary(n)]
    shown = ", ".join(foreign[:5] + (["…"] if len(foreign) > 5 else []))
    if foreign:
        return f"it holds {shown}, which a sweep does not write"
    if all(_our_temporary(n) for n in names):
        return None  # a sweep killed before its config.json was complete
    if not (out / "config.json").exists():
        return "it has no config.json"
    if _read_config(out) is None:
        return "its config.json is not a sweep's"
    return None


def layout_record(grid_size: int, devices: list, block: str = "vmap") -> dict:
    """How the grid is laid out over devices and how each device runs its runs (``grid.run_batched``; recorded when
    not the default vmap): the numbers of a run depend on both (docs/RELIABILITY.md)."""
    n = len(devices)
    padded = -(-grid_size // n) * n
    return {"devices": n, "platform": devices[0].platform, "runs_per_device": padded // n,
            "padding": padded - grid_size, **({"block": block} if block != "vmap" else {})}


def check_out(args: SweepArgs, sweep_cfg: dict, layout: dict | None = None) -> None:
    """Refuse an existing --out unless --resume (same configuration and layout) or --overwrite of a sweep's own
    output; writes nothing (an --overwrite removes the old sweep later, after every check has passed)."""
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"--out {out} is a file, not a directory: choose another --out.")
    if out.exists() and any(out.iterdir()):
        if args.resume:
            old = _read_config(out)
            if old is None:
                raise ValueError(f"--resume: {out} holds no sweep to resume (no readable config.json of a sweep).")
            recorded = with_later_defaults(old["sweep"], sweep_record(SweepArgs()))
            if recorded != sweep_cfg:
                diff = {k: (recorded.get(k), v) for k, v in sweep_cfg.items() if recorded.get(k) != v}
                raise ValueError(f"--resume: the configuration differs from the one in {out}: {diff}.")
            was = old.get("layout")
            if layout is not None and was is not None and was != layout:
                block, now = was.get("block", "vmap"), layout.get("block", "vmap")  # recorded when not vmap
                flag = (f"--devices {was['devices']}" if was.get("platform") == "cpu"
                        else f"{was['devices']} {was.get('platform')} device(s)")
                raise ValueError(f"--resume: {out} ran on {was['devices']} {was.get('platform')} device(s) "
                                 f"({was['runs_per_device']} run(s) each, block {block}), this process has "
                                 f"{layout['devices']} ({layout['runs_per_device']} each, block {now}), which gives "
                                 f"other numbers: resume with {flag} --block {block}.")
        elif not args.overwrite:
            raise FileExistsError(f"{out} exists: pass --resume to continue it, --overwrite to replace it, "
                                  "or choose another --out.")
        elif why := not_a_sweep(out):
            raise FileExistsError(f"--overwrite: {out} is not a sweep's output ({why}): refusing to delete it; "
                                  "choose another --out.")
    elif args.resume:
        raise FileNotFoundError(f"--resume: nothing to resume in {out}.")


def prepare_out(args: SweepArgs, config: dict) -> None:
    """Take --out's lock (one process writes a sweep: ``files.lock_dir``), create it (replacing an old sweep with
    --overwrite) and write config.json: called once every check of the run has passed, so a refused run leaves an
    old sweep as it was."""
    out = Path(args.out)
    replacing = not args.resume and out.exists() and args.overwrite and any(out.iterdir())
    if args.resume or replacing:
        lock_dir(out, CHOOSE_OUT)  # before anything in it is read again or deleted
    if args.resume:
        return
    if replacing:
        if why := not_a_sweep(out):  # (checked before; the directory may have changed since)
            raise FileExistsError(f"--overwrite: {out} is not a sweep's output ({why}): refusing to delete it.")
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)
    lock_dir(out, CHOOSE_OUT)
    write_json_atomic(out / "config.json", strict_json(config))


def truncate_metrics(path: Path, chunks_done: int, runs: int | None = None) -> None:
    """Keep the rows of the checkpointed chunks (those before ``chunks_done``, and π₀'s): rows logged after the last
    checkpoint (a crash between the two) and a torn last line (a crash inside an append) are dropped; their chunks
    are re-run from the checkpoint. With ``runs``, every kept chunk must hold that many rows."""
    if not path.exists():
        return
    rows, torn = read_jsonl(path)
    keep = [r for r in rows if r["chunk"] < chunks_done]
    if torn:
        print(f"{path}: dropped a torn last line (a crash during an append); its chunk is re-run", flush=True)
    if runs is not None and chunks_done > 0:
        counts = {c: 0 for c in range(-1, chunks_done)}
        for r in keep:
            counts[r["chunk"]] = counts.get(r["chunk"], 0) + 1
        short = {c: n for c, n in counts.items() if n != runs}
        if short:
            raise ValueError(f"--resume: {path} lacks rows of checkpointed chunks ({short} rows, {runs} expected per "
                             "chunk): the file was damaged; rerun the sweep with --overwrite.")
    write_text_atomic(path, "".join(json.dumps(strict_json(r), allow_nan=False) + "\n" for r in keep))


def append_rows(path: Path, rows: list[dict]) -> None:
    """One chunk's rows as strict JSON lines (NaN -> null), appended in one write: a kill leaves all or none."""
    append_once(path, "".join(json.dumps(strict_json(r), allow_nan=False) + "\n" for r in rows))
