"""``python -m proto_brax.datasets``: make, export, inspect and list the registered datasets
(``proto_brax.data.cache``).

    python -m proto_brax.datasets list
    python -m proto_brax.datasets make hopper-medium [--size N] [--seed S]
    python -m proto_brax.datasets info hopper-medium
    python -m proto_brax.datasets export hopper-medium --minari [--id proto_brax/hopper/medium-v0] [--out DIR]
    python -m proto_brax.datasets collect hopper-v5 --policy medium --steps 100000 --id local/hopper-v5/medium-v0
    python -m proto_brax.datasets references hopper
    python -m proto_brax.datasets measure ant            # behaviour-policy returns of every snapshot (picks medium)
"""

from __future__ import annotations

import dataclasses
import os
import time
from pathlib import Path

import numpy as np
import tyro

from proto_brax.data.cache import (
    cached_metadata,
    dataset_path,
    generation_numerics_pinned,
    generation_xla_flags,
    load_dataset,
    make_dataset,
    partial_path,
    rebuild_command,
    reference_returns,
    stale_reason,
)


@dataclasses.dataclass
class Make:
    """Generate a dataset into the cache (atomic write). An interrupted AntMaze build resumes where it stopped when
    the same command is run again (its progress is kept beside the dataset file, ``.NAME.npz.partial``)."""

    name: tyro.conf.Positional[str]
    size: int | None = None
    """Transitions (default: 10⁶; medium-expert is twice that)."""
    seed: int = 0
    num_envs: int = 100
    """Envs rolled out side by side."""
    cache_dir: Path | None = None
    """Default: $PROTO_BRAX_DATASETS or ~/.cache/proto_brax/datasets."""
    force: bool = False
    """Rebuild even if cached."""


@dataclasses.dataclass
class Export:
    """Write a dataset as a local Minari dataset with minari's own writer (``proto_brax.data.minari_io``): episodes,
    reference scores, the content hash and the generation metadata, readable back bit-for-bit (``--dataset ID``)."""

    name: tyro.conf.Positional[str]
    """A registered dataset (built into the cache first if missing) or a dataset file (.npz, D4RL .hdf5)."""
    minari: bool = False
    """Export to the Minari format (the one export format; required)."""
    id: str | None = None
    """Minari dataset id, [NAMESPACE/]NAME-vVERSION (default: proto_brax/ENV/KIND-v0 for a registered dataset)."""
    out: Path | None = None
    """Minari datasets root to write under (default: $MINARI_DATASETS_PATH or ~/.minari/datasets)."""
    size: int | None = None
    seed: int = 0
    cache_dir: Path | None = None
    force: bool = False
    """Replace an existing dataset of that id, only if this command wrote it."""


@dataclasses.dataclass
class Collect:
    """Record a Minari dataset on Gymnasium's native v5 env with minari's DataCollector, the way Farama recorded
    mujoco/* (``proto_brax.data.minari_collect``): a behaviour policy of ours, D4RL's references as
    ref_min_score / ref_max_score, the suite's content hash. Load it with --dataset ID --env ENV."""

    env: tyro.conf.Positional[str]
    """A Gymnasium v5 env: hopper-v5, walker2d-v5, halfcheetah-v5, ant-v5."""
    id: str
    """Minari dataset id to write, [NAMESPACE/]NAME-vVERSION (never replaced)."""
    policy: str = "medium"
    """random, medium, expert (the registered datasets' rule over checkpoints/behavior/ENV) or a snapshot step."""
    steps: int = 100_000
    """Transitions (the last episode is cut there, as a truncation)."""
    seed: int = 0
    out: Path | None = None
    """Minari datasets root to write under (default: $MINARI_DATASETS_PATH or ~/.minari/datasets)."""
    behavior_root: Path | None = None
    """Default: checkpoints/behavior."""


@dataclasses.dataclass
class Info:
    """Print a cached dataset's metadata and episode-return statistics."""

    name: tyro.conf.Positional[str]
    size: int | None = None
    seed: int = 0
    cache_dir: Path | None = None


@dataclasses.dataclass
class List:
    """List every dataset name, its size and whether it is cached."""

    cache_dir: Path | None = None


