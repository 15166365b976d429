"""Minari datasets recorded the way Farama recorded ``mujoco/*``: minari's own ``DataCollector`` around Gymnasium's
native v5 env (``Hopper-v5``, …), stepped by a behaviour policy of ours, written with ``create_dataset``.

This is the data path a user of the field's standard data takes (issue 34): the rows come from Gymnasium's MuJoCo,
not from the suite's MJX port, and the suite then pretrains on them (``--dataset ID``) and finetunes online on the
MJX port of the same env (``--env hopper-v5``), whose dynamics, observations and rewards match Gymnasium's
(``envs.gym_v5``; ``benchmarks/gym_v5_check.py``), so online returns are in the data's units.

The behaviour policy is ``random`` (uniform actions) or a snapshot of ``checkpoints/behavior/ENV`` (the native SAC
trainer, ``data.native_behavior``): ``medium`` / ``expert`` by the registered datasets' rule
(``generate.pick_expert_medium``), or a step; its actions are sampled from the tanh-Gaussian, as D4RL's and the
suite's datasets are. Everything random is seeded from ``seed``: reset seeds from a NumPy generator, action keys
folded with the step, so a collection is reproducible on one CPU (same content hash).

The metadata carries Minari's fields (``ref_min_score`` / ``ref_max_score`` from the env's registered references,
so ``minari.get_normalized_score`` gives the suite's normalized score; ``algorithm_name``; the env spec, recorded by
the collector) and the suite's block (``"proto_brax"``: the content hash, which the suite's reader checks, the
suite env, the behaviour snapshot and the command).

    python -m proto_brax.datasets collect hopper-v5 --policy medium --steps 100000 --id local/hopper-v5/medium-v0
"""

from __future__ import annotations

import os
import time
import warnings
from pathlib import Path
from typing import Any, Callable

import jax
import numpy as np

from proto_brax.data.minari_io import METADATA_KEY, MINARI_ENV, check_id, minari_root

POLICIES = ("random", "medium", "expert")  # or a snapshot step


def behavior_policy(env: str, policy: str, action_size: int, seed: int,
                    behavior_root: Path | None = None) -> tuple[Callable[[np.ndarray, int], np.ndarray], dict]:
    """(act(obs, t) -> action, record): ``policy`` as a host function of one observation and the step index, its
    randomness seeded from ``seed`` (uniform actions from a NumPy generator; a snapshot's samples from a JAX key
    folded with the step)."""
    from proto_brax import envs
    from proto_brax.data import generate as g
    from proto_brax.data.cache import reference_returns

    if policy == "random":
        rng = np.random.default_rng([seed, 1])  # (the reset seeds come from [seed])
        return (lambda obs, t: rng.uniform(-1.0, 1.0, action_size).astype(np.float32)), {"policy": "random"}
    snaps = g.list_snapshots(env, behavior_root)
    if policy in ("medium", "expert"):
        expert, medium = g.pick_expert_medium(snaps, reference_returns(envs.get_spec(env)))
        snap = medium if policy == "medium" else expert
    else:
        try:
            step = int(policy)
        except ValueError:
            raise ValueError(f"--policy {policy!r}: pass one of {', '.join(POLICIES)} or a snapshot step "
                             f"({', '.join(str(s.step) for s in snaps)}).") from None
        found = [s for s in snaps if s.step == step]
        if not found:
            raise ValueError(f"--policy {step}: no snapshot of {env} at that step; the steps are "
                             f"{', '.join(str(s.step) for s in snaps)}.")
        snap = found[0]

    from proto_brax.envs.native import native_env

    sampler, params = g.snapshot_policy(snap, native_env(env))  # (the native twin: its sizes)
    key = jax.random.PRNGKey(seed)
    sample = jax.jit(lambda obs, k: sampler(params, obs[None], k)[0])

    def act(obs: np.ndarray, t: int) -> np.ndarray:
        return np.asarray(sample(np.asarray(obs, np.float32), jax.random.fold_in(key, t)))

    record = {"policy": policy, "snapshot": str(snap.path), "snapshot_step": snap.step,
              "snapshot_eval_return": snap.eval_return,
              "sampling": "stochastic (the snapshot's samples: tanh-Gaussian for SAC actors)"}
    return act, record


