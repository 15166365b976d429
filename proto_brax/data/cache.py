"""The registered datasets' cache: where each lives, whether it is stale, how it is made and loaded (the command
line is ``python -m proto_brax.datasets``, ``proto_brax.cli.datasets``). D4RL-style offline datasets, generated
reproducibly from committed behaviour policies.

Kinds (per env, D4RL's definitions adapted to the suite's own SAC runs, ``checkpoints/behavior/<env>/``):

* ``random``: uniform random actions in [-1, 1];
* ``expert``: the final behaviour snapshot, actions sampled from its tanh-Gaussian (stochastic, as D4RL);
* ``medium``: the snapshot whose evaluation return is closest to a third of the expert's, stochastic;
* ``medium-replay``: the policies an agent went through up to medium: the uniform policy (the replay buffer's warm-up)
  then every snapshot up to and including medium, each contributing an equal share of the transitions (stochastic);
* ``medium-expert``: the ``medium`` dataset followed by the ``expert`` dataset, exactly (twice the size; built from
  the cached parts when they exist, else by generating both);
* ``cloned`` (Adroit, point): D4RL's recipe, half expert rows, half a BC policy's (``make_cloned``);
* ``human`` (Adroit, point): D4RL's human-data size, 25 expert episodes with Gaussian action noise.

Each dataset is ``size`` transitions from ``num_envs`` envs run side by side (episodes stay contiguous per env); time
limits are ``timeouts``, true terminations ``terminals``. Same name, size and seed ⇒ identical arrays (checked by the
content hash in the metadata), given the same XLA threading and CPU: ``make`` generates with one XLA thread
(``generation_xla_flags``), since multi-threaded rounding gives hopper and walker2d other episodes, and records the
CPU (``envs.host_cpu``): XLA compiles for the host CPU, and another CPU can build other episodes (an AVX-512 machine
did, against two earlier AVX2 machines that agreed). The commands that make, export and inspect them are listed in
``proto_brax.cli.datasets``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

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
    medium for medium and medium-replay, expert for expert, cloned and human, both for medium-expert — is not the one
    the current rule picks: new snapshots, or a changed rule; AntMaze: its controller is not the last ant-goal
    snapshot), or None when it is current."""
    if "controller" in meta:  # AntMaze: made with the ant-goal controller's last snapshot of the time
        from proto_brax.data import generate as g

        last = g.list_snapshots(meta["controller"]["env"], behavior_root)[-1].step
        had = meta["controller"]["step"]
        return None if had == last else (f"it was generated with the {meta['controller']['env']} controller at step "
                                         f"{had}, the last snapshot is step {last}")
    uses = {"medium": ("medium",), "medium-replay": ("medium",), "expert": ("expert",), "cloned": ("expert",),
            "human": ("expert",), "medium-expert": ("medium", "expert")}.get(meta.get("kind"), ())
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

    env, kind = parse_name(name)
    size = size or default_size(env, kind)
    suffix = "" if (size == default_size(env, kind) and seed == 0) else f"-n{size}-seed{seed}"
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
    size = size or g.default_size(env_name, kind)
    if kind == "human":  # one env per demonstration: each runs its episode to the time limit
        num_envs = g.HUMAN_EPISODES
    if size % num_envs:
        raise ValueError(f"size ({size}) must be a multiple of num_envs ({num_envs}).")
    spec = envs.get_spec(env_name)
    # Recorded on the env's native twin where it has one (generate.native_rollouts), not on MJX: gymnasium's own v5
    # envs (Farama's mujoco/* data came from them) and Adroit's capsule model (MJX steps a hand ~100 times a second
    # here); the sweeps still run MJX.
    from proto_brax.envs.native import NATIVE_ENVS, native_env

    native = env_name in NATIVE_ENVS
    env = native_env(env_name) if native else envs.make_env(env_name)
    key = g.dataset_key(seed, kind)
    meta = {"name": name, "env": env_name, "backend": "native" if native else spec.default_backend, "kind": kind,
            "size": size, "seed": seed, "num_envs": num_envs, "episode_length": spec.episode_length,
            "version": __version__}

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
            policy, params = g.snapshot_policy(s, env)
            return (f"step_{s.step}", policy, params,
                    {"step": s.step, "eval_return": s.eval_return, "params_hash": g.params_hash(params),
                     **({"policy_class": s.metadata["policy_class"]} if "policy_class" in s.metadata else {})})

    uniform = ("uniform", g.uniform_param_policy(env.action_size), None, {"step": 0})
    if kind == "random":
        policies.append(uniform)
    elif kind in ("medium", "expert"):
        policies.append(snap_policy(medium if kind == "medium" else expert))
    elif kind == "human":
        label, policy, params, info = snap_policy(expert)
        policies.append((label, g.noisy_policy(policy, g.HUMAN_NOISE), params, {**info, "action_noise": g.HUMAN_NOISE}))
        meta["note"] = ("D4RL's human data are people's demonstrations; here the suite's expert with N(0, "
                        f"{g.HUMAN_NOISE}²) action noise stands in, {g.HUMAN_EPISODES} of them (D4RL's number).")
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
        parts.append(g.dataset_rollouts(env_name, spec.episode_length, policy, params, jax.random.fold_in(key, i),
                                        num_envs, steps, bar, env))
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
    spec = envs.get_spec(env_name)
    steps = size // 2 // num_envs
    cloned = g.dataset_rollouts(env_name, spec.episode_length, g.stochastic_policy(pre.nets), actor,
                                g.dataset_key(seed, "cloned"), num_envs, steps)
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


def partial_path(path: Path) -> Path:
    """Where an unfinished build of the dataset file ``path`` keeps its progress (``proto_brax.data.partial``)."""
    return path.with_name(f".{path.name}.partial")
