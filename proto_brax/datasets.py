"""``python -m proto_brax.datasets``: D4RL-style offline datasets, generated reproducibly from committed behaviour
policies.

Kinds (per env, D4RL's definitions adapted to the suite's own SAC runs, ``checkpoints/behavior/<env>/``):

* ``random``: uniform random actions in [-1, 1];
* ``expert``: the final behaviour snapshot, actions sampled from its tanh-Gaussian (stochastic, as D4RL);
* ``medium``: the snapshot whose evaluation return is closest to a third of the expert's, stochastic;
* ``medium-replay``: the policies an agent went through up to medium: the uniform policy (the replay buffer's warm-up)
  then every snapshot up to and including medium, each contributing an equal share of the transitions (stochastic);
* ``medium-expert``: the ``medium`` dataset followed by the ``expert`` dataset, exactly (twice the size; built from
  the cached parts when they exist, else by generating both).

Each dataset is ``size`` transitions from ``num_envs`` envs run side by side (episodes stay contiguous per env); time
limits are ``timeouts``, true terminations ``terminals``. Same name, size and seed ⇒ identical arrays (checked by the
content hash in the metadata), given the same XLA threading and CPU: ``make`` generates with one XLA thread
(``generation_xla_flags``), since multi-threaded rounding gives hopper and walker2d other episodes, and records the
CPU (``envs.host_cpu``): XLA compiles for the host CPU, and another CPU can build other episodes (an AVX-512 machine
did, against two earlier AVX2 machines that agreed).

    python -m proto_brax.datasets list
    python -m proto_brax.datasets make hopper-medium [--size N] [--seed S]
    python -m proto_brax.datasets info hopper-medium
    python -m proto_brax.datasets export hopper-medium --minari [--id proto_brax/hopper/medium-v0] [--out DIR]
    python -m proto_brax.datasets references hopper
    python -m proto_brax.datasets measure ant            # behaviour-policy returns of every snapshot (picks medium)
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from pathlib import Path

import numpy as np
import tyro

ENV_VAR = "PROTO_BRAX_DATASETS"


MEDIUM_RULE = "closest to R_random + (R_expert - R_random) / 3 (registered references)"


def reference_returns(spec) -> tuple[float, float] | None:
    """(R_random, R_expert) registered for the env, None where it has none (medium then falls back to expert / 3)."""
    return None if spec.ref_random is None or spec.ref_expert is None else (spec.ref_random, spec.ref_expert)


def current_snapshots(env_name: str, behavior_root: Path | None = None) -> dict[str, int]:
    """Steps of the behaviour snapshots the current rule picks for ``env_name``: {"expert": …, "medium": …}."""
    from proto_brax import envs
    from proto_brax.data import generate as g

    expert, medium = g.pick_expert_medium(g.list_snapshots(env_name, behavior_root),
                                          reference_returns(envs.get_spec(env_name)))
    return {"expert": expert.step, "medium": medium.step}


def cached_metadata(path: Path, rebuild_hint: str | None = None) -> dict:
    """The metadata entry of a cached dataset file, read without loading (or hashing) its arrays; a file that cannot
    be read (truncated, garbled) raises CorruptDatasetError naming ``rebuild_hint`` (default: the ``make`` command
    of the name the file is cached under)."""
    import zipfile

    from proto_brax.data.dataset import CorruptDatasetError

    try:
        with np.load(path, allow_pickle=False) as npz:
            meta = json.loads(str(npz["metadata"][()]))
        if not isinstance(meta, dict):
            raise ValueError("the metadata entry is not a JSON object")
        return meta
    except (OSError, EOFError, ValueError, KeyError, TypeError, zipfile.BadZipFile, UnicodeDecodeError) as e:
        hint = rebuild_hint or _rebuild_hint_for(Path(path))
        how = f"rebuild it with: {hint}" if hint else "delete it and rebuild it with the command that created it"
        raise CorruptDatasetError(f"dataset file {str(path)!r} is corrupt or unreadable ({type(e).__name__}: {e}); "
                                  f"{how}") from e


def _rebuild_hint_for(path: Path) -> str | None:
    """The ``make … --force`` command of a cache file's name (NAME.npz or NAME-nSIZE-seedS.npz), None if not one."""
    import re

    from proto_brax.data.generate import dataset_names

    m = re.fullmatch(r"(.+?)(?:-n(\d+)-seed(\d+))?\.npz", path.name)
    if m is None or m.group(1) not in dataset_names():
        return None
    return rebuild_command(m.group(1), int(m.group(2)) if m.group(2) else None, int(m.group(3) or 0))


