"""Offline pretraining (EQL, SQL, IQL, BC + FQE, CQL, Cal-QL) saved as an orbax bundle (the command line:
``python -m proto_brax.pretrain``, ``proto_brax.cli.pretrain``).

    python -m proto_brax.pretrain --dataset hopper-medium --algo eql --seeds 0 1 2 3 4 --steps 100000 --out DIR

All seeds train in one vmapped program; the bundle stores every seed (finetuning maps them onto its seeds or
broadcasts one) with metadata: algorithm and hyper-parameters, dataset name and content hash, env and sizes,
network config, steps, seeds, offline evaluation (return and normalized score) and timing.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import time
from pathlib import Path
from typing import Literal

import numpy as np

from proto_brax.agents.registry import PRETRAIN_ALGOS, PRETRAIN_HP


@dataclasses.dataclass
class PretrainArgs:
    """Offline pretraining of a bundle for finetune-only PROTO runs."""

    dataset: str
    """Registered dataset name (e.g. hopper-medium) or a file (.npz ours, .hdf5 D4RL)."""
    dataset_size: int | None = None
    """Transitions of a registered dataset (default 10⁶), as cached by `python -m proto_brax.datasets make`."""
    algo: Literal[PRETRAIN_ALGOS] = "eql"
    """eql / sql (IVR in-sample), iql, bc (BC actor + FQE critic, for PROTO+BC and AWAC), cql, or calql (CQL with
    Cal-QL's Monte-Carlo calibration; policy learning rate 1e-4 unless --hp lr_actor says otherwise)."""
    env: str | None = None
    """Env of the dataset; read from the dataset's metadata when absent."""
    seeds: tuple[int, ...] = (0,)
    steps: int = 100_000
    """Gradient steps (paper: 10⁵ MuJoCo/Adroit, 2·10⁵ AntMaze)."""
    log_every: int = 10_000
    batch_size: int = 256
    hidden: tuple[int, ...] = (256, 256)
    critic_layer_norm: bool | None = None
    """LayerNorm in Q and V; default: on, except halfcheetah (paper)."""
    policy: Literal["tanh_gaussian", "gaussian"] = "tanh_gaussian"
    """The actor's distribution: tanh-squashed Gaussian (ours) or the official PROTO code's Gaussian with mean
    tanh(m(s)) and a state-independent std (FIDELITY.md)."""
    eval_episodes: int = 10
    reward_scale: float | None = None
    """Training rewards are reward_scale · r + reward_shift (evaluation reports raw returns). Default: the env's rule,
    1000 / (max − min episode return of the dataset) for locomotion as the IQL/IVR/PROTO reference code, 1 for
    AntMaze and point. Recorded in the bundle; finetuning uses the same transform."""
    reward_shift: float | None = None
    """Default: the env's (AntMaze −1, as the reference code; else 0)."""
    hp: dict[str, float] = dataclasses.field(default_factory=dict)
    """Offline hyper-parameters, e.g. --hp alpha 2.0 (see proto_brax.agents.insample.OfflineHParams)."""
    out: Path | None = None
    """Bundle directory; default checkpoints/pretrained/<dataset>/<algo>."""
    overwrite: bool = False
    resume: bool = True
    """Continue an interrupted run of the same configuration (arguments and dataset content) from its last chunk:
    its state is kept under $PROTO_BRAX_RUNS/pretrain (default ~/.cache/proto_brax/runs) until the bundle is saved."""


RUN_ONLY = ("out", "overwrite", "resume")  # PretrainArgs fields that do not change the bundle's numbers


def partial_dir(args: PretrainArgs, data_hash: str) -> Path:
    """Where an unfinished run of ``args`` on the data with content hash ``data_hash`` keeps its chunks: one
    directory per configuration, so only the same run resumes from it."""
    record = {k: (str(v) if isinstance(v, Path) else v) for k, v in dataclasses.asdict(args).items()
              if k not in RUN_ONLY}
    key = hashlib.sha256(json.dumps([record, data_hash], sort_keys=True).encode()).hexdigest()[:16]
    runs = Path(os.environ.get("PROTO_BRAX_RUNS", Path.home() / ".cache" / "proto_brax" / "runs"))
    return runs / "pretrain" / f"{Path(str(args.dataset)).name}-{args.algo}-{key}"


def check_out(out: Path, overwrite: bool) -> None:
    """Refuse an --out that holds anything but a bundle (even with --overwrite, which replaces only a bundle), and an
    existing bundle without --overwrite."""
    import json

    from proto_brax.checkpoints import BUNDLE_KIND

    if out.exists() and not out.is_dir():
        raise FileExistsError(f"--out {out} is a file: choose another --out.")
    if not out.exists() or not any(out.iterdir()):
        return
    try:
        kind = json.loads((out / "metadata.json").read_text()).get("kind")
    except (OSError, ValueError, AttributeError):
        kind = None
    if kind != BUNDLE_KIND:
        held = ", ".join(sorted(p.name for p in out.iterdir())[:5])
        raise FileExistsError(f"--out {out} is not a pretrained bundle (it holds {held}): refusing to replace it"
                              f"{' even with --overwrite' if overwrite else ''}; choose another --out.")
    if not overwrite:
        raise FileExistsError(f"{out} already holds a bundle: pass --overwrite or another --out.")


def pretrain(args: PretrainArgs) -> dict:
    from proto_brax import __version__, checkpoints, envs
    from proto_brax.agents.insample import OfflineHParams
    from proto_brax.data.cache import load_dataset
    from proto_brax.data.dataset import content_hash, transform_rewards, validate_for_env, with_returns_to_go
    from proto_brax.files import lock_dir, release_dir
    from proto_brax.networks import NetworkConfig
    from proto_brax.train.offline import PretrainConfig, make_pretrain, run_pretrain

    hp = OfflineHParams.create(**{**PRETRAIN_HP.get(args.algo, {}), **args.hp})
    dname = checkpoints.dataset_label(args.dataset)
    out = Path(args.out or Path("checkpoints/pretrained") / dname / args.algo)
    check_out(out, args.overwrite)  # before the data are read (or anything trains)
    data, dmeta = load_dataset(args.dataset, args.dataset_size)
    env = args.env or (dmeta or {}).get("env")
    if env is None:
        raise ValueError(f"Dataset {args.dataset} does not name its env: pass --env.")
    data_hash = (dmeta or {}).get("content_hash") or content_hash(data)  # of the data as stored (raw rewards)
    scale, shift = envs.reward_transform(env, data, args.reward_scale, args.reward_shift)
    data = transform_rewards(data, scale, shift)
    if args.algo == "calql":
        data = with_returns_to_go(data, float(hp.gamma))
    ln = envs.default_layer_norm(env) if args.critic_layer_norm is None else args.critic_layer_norm
    cfg = PretrainConfig(algo=args.algo, env=env, net=NetworkConfig(hidden=tuple(args.hidden), critic_layer_norm=ln,
                                                                 policy=args.policy),
                         steps=args.steps, log_every=args.log_every, batch_size=args.batch_size,
                         eval_episodes=args.eval_episodes)
    pre = make_pretrain(cfg)
    validate_for_env(data, pre.obs_size, pre.act_size, str(args.dataset), env_name=env)

    import jax
    from tqdm import tqdm

    dataset = jax.tree.map(jax.numpy.asarray, data)
    bar = tqdm(total=cfg.steps, unit="step", desc=f"{args.algo} {dname}", dynamic_ncols=True)
    t0 = time.time()
    first = {}

    def on_chunk(c, m):
        first.setdefault("t", time.time() - t0)
        bar.update(cfg.log_every)
        bar.set_postfix({k: f"{float(np.mean(v)):.3g}" for k, v in m.items()
                         if k in ("critic_loss", "value_loss", "actor_loss", "bc_loss")})

    partial, done = partial_dir(args, data_hash) if args.resume else None, 0
    if partial is not None:  # one process per resume state (the same configuration's twin would share it)
        lock_dir(partial, "run without --resume (it keeps no resume state)")
    if partial is not None and (latest := checkpoints.latest_step(partial)) is not None:
        done = checkpoints.read_metadata(latest)["chunks_done"]
        print(f"resuming after chunk {done} of {cfg.steps // cfg.log_every} ({partial})", flush=True)
        bar.update(done * cfg.log_every)
    try:
        state, hist, returns = run_pretrain(pre, hp, list(args.seeds), dataset, callback=on_chunk, resume=partial)
    except BaseException:
        if partial is not None:
            release_dir(partial)
        raise
    bar.close()
    seconds, ran = time.time() - t0, cfg.steps - done * cfg.log_every
    returns = np.asarray(returns)
    scores = np.asarray(envs.normalized_score(env, returns.mean(-1)))
    meta = {
        "algo": args.algo, "env": env, "backend": envs.get_spec(env).default_backend,
        "obs_size": pre.obs_size, "act_size": pre.act_size, "net": dataclasses.asdict(cfg.net),
        "steps": cfg.steps, "batch_size": cfg.batch_size, "seeds": list(args.seeds),
        "hparams": {k: float(v) for k, v in dataclasses.asdict(hp).items()},
        "dataset": dname, "dataset_size": int(np.asarray(data.rewards).shape[0]),
        "dataset_content_hash": data_hash,
        "reward_scale": scale, "reward_shift": shift,
        "offline_eval": {
            "episodes": cfg.eval_episodes, "returns_per_seed": returns.mean(-1).tolist(),
            "return_mean": float(returns.mean()), "normalized_score_per_seed": scores.tolist(),
            "normalized_score_mean": float(np.nanmean(scores)) if np.isfinite(scores).any() else float("nan"),
        },
        "final_losses": {k: np.asarray(v[-1]).tolist() for k, v in hist.items()},
        # this process's timing: a resumed run times the chunks it ran (after ``resumed_after_chunk``)
        "seconds": seconds, "seconds_first_chunk_incl_compile": first.get("t"), "resumed_after_chunk": done,
        "seconds_per_1e5_steps_all_seeds": (seconds - first.get("t", 0.0)) / (ran - cfg.log_every) * 1e5
        if ran > cfg.log_every else None,
        "version": __version__,
    }
    checkpoints.save_bundle(out, state, meta)
    if partial is not None:
        shutil.rmtree(partial, ignore_errors=True)  # (our own resume state, never the user's: the bundle is saved)
        release_dir(partial)
    print(f"{args.algo} on {dname}: offline return {returns.mean():.1f} (per seed {np.round(returns.mean(-1), 1)}), "
          f"normalized {meta['offline_eval']['normalized_score_mean']:.1f}; {seconds:.0f} s -> {out}")
    return meta