def collect(env: str, dataset_id: str, steps: int, policy: str = "medium", seed: int = 0,
            root: str | os.PathLike[str] | None = None, behavior_root: Path | None = None,
            command: str | None = None, bar=None) -> Path:
    """Record ``steps`` transitions of ``policy`` on Gymnasium's native ``env`` (a registered ``*-v5`` name) with
    minari's DataCollector into the local Minari dataset ``dataset_id`` under ``root``; returns its directory.

    Episodes end at Gymnasium's termination or its 1000-step time limit (a truncation); the last one is cut at
    ``steps`` (minari marks it truncated). The rows are read back once, with the suite's reader, to record their
    content hash. An existing dataset of that id is never replaced: FileExistsError, before anything runs."""
    import gymnasium as gym
    from minari import DataCollector

    from proto_brax import __version__, envs
    from proto_brax.data.dataset import _env_var, load_minari
    from proto_brax.envs import gym_v5

    if not env.endswith("-v5") or env not in envs.REGISTRY:
        raise ValueError(f"collect records Gymnasium's own v5 envs; {env!r} is not one: pass "
                         f"{', '.join(n for n in envs.REGISTRY if n.endswith('-v5'))}.")
    check_id(dataset_id)
    if steps <= 0:
        raise ValueError(f"--steps must be positive (got {steps}).")
    root = minari_root(root).absolute()
    target = root / dataset_id
    if target.exists() or target.is_symlink():
        raise FileExistsError(f"Minari dataset {dataset_id} already exists at {target}: pass another --id or --out "
                              "(collect never replaces a dataset).")
    spec = envs.get_spec(env)
    gym_env = gym.make(gym_v5.get_task(env.removesuffix("-v5")).gym_id)  # with its TimeLimit: truncations
    act, record = behavior_policy(env, policy, int(gym_env.action_space.shape[0]), seed, behavior_root)
    rng = np.random.default_rng(seed)
    root.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    with _env_var(MINARI_ENV, str(root)):
        collector = DataCollector(gym_env, record_infos=False)
        try:
            obs, _ = collector.reset(seed=int(rng.integers(2**31 - 1)))
            returns, ret = [], 0.0
            for t in range(steps):
                obs, reward, terminated, truncated, _ = collector.step(act(obs, t))
                ret += float(reward)
                if terminated or truncated:
                    returns.append(ret)
                    ret = 0.0
                    if t + 1 < steps:
                        obs, _ = collector.reset(seed=int(rng.integers(2**31 - 1)))
                if bar is not None:
                    bar.update(1)
            name = record["policy"] if policy == "random" else f"SAC snapshot step {record['snapshot_step']}"
            with warnings.catch_warnings():  # minari's advice to give an e-mail address: there is none to give
                warnings.filterwarnings("ignore", message=r"`author_email` is set to None", category=UserWarning)
                ds = collector.create_dataset(
                    dataset_id=dataset_id, eval_env=gym_env.spec.id,
                    algorithm_name=f"proto_brax {name} ({policy})",
                    author="proto_brax",
                    code_permalink=f"proto_brax {__version__} (python -m proto_brax.datasets collect)",
                    ref_min_score=float(spec.ref_random), ref_max_score=float(spec.ref_expert),
                    description=(f"{steps} steps of a proto_brax behaviour policy ({policy}) on Gymnasium's {env} "
                                 "recorded with minari's DataCollector; see metadata['proto_brax']."),
                )
        finally:
            collector.close()
        seconds = time.time() - t0
        _, meta = load_minari(target)  # the suite's reader: the rows the suite will train on
        block: dict[str, Any] = {
            "content_hash": meta["content_hash"],  # checked by every later load
            "env": env, "source": "collect", "export_command": command, "collected_by": f"proto_brax {__version__}",
            "generation": {**record, "steps": steps, "seed": seed, "gym_id": gym_env.spec.id,
                           "completed_episode_returns": {"count": len(returns),
                                                         "mean": float(np.mean(returns)) if returns else None},
                           "seconds": seconds, "cpu": envs.host_cpu()},
        }
        # Only metadata.json changes here, and every later load (summary's first) checks the rows against the hash:
        # reading a million rows back once more would check nothing new.
        ds.storage.update_metadata({METADATA_KEY: block})
    return target


def summary(path: Path) -> dict:
    """The collected dataset's size, episodes and returns as the suite reads it."""
    from proto_brax import envs
    from proto_brax.data.dataset import episode_returns, load_minari

    data, meta = load_minari(path)
    r = episode_returns(data)
    env = meta["env"]
    return {"transitions": meta["total_steps"], "episodes": meta["total_episodes"], "return_mean": float(r.mean()),
            "normalized": float(envs.normalized_score(env, float(r.mean()))), "content_hash": meta["content_hash"],
            "env": env}