@dataclasses.dataclass
class Measure:
    """Measure every behaviour snapshot's stochastic-policy return (the policy that generates the data) and record
    it as ``behavior_return`` in the snapshot's metadata.json; medium is then chosen by it."""

    env: tyro.conf.Positional[str]
    episodes: int = 100
    seed: int = 0
    behavior_root: Path | None = None
    """Default: checkpoints/behavior."""


@dataclasses.dataclass
class References:
    """Measure an env's normalized-score references: uniform policy and deterministic expert snapshot."""

    env: tyro.conf.Positional[str]
    episodes: int = 100
    seed: int = 0


def cmd_measure(a: Measure) -> list[dict]:
    from proto_brax import envs
    from proto_brax.data import generate as g
    from proto_brax.files import write_json_atomic

    spec = envs.get_spec(a.env)
    out = []
    for snap, ret in g.behavior_returns(a.env, g.list_snapshots(a.env, a.behavior_root), a.episodes, a.seed):
        rec = {"mean": float(ret.mean()), "std": float(ret.std()), "episodes": a.episodes, "seed": a.seed,
               "policy": "stochastic (tanh-Gaussian samples), as in the datasets"}
        write_json_atomic(snap.path / "metadata.json", {**snap.metadata, "behavior_return": rec})
        score = float(envs.normalized_score(a.env, rec["mean"]))
        print(f"{a.env} step {snap.step}: eval {snap.eval_return:.1f}, behaviour return {rec['mean']:.1f} ± "
              f"{rec['std']:.1f} (normalized {score:.1f}) over {a.episodes} episodes", flush=True)
        out.append({"step": snap.step, **rec, "normalized": score})
    _, medium = g.pick_expert_medium(g.list_snapshots(a.env, a.behavior_root), reference_returns(spec))
    print(f"{a.env}: medium is now the snapshot at step {medium.step}")
    return out


def cmd_make(a: Make) -> Path:
    from proto_brax import envs
    from proto_brax.data.dataset import save_npz
    from proto_brax.data.partial import discard

    path = dataset_path(a.name, a.size, a.seed, a.cache_dir)
    if path.is_symlink() or (path.exists() and not path.is_file()):  # --force replaces only a dataset file
        raise FileExistsError(f"{path} is not a dataset file (a directory or a link): refusing to replace it"
                              f"{' even with --force' if a.force else ''}; move it away or pass another --cache-dir.")
    if path.exists() and not a.force:
        print(f"{a.name}: already cached at {path} (use --force to rebuild)")
        return path
    t0 = time.time()
    parts = {}  # medium-expert: cached medium / expert parts (make_dataset generates the missing ones, identically)
    if a.name.endswith("-medium-expert"):
        from proto_brax.data.dataset import load_npz

        for sub in ("medium", "expert"):
            sub_path = dataset_path(a.name.replace("medium-expert", sub), a.size, a.seed, a.cache_dir)
            try:  # a corrupt or stale part is generated again (identically) rather than reused
                if sub_path.exists() and not stale_reason((part := load_npz(sub_path))[1]):
                    parts[sub] = part
            except ValueError as e:  # CorruptDatasetError, non-finite values
                print(f"not reusing {sub_path}: {e}", flush=True)
    if not generation_numerics_pinned():
        print(f"warning: {a.name} is generated under multi-threaded XLA, whose rounding differs (other episodes, "
              "another content hash): `python -m proto_brax.datasets make` pins one thread.", flush=True)
    partial = partial_path(path)
    data, meta = make_dataset(a.name, a.size, a.seed, a.num_envs, parts=parts, checkpoint=partial)
    meta["seconds"] = time.time() - t0  # of this process: a resumed build counts only its own part
    meta["xla_flags"] = os.environ.get("XLA_FLAGS", "")  # provenance: the numerics it was generated under,
    meta["cpu"] = envs.host_cpu()  # and the CPU XLA compiled them for (another CPU rounds differently)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_npz(path, data, meta)
    discard(partial)
    r = meta["returns"]
    print(f"{a.name}: {meta['size']} transitions, {r['num_episodes']} episodes, return mean {r['mean']:.1f} "
          f"(min {r['min']:.1f}, max {r['max']:.1f}) in {meta['seconds']:.0f} s -> {path}")
    return path


_CACHE_FILE_RE = r"(.+?)(?:-n(\d+)-seed(\d+))?\.npz"  # NAME.npz or NAME-nSIZE-seedS.npz (dataset_path)