def stale_reason(meta: dict, behavior_root: Path | None = None) -> str | None:
    """Why a cached dataset no longer matches what ``make`` would generate now (a snapshot its kind is made from —
    medium for medium and medium-replay, expert for expert and cloned, both for medium-expert — is not the one the
    current rule picks: new snapshots, or a changed rule; AntMaze: its controller is not the last ant-goal snapshot),
    or None when it is current."""
    if "controller" in meta:  # AntMaze: made with the ant-goal controller's last snapshot of the time
        from proto_brax.data import generate as g

        last = g.list_snapshots(meta["controller"]["env"], behavior_root)[-1].step
        had = meta["controller"]["step"]
        return None if had == last else (f"it was generated with the {meta['controller']['env']} controller at step "
                                         f"{had}, the last snapshot is step {last}")
    uses = {"medium": ("medium",), "medium-replay": ("medium",), "expert": ("expert",), "cloned": ("expert",),
            "medium-expert": ("medium", "expert")}.get(meta.get("kind"), ())
    if not uses or "expert_snapshot" not in meta:
        return None
    now = current_snapshots(meta["env"], behavior_root)
    for which in uses:
        had = meta[f"{which}_snapshot"]["step"]
        if had != now[which]:
            return f"it was generated from the {which} snapshot at step {had}, the current rule picks step {now[which]}"
    return None


def cache_dir(override: Path | None = None) -> Path:
    """--cache-dir, else $PROTO_BRAX_DATASETS, else ~/.cache/proto_brax/datasets."""
    if override is not None:
        return Path(override)
    return Path(os.environ.get(ENV_VAR) or Path.home() / ".cache" / "proto_brax" / "datasets")


def dataset_path(name: str, size: int | None = None, seed: int = 0, cache: Path | None = None) -> Path:
    from proto_brax.data.generate import default_size, parse_name

    env, _ = parse_name(name)
    size = size or default_size(env)
    suffix = "" if (size == default_size(env) and seed == 0) else f"-n{size}-seed{seed}"
    return cache_dir(cache) / f"{name}{suffix}.npz"


_THREAD_FLAGS = ("xla_cpu_multi_thread_eigen", "intra_op_parallelism_threads")


def generation_xla_flags(flags: str | None = None, mjx: bool = False) -> str:
    """The XLA_FLAGS datasets are generated under: one XLA thread whatever the caller set (+ MJX's scheduler fix).

    Why: XLA's multi-threaded CPU kernels round differently from its single-threaded ones, and on envs whose episodes
    end on falls that changes the episodes. Measured (walker2d-medium, 5·10⁴ rows, one machine): multi-threaded and
    single-threaded generation gave different content hashes (128 vs 127 episodes), single-threaded generation gave
    the same hash twice and again with the CPU capped at AVX2 (``--xla_cpu_max_isa=AVX2``). Single-threaded,
    halfcheetah-medium reproduced the hash its bundle recorded on an earlier machine; hopper/walker2d-medium did not
    reproduce the hashes of caches built on earlier machines without this pin. The pin does not carry across CPUs
    (``envs.host_cpu``, recorded beside the flags): an AVX-512 machine built other rows than two earlier machines
    (FACTS.md's kind: AVX2) that agreed. Pure: returns the value for an entry point to set before jax starts."""
    from proto_brax import envs

    flags = os.environ.get("XLA_FLAGS", "") if flags is None else flags
    kept = " ".join(f for f in flags.split() if not f.lstrip("-").startswith(_THREAD_FLAGS))
    return envs.single_thread_mjx_xla_flags(kept) if mjx else envs.single_thread_xla_flags(kept)


def generation_numerics_pinned(flags: str | None = None) -> bool:
    """Whether ``flags`` hold ``generation_xla_flags``' thread flags; None = this process's XLA_FLAGS (as jax read
    them at start). Also read on a build's recorded ``xla_flags`` (``benchmarks/results_md.py``)."""
    from proto_brax.envs import SINGLE_THREAD_XLA_FLAGS

    flags = os.environ.get("XLA_FLAGS", "") if flags is None else flags
    return all(f in flags.split() for f in SINGLE_THREAD_XLA_FLAGS)


def make_argv(name: str, size: int | None, seed: int) -> list[str]:
    """``python -m proto_brax.datasets`` arguments that (re)build dataset ``name`` in the registry's cache."""
    return ["make", name, *(["--size", str(size)] if size else []), *(["--seed", str(seed)] if seed else []),
            "--force"]


