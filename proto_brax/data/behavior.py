"""Behaviour policies for the offline datasets: SAC trained online from scratch by the suite's own loop.

SAC from scratch is PROTO-SAC with α₀ = 0 from a random init (no separate code path), with standard SAC settings
(initial temperature 1, target entropy −|A|). Every ``snapshot_every`` env steps the actor is evaluated
(``eval_episodes`` deterministic episodes) and saved under ``checkpoints/behavior/<env>/step_XXXXXXX/`` (actor
parameters only: small, committed). The full training state (including the replay buffer) is saved after each chunk
under ``--resume-dir`` so an interrupted run resumes where it stopped.

    python -m proto_brax.data.behavior --env hopper --steps 300000
    python -m proto_brax.data.behavior --env ant-goal --steps 300000 --snapshot-every 10000   # AntMaze's controller
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

if __name__ == "__main__":  # as a command line: the quiet start before the imports that print (MJX's warp lines)
    from proto_brax.startup import quiet_start

    quiet_start()

import jax
import jax.numpy as jnp
import numpy as np

from proto_brax import __version__, checkpoints, envs
from proto_brax.config import FinetuneConfig
from proto_brax.networks import NetworkConfig
from proto_brax.train.online import make_finetune

SAC_SCRATCH = dict(alpha0=0.0, alpha_sac_init=1.0, target_entropy_scale=-1.0)


@dataclasses.dataclass
class Args:
    env: str = "hopper"  # registered env name
    backend: str | None = None  # None = the env's default backend
    steps: int = 300_000  # total env steps (= gradient steps)
    snapshot_every: int = 20_000  # env steps between evaluated, saved snapshots
    eval_episodes: int = 10
    seed: int = 0
    out: Path = Path("checkpoints/behavior")  # snapshots: OUT/<env>/step_XXXXXXX
    resume_dir: Path = Path("runs/behavior")  # full training state for resuming: RESUME_DIR/<env>
    learning_starts: int = 10_000
    buffer_capacity: int = 1_000_000
    hidden: tuple[int, ...] = (256, 256)  # actor and critic hidden sizes


def behavior_config(args: Args) -> FinetuneConfig:
    return FinetuneConfig(
        env=args.env, backend=args.backend, algo="sac", steps=args.steps, eval_every=args.snapshot_every,
        eval_episodes=args.eval_episodes, sampling="online", learning_starts=args.learning_starts,
        buffer_capacity=args.buffer_capacity, net=NetworkConfig(hidden=tuple(args.hidden)),
    )


def snapshot_dir(out: Path, env: str, step: int) -> Path:
    return Path(out) / env / f"step_{step:07d}"


def train_behavior(args: Args) -> list[dict]:
    cfg = behavior_config(args)
    ft = make_finetune(cfg)
    hp = ft.hparams.create(**SAC_SCRATCH)
    state = jax.jit(ft.init, static_argnums=())(hp, jax.random.PRNGKey(args.seed), None, None)
    resume = Path(args.resume_dir) / args.env
    start_chunk = 0
    latest = checkpoints.latest_step(resume)
    if latest is None and (resume / "metadata.json").exists():  # runs started before step-numbered resumes
        latest = resume
    if latest is not None:
        state, meta = checkpoints.restore(latest, state)
        start_chunk = meta["chunks_done"]
        print(f"[{args.env}] resuming after chunk {start_chunk} ({start_chunk * cfg.eval_every} steps)", flush=True)
    chunk = jax.jit(ft.chunk, donate_argnums=(0,))
    backend = cfg.backend or envs.get_spec(cfg.env).default_backend
    log = []
    for c in range(start_chunk, cfg.num_chunks):
        t0 = time.time()
        state, m = chunk(state, hp, None, jnp.asarray(c * cfg.eval_every, jnp.int32))
        m = jax.device_get(m)
        dt = time.time() - t0
        step = int(m["step"])
        rec = {
            "env": cfg.env, "backend": backend, "step": step, "seed": args.seed,
            "eval_return_mean": float(m["eval_return"]), "eval_returns": np.asarray(m["eval_returns"]).tolist(),
            "train_return": float(m["train_return"]), "critic_loss": float(m["critic_loss"]),
            "alpha_sac": float(m["alpha_sac"]), "seconds": dt, "steps_per_second": cfg.eval_every / dt,
            "config": {"finetune": dataclasses.asdict(cfg), "hparams": SAC_SCRATCH}, "version": __version__,
        }
        checkpoints.save(snapshot_dir(args.out, cfg.env, step), state.learner.actor, rec)
        checkpoints.save_step(resume, c + 1, state, {"chunks_done": c + 1, "env": cfg.env}, keep=1)
        print(f"[{cfg.env}] step {step} eval {rec['eval_return_mean']:.1f} train {rec['train_return']:.1f} "
              f"({rec['steps_per_second']:.0f} steps/s)", flush=True)
        log.append(rec)
    return log


if __name__ == "__main__":
    import os

    import tyro

    args = tyro.cli(Args)
    if (args.backend or envs.get_spec(args.env).default_backend) == "mjx":  # before JAX starts its backend
        os.environ["XLA_FLAGS"] = envs.mjx_xla_flags()
        from proto_brax.train.grid import size_cpu_pool

        size_cpu_pool(1)  # one device: jaxlib's batched LAPACK never splits (grid.cpu_pool_threads)
    train_behavior(args)