def cmd_export(a: Export) -> Path:
    """``export NAME --minari``: the written dataset is read back with the suite's reader and must give the same
    content hash (else the export is removed and an error raised)."""
    import re

    from proto_brax.data import minari_io
    from proto_brax.data.dataset import CorruptDatasetError, content_hash, load_minari
    from proto_brax.data.generate import dataset_names

    if not a.minari:
        raise ValueError("export writes the Minari format only: pass --minari.")
    if a.id is not None:
        minari_io.check_id(a.id)  # before anything is built or read
    if a.name in dataset_names():
        if not dataset_path(a.name, a.size, a.seed, a.cache_dir).exists():
            print(f"{a.name} is not cached: building it first", flush=True)
            cmd_make(Make(a.name, size=a.size, seed=a.seed, cache_dir=a.cache_dir))
        data, meta = load_dataset(a.name, a.size, a.seed, a.cache_dir)
        dataset_id = a.id or minari_io.default_id(a.name, a.size, a.seed)
    else:
        data, meta = load_dataset(a.name)  # a file (or an error naming the problem)
        m = re.fullmatch(_CACHE_FILE_RE, Path(a.name).name)
        if a.id is None and (m is None or m.group(1) not in dataset_names()):
            raise ValueError(f"{a.name} is not a registered dataset's cache file: pass --id NAMESPACE/NAME-v0 "
                             "(a Minari dataset id) to export it.")
        dataset_id = a.id or minari_io.default_id(m.group(1), int(m.group(2)) if m.group(2) else None,
                                                   int(m.group(3) or 0))
    command = " ".join(["python -m proto_brax.datasets export", a.name, "--minari", "--id", dataset_id,
                        *(["--size", str(a.size)] if a.size else []), *(["--seed", str(a.seed)] if a.seed else []),
                        *(["--cache-dir", str(a.cache_dir)] if a.cache_dir else []),
                        *(["--out", str(a.out)] if a.out else []), "--force"])
    expected = content_hash(data)
    path = minari_io.export_minari(data, meta, dataset_id, root=a.out, force=a.force, source=a.name,
                                   command=command)
    try:
        back, bmeta = load_minari(path)
    except Exception:
        minari_io.remove_export(path)
        raise
    if content_hash(back) != expected:  # load_minari checks against the recorded hash; this checks the source too
        minari_io.remove_export(path)
        raise CorruptDatasetError(f"the Minari export of {a.name} read back with content hash {content_hash(back)}, "
                                  f"not {expected}: removed it.")
    root = path.parents[len(Path(dataset_id).parts) - 1]
    print(f"{a.name}: {bmeta['total_steps']} transitions, {bmeta['total_episodes']} episodes -> Minari dataset "
          f"{dataset_id} at {path}; read back bit-for-bit (content hash {expected}). Load it with --dataset {path}, "
          f"or --dataset {dataset_id} with MINARI_DATASETS_PATH={root}.")
    return path


def cmd_collect(a: Collect) -> Path:
    from tqdm import tqdm

    from proto_brax.data import minari_collect

    command = " ".join(["python -m proto_brax.datasets collect", a.env, "--id", a.id, "--policy", a.policy,
                        "--steps", str(a.steps), *(["--seed", str(a.seed)] if a.seed else []),
                        *(["--out", str(a.out)] if a.out else [])])
    with tqdm(total=a.steps, desc=f"collect {a.env}", unit="step", mininterval=5) as bar:
        path = minari_collect.collect(a.env, a.id, a.steps, a.policy, a.seed, a.out, a.behavior_root, command, bar)
    s = minari_collect.summary(path)
    print(f"{a.id}: {s['transitions']} transitions, {s['episodes']} episodes on Gymnasium's {a.env}, episode return "
          f"mean {s['return_mean']:.1f} (normalized {s['normalized']:.1f}), content hash {s['content_hash']} -> "
          f"{path}. Pretrain on it with --dataset {path} --env {a.env}.")
    return path