def rebuild_command(name: str, size: int | None, seed: int) -> str:
    return " ".join(["python -m proto_brax.datasets", *make_argv(name, size, seed)])


def make_dataset(name: str, size: int | None = None, seed: int = 0, num_envs: int = 100,
                 behavior_root: Path | None = None, progress: bool = True, parts: dict | None = None,
                 checkpoint: Path | None = None):
    """Generate dataset ``name`` (numpy ``OfflineDataset``, metadata). Deterministic in (name, size, seed).

    ``checkpoint``: a directory for the long (AntMaze) builds' progress, from which an interrupted build resumes.

    ``parts`` may hold already generated ``{"medium": (data, meta), "expert": (data, meta)}`` for medium-expert.
    """
    import jax

    from proto_brax.data import generate as g

    env_name, kind = g.parse_name(name)
    if env_name in g.ANTMAZE_ENVS:
        from proto_brax.data.antmaze_data import make_antmaze_dataset

        return make_antmaze_dataset(env_name.removeprefix("antmaze-"), kind, size or g.default_size(env_name), seed,
                                    num_envs, progress=progress, checkpoint=checkpoint)
    if kind == "cloned":
        return make_cloned(name, size or g.default_size(env_name), seed, num_envs, behavior_root, progress)
    if kind == "medium-expert":  # D4RL: the concatenation of the medium and expert datasets
        parts = dict(parts or {})
        for sub in ("medium", "expert"):
            if sub not in parts:
                parts[sub] = make_dataset(f"{env_name}-{sub}", size, seed, num_envs, behavior_root, progress)
        from proto_brax.data.dataset import content_hash, episode_return_stats

        for d, m in parts.values():
            m.setdefault("content_hash", content_hash(d))
        (dm, mm), (de, me) = parts["medium"], parts["expert"]
        data = jax.tree.map(lambda a, b: np.concatenate([a, b]).astype(np.float32), dm, de)

        meta = {**{k: mm[k] for k in ("env", "backend", "seed", "num_envs", "episode_length", "version",
                                     "medium_snapshot", "expert_snapshot")},
                "name": name, "kind": kind, "size": mm["size"] + me["size"],
                "behavior": mm["behavior"] + me["behavior"],
                "parts": {"medium": mm["content_hash"], "expert": me["content_hash"]},
                "returns": episode_return_stats(data)}
        return data, meta
    from tqdm import tqdm

    from proto_brax import __version__, envs
    from proto_brax.data import generate as g
    from proto_brax.data.dataset import episode_return_stats

    env_name, kind = g.parse_name(name)
    size = size or g.default_size(env_name)
    if size % num_envs:
        raise ValueError(f"size ({size}) must be a multiple of num_envs ({num_envs}).")
    spec = envs.get_spec(env_name)
    env = envs.make_env(env_name)
    key = g.dataset_key(seed, kind)
    meta = {"name": name, "env": env_name, "backend": spec.default_backend, "kind": kind, "size": size,
            "seed": seed, "num_envs": num_envs, "episode_length": spec.episode_length, "version": __version__}

    policies: list[tuple[str, object, object, dict]] = []  # (label, policy, params, info)
    if kind != "random":
        snaps = g.list_snapshots(env_name, behavior_root)
        expert, medium = g.pick_expert_medium(snaps, reference_returns(spec))
        meta["expert_snapshot"] = {"step": expert.step, "eval_return": expert.eval_return}
        measured = "behavior_return" in medium.metadata
        meta["medium_snapshot"] = {
            "step": medium.step, "eval_return": medium.eval_return,
            **({"behavior_return": medium.metadata["behavior_return"]} if measured else {}),
            "rule": (f"{'behaviour return' if measured else 'eval return'} {MEDIUM_RULE}" if reference_returns(spec)
                     else "expert eval / 3")}

        def snap_policy(s):
            nets, params = g.load_snapshot_actor(s, env)
            return (f"step_{s.step}", g.stochastic_policy(nets), params,
                    {"step": s.step, "eval_return": s.eval_return, "params_hash": g.params_hash(params)})

    uniform = ("uniform", g.uniform_param_policy(env.action_size), None, {"step": 0})
    if kind == "random":
        policies.append(uniform)
    elif kind in ("medium", "expert"):
        policies.append(snap_policy(medium if kind == "medium" else expert))
    elif kind == "medium-replay":
        policies.append(uniform)
        policies += [snap_policy(s) for s in snaps if s.step <= medium.step]
    else:  # medium-expert
        policies += [snap_policy(medium), snap_policy(expert)]

    # Split the transitions between the policies (medium-replay: equal shares; medium-expert: size each).
    total = 2 * size if kind == "medium-expert" else size
    per_env = total // num_envs
    n = len(policies)
    shares = [per_env // n] * n
    shares[-1] += per_env - sum(shares)
    parts = []
    bar = tqdm(total=total, unit="tr", desc=name, disable=not progress, dynamic_ncols=True)
    for i, ((_, policy, params, info), steps) in enumerate(zip(policies, shares)):
        part = g.rollouts(env, spec.episode_length, policy, params, jax.random.fold_in(key, i), num_envs, steps,
                          g.segment_for(steps), bar)
        parts.append(part)
        info["transitions"] = steps * num_envs
    bar.close()
    data = jax.tree.map(lambda *xs: np.concatenate(xs).astype(np.float32), *parts)
    meta["behavior"] = [info for *_, info in policies]
    meta["size"] = total
    meta["returns"] = episode_return_stats(data)
    return data, meta


CLONED_DEMOS = 25  # D4RL's number of human demonstrations per Adroit task


def first_episodes(data, n: int):
    """The first ``n`` episodes of a (env-major) dataset: rows up to the n-th episode end
    (:func:`proto_brax.data.dataset.episode_ends`)."""
    import jax

    from proto_brax.data.dataset import episode_ends

    ends = np.flatnonzero(episode_ends(data))
    if len(ends) < n:
        raise ValueError(f"the dataset holds {len(ends)} episodes, fewer than the {n} asked for.")
    return jax.tree.map(lambda x: np.asarray(x)[: ends[n - 1] + 1], data)


def make_cloned(name: str, size: int, seed: int = 0, num_envs: int = 100, behavior_root: Path | None = None,
                progress: bool = True, demos: int = CLONED_DEMOS, bc_steps: int = 20_000):
    """D4RL's Adroit ``cloned`` recipe on the suite's own data: a 50-50 mix of demonstrations and rollouts of a
    behaviour-cloning policy trained on ``demos`` of them. D4RL's demonstrations are human; here they are the
    suite's expert (half of the rows: the ``-expert`` dataset at half the size, whose first ``demos`` episodes train
    the BC policy: maximum likelihood with the tanh-Gaussian actor, ``bc_steps`` steps of batch 256), and the other
    half are the BC policy's sampled actions."""
    import jax
    import jax.numpy as jnp

    from proto_brax import envs
    from proto_brax.agents.insample import OfflineHParams
    from proto_brax.data import generate as g
    from proto_brax.data.dataset import content_hash, episode_return_stats
    from proto_brax.train.offline import PretrainConfig, make_pretrain, run_pretrain

    env_name, _ = g.parse_name(name)
    if size % (2 * num_envs):
        raise ValueError(f"size ({size}) must be a multiple of 2 × num_envs ({2 * num_envs}).")
    expert, emeta = make_dataset(f"{env_name}-expert", size // 2, seed, num_envs, behavior_root, progress)
    demo = first_episodes(expert, demos)
    log_every = next(d for d in (10_000, 5_000, 2_000, 1_000, 500, 100, 1) if bc_steps % d == 0)
    pre = make_pretrain(PretrainConfig(algo="bc", env=env_name, steps=bc_steps, log_every=log_every))
    state, metrics, bc_returns = run_pretrain(pre, OfflineHParams.create(), [seed], jax.tree.map(jnp.asarray, demo))
    actor = jax.tree.map(lambda x: x[0], state.actor)
    env, spec = envs.make_env(env_name), envs.get_spec(env_name)
    steps = size // 2 // num_envs
    cloned = g.rollouts(env, spec.episode_length, g.stochastic_policy(pre.nets), actor, g.dataset_key(seed, "cloned"),
                        num_envs, steps, g.segment_for(steps))
    data = jax.tree.map(lambda a, b: np.concatenate([a, b]).astype(np.float32), expert, cloned)
    meta = {**{k: emeta[k] for k in ("env", "backend", "seed", "num_envs", "episode_length", "version",
                                     "expert_snapshot")},
            "name": name, "kind": "cloned", "size": size,
            "behavior": emeta["behavior"] + [{"step": "bc", "demos": demos, "demo_transitions": len(demo.rewards),
                                              "bc_steps": bc_steps, "params_hash": g.params_hash(actor),
                                              "bc_mse": float(metrics["mse"][-1][0]),
                                              "bc_eval_return": float(np.mean(bc_returns)),
                                              "transitions": size // 2}],
            "parts": {"expert": content_hash(expert), "cloned": content_hash(cloned)},
            "note": "D4RL's cloned data mix human demonstrations with a BC policy's rollouts; human demonstrations "
                    "cannot be recorded here, so the suite's expert policy stands in for the demonstrator.",
            "returns": episode_return_stats(data)}
    return data, meta


def load_dataset(name_or_path: str | Path, size: int | None = None, seed: int = 0, cache: Path | None = None):
    """A registered dataset from the cache (error naming the `make` command when absent), a file path (our .npz or a
    D4RL .hdf5), a local Minari dataset directory, or a Minari dataset id (``D4RL/pen/human-v2``: read from the
    user's Minari cache, never downloaded)."""
    from proto_brax.data import dataset as ds
    from proto_brax.data.generate import dataset_names

    p = Path(name_or_path)
    if str(name_or_path) in dataset_names():
        path = dataset_path(str(name_or_path), size, seed, cache)
        hint = rebuild_command(str(name_or_path), size, seed).replace(" --force", "")
        if not path.exists():
            raise FileNotFoundError(f"Dataset {name_or_path} is not in the cache ({path}): build it with `{hint}`.")
        data, meta = ds.load_npz(path, rebuild_hint=hint + " --force")
        if why := stale_reason(meta):
            raise ds.CorruptDatasetError(f"Cached dataset {path} is stale: {why}; rebuild it with `{hint} --force`.")
        return data, meta
    if p.is_dir():
        return ds.load_minari(p)
    if p.exists():
        return ds.load_d4rl_hdf5(p) if p.suffix in (".hdf5", ".h5") else ds.load_npz(p)
    if p.suffix:
        raise FileNotFoundError(f"Dataset file {name_or_path} does not exist.")
    if "/" in str(name_or_path):  # a Minari id: NAMESPACE/TASK/KIND-vN
        try:
            return ds.load_minari(str(name_or_path))
        except (ds.CorruptDatasetError, ds.NonFiniteDatasetError):  # found, but not what it was written as
            raise
        except Exception as e:  # minari raises its own error types (FileNotFoundError, ValueError, …) across versions
            root = os.environ.get(ds._MINARI_ENV, str(Path.home() / ".minari" / "datasets"))
            raise FileNotFoundError(
                f"Minari dataset {name_or_path} is not available locally ({type(e).__name__}: {e}). Nothing is "
                f"downloaded here: copy it to {root}/{name_or_path} (or set MINARI_DATASETS_PATH), or pass its "
                "directory or a D4RL .hdf5 file as --dataset.") from e
    raise ValueError(f"Unknown dataset {name_or_path!r}: not a file, and not one of: {', '.join(dataset_names())}.")


# ------------------------------------------------------------------------------------------------------------- CLI


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
    env = envs.make_env(a.env)
    out = []
    for snap, ret in g.behavior_returns(env, spec.episode_length, g.list_snapshots(a.env, a.behavior_root),
                                        a.episodes, a.seed):
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


def partial_path(path: Path) -> Path:
    """Where an unfinished build of the dataset file ``path`` keeps its progress (``proto_brax.data.partial``)."""
    return path.with_name(f".{path.name}.partial")


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
        size = default_size(env) * (2 if kind == "medium-expert" else 1)
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
    nets, params = g.load_snapshot_actor(expert, env)
    import jax.numpy as jnp

    det = lambda obs, k: jnp.tanh(nets.actor.apply(params, obs)[0])  # noqa: E731
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
        {"make": Make, "export": Export, "info": Info, "list": List, "references": References, "measure": Measure},
        args=argv,
    )
    # Before JAX starts: the pinned generation numerics (export builds a registered dataset that is not cached).
    if isinstance(cmd, (Make, Export)) and cmd.name in dataset_names():
        from proto_brax import envs

        mjx = envs.get_spec(parse_name(cmd.name)[0]).default_backend == "mjx"  # AntMaze, Adroit
        os.environ["XLA_FLAGS"] = generation_xla_flags(mjx=mjx)
    from proto_brax.startup import exit_on_input_error

    run = {Make: cmd_make, Export: cmd_export, Info: cmd_info, List: cmd_list, References: cmd_references,
           Measure: cmd_measure}[type(cmd)]
    exit_on_input_error(lambda: run(cmd), argv)


if __name__ == "__main__":
    from proto_brax.startup import quiet_start

    quiet_start()
    main()