def cmd_info(a: Info) -> dict:
    from proto_brax import envs
    from proto_brax.data.generate import dataset_names

    path = dataset_path(a.name, a.size, a.seed, a.cache_dir) if a.name in dataset_names() else None
    hint = rebuild_command(a.name, a.size, a.seed) if path is not None else None
    if path is not None and path.exists() and (why := stale_reason(meta := cached_metadata(path, hint))):
        print(f"{a.name}: STALE ({why}): {rebuild_command(a.name, a.size, a.seed)}")  # still show what it holds
    else:
        _, meta = load_dataset(a.name, a.size, a.seed, a.cache_dir)  # verifies the file; names the fix if absent
    r = meta["returns"]
    print(f"{a.name}: {meta['size']} transitions from {meta['kind']} behaviour on {meta['env']} ({meta['backend']})")
    if "stats" in meta:  # AntMaze: terminals mark the goal inside runs, so "episode returns" mean nothing there
        st = meta["stats"]
        print(f"  runs {st['episodes']}, reaching the evaluation goal {100 * st['success_rate']:.1f}%, cut short "
              f"(upside down) {100 * st['cut_short']:.1f}%, rewarded transitions {100 * st['reward_rate']:.2f}%")
    else:
        print(f"  episodes {r['num_episodes']}, return mean {r['mean']:.1f} min {r['min']:.1f} max {r['max']:.1f}, "
              f"normalized score of the mean {float(envs.normalized_score(meta['env'], r['mean'])):.1f}")
    for k in ("seed", "num_envs", "expert_snapshot", "medium_snapshot", "behavior", "controller", "cells",
              "content_hash", "version"):
        if k in meta:
            print(f"  {k}: {meta[k]}")
    return meta


def cmd_list(a: List) -> None:
    from proto_brax.data.generate import dataset_names, default_size, parse_name

    for name in dataset_names():
        env, kind = parse_name(name)
        size = default_size(env, kind) * (2 if kind == "medium-expert" else 1)
        path = dataset_path(name, None, 0, a.cache_dir)
        state = "-"
        if path.exists():
            try:
                why = stale_reason(cached_metadata(path))
                state = f"stale ({why}): {rebuild_command(name, None, 0)}" if why else "cached"
            except ValueError:  # CorruptDatasetError
                state = f"corrupt: {rebuild_command(name, None, 0)}"
        print(f"{name:28s} {size:>9d}  {state}")


def cmd_references(a: References) -> dict:
    import jax

    from proto_brax import envs
    from proto_brax.data import generate as g
    from proto_brax.train.evaluate import run_episodes

    spec = envs.get_spec(a.env)
    env = envs.make_env(a.env)
    expert, _ = g.pick_expert_medium(g.list_snapshots(a.env))  # the expert is the final snapshot either way
    mean, params = g.snapshot_policy(expert, env, sampled=False)
    det = lambda obs, k: mean(params, obs, k)  # noqa: E731
    out = {}
    for label, pol in (("random", g.uniform_policy(env.action_size)), ("expert", det)):
        episodes = jax.jit(lambda k, pol=pol: run_episodes(env, spec.episode_length, pol, k, a.episodes))
        ret = episodes(jax.random.PRNGKey(a.seed))
        ret = np.asarray(ret)
        out[label] = {"mean": float(ret.mean()), "std": float(ret.std()), "episodes": a.episodes}
        print(f"{a.env} {label}: mean {ret.mean():.2f} ± {ret.std():.2f} over {a.episodes} episodes"
              + (f" (expert snapshot step {expert.step})" if label == "expert" else ""))
    return out


def main(argv: list[str] | None = None) -> None:
    from proto_brax.data.generate import dataset_names, parse_name

    cmd = tyro.extras.subcommand_cli_from_dict(
        {"make": Make, "export": Export, "collect": Collect, "info": Info, "list": List, "references": References,
         "measure": Measure},
        args=argv,
    )
    # Before JAX starts: the pinned generation numerics (export builds a registered dataset that is not cached).
    if isinstance(cmd, (Make, Export)) and cmd.name in dataset_names():
        from proto_brax import envs

        mjx = envs.get_spec(parse_name(cmd.name)[0]).default_backend == "mjx"  # AntMaze, Adroit
        os.environ["XLA_FLAGS"] = generation_xla_flags(mjx=mjx)
    from proto_brax.startup import exit_on_input_error

    run = {Make: cmd_make, Export: cmd_export, Collect: cmd_collect, Info: cmd_info, List: cmd_list,
           References: cmd_references, Measure: cmd_measure}[type(cmd)]
    exit_on_input_error(lambda: run(cmd), argv)


if __name__ == "__main__":
    from proto_brax.startup import quiet_start

    quiet_start()
    main()
