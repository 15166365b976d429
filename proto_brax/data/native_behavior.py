"""Behaviour policies on native MuJoCo: SAC from scratch, the env stepped in a Python loop, the update jitted. For
Adroit (issue 36: MJX trains an expert at ~6 SAC steps/s here) and Gymnasium's v5 locomotion (issue 34: Farama's
``mujoco/*`` data came from the native envs; MJX's hopper-v5 trains at a few steps/s beside other jobs); native
stepping leaves the update as the cost.

The agent is the suite's own SAC (``agents.sac`` with α₀ = 0, ``behavior.SAC_SCRATCH``'s temperature 1 and target
entropy −|A|), its replay buffer and networks; only the env loop runs on the host (``envs.adroit_native``: the MJX
env's capsule model, reset, observation, D4RL reward and termination; ``envs.gym_v5.NativeGymV5``: gymnasium's own
v5 env). Per env step: one jitted action, one native step, one jitted insert + gradient step (after
``learning_starts``). The registered time limit (D4RL's pen 100, door and hammer 200; v5 1000) truncates:
bootstrapping continues; only a true termination (pen dropped, a fallen hopper, non-finite physics) stops it.

Snapshots are the format of ``checkpoints/behavior/`` (``behavior.snapshot_dir``: the actor and its record with
``eval_return_mean``, so ``python -m proto_brax.datasets make pen-expert`` picks them up), with the evaluation's
success rate by D4RL's rule (``EnvSpec.success_steps``). After each snapshot the learner, the buffer, the keys and the
step are saved under ``--resume-dir``: a rerun continues from there with a fresh episode (the native physics state is
not saved; the trajectory then differs from an uninterrupted run's from that point).

    python -m proto_brax.data.native_behavior --env pen --steps 300000
    python -m proto_brax.data.native_behavior --env hopper-v5 --steps 300000
"""

from __future__ import annotations

import dataclasses
import functools
import time
from pathlib import Path

if __name__ == "__main__":  # as a command line: the quiet start before the imports that print (MJX's warp lines)
    from proto_brax.startup import quiet_start

    quiet_start()

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from proto_brax import __version__, checkpoints, envs
from proto_brax.agents import sac
from proto_brax.agents.learner import Learner, init_learner
from proto_brax.config import FinetuneConfig
from proto_brax.data.behavior import SAC_SCRATCH, snapshot_dir
from proto_brax.data.dataset import Transition
from proto_brax.data.replay import ReplayBuffer, replay_init, replay_insert, replay_sample
from proto_brax.envs.native import native_env, native_episodes
from proto_brax.networks import NetworkConfig, make_networks


@dataclasses.dataclass
class Args:
    env: str = "pen"  # pen, door, hammer, or a Gymnasium v5 env (hopper-v5, walker2d-v5, halfcheetah-v5, ant-v5)
    steps: int = 300_000  # env steps (= gradient steps after learning_starts)
    snapshot_every: int = 20_000  # env steps between evaluated, saved snapshots (and resume points)
    eval_episodes: int = 10
    seed: int = 0
    out: Path = Path("checkpoints/behavior")  # snapshots: OUT/<env>/step_XXXXXXX
    resume_dir: Path = Path("runs/native_behavior")  # RESUME_DIR/<env>: learner, buffer, keys, step
    learning_starts: int = 10_000
    buffer_capacity: int = 1_000_000
    batch_size: int = 256
    hidden: tuple[int, ...] = (256, 256)


@struct.dataclass
class Trainer:
    """Everything that resumes: the learner, the replay buffer, the key and the env steps taken."""

    learner: Learner
    buffer: ReplayBuffer
    key: jax.Array
    step: jax.Array


def make_trainer(args: Args):
    """(config, networks, hparams, init, act, learn): pure functions of the trainer state, jitted."""
    cfg = FinetuneConfig(env=args.env, algo="sac", regularizer=False, batch_size=args.batch_size,
                         steps=args.steps, eval_every=args.snapshot_every,
                         net=NetworkConfig(hidden=tuple(args.hidden)))
    env = native_env(args.env)  # its sizes
    nets = make_networks(cfg.net, env.action_size)
    hp = sac.SACHParams.create(**SAC_SCRATCH)

    def init(key: jax.Array) -> Trainer:
        k_learner, k_run = jax.random.split(key)
        learner = init_learner(k_learner, nets, sac.ONLINE, hp, env.observation_size, env.action_size, None)
        trainer = Trainer(learner=learner, buffer=replay_init(args.buffer_capacity, env.observation_size,
                                                             env.action_size),
                          key=k_run, step=jnp.zeros((), jnp.int32))
        # Distinct arrays for every leaf (π̄ and π₀ start as the actor's, the target as the critic's): ``learn``
        # donates the whole state, and one buffer cannot be donated twice.
        return jax.tree.map(jnp.array, trainer)

    @functools.partial(jax.jit, static_argnames="deterministic")
    def act(learner: Learner, obs: jax.Array, key: jax.Array, step: jax.Array, deterministic: bool = False):
        """π's action at ``obs`` (sampled with the key folded with ``step``: no host-side key splitting)."""
        return sac.act(nets, learner, obs, jax.random.fold_in(key, step), hp, deterministic)

    @functools.partial(jax.jit, donate_argnums=(0,))  # (in place: the 10⁶-row buffer is not copied every step)
    def learn(trainer: Trainer, transition: Transition) -> tuple[Trainer, dict]:
        """Insert one transition; then, from ``learning_starts`` on, one SAC gradient step on a replay batch."""
        buffer = replay_insert(trainer.buffer, jax.tree.map(lambda x: x[None], transition))
        key, k_batch, k_update = jax.random.split(trainer.key, 3)

        def update(learner):
            batch = replay_sample(k_batch, buffer, None, cfg.batch_size, "online")
            learner, m = sac.update(learner, batch, k_update, jnp.zeros(()), hp, nets, cfg, trainer.step)
            return learner, {k: m[k] for k in ("critic_loss", "q_mean", "alpha_sac")}

        def wait(learner):
            nan = jnp.full((), jnp.nan, jnp.float32)
            return learner, {"critic_loss": nan, "q_mean": nan, "alpha_sac": jnp.exp(learner.log_alpha_sac)}

        learner, m = jax.lax.cond(trainer.step + 1 >= args.learning_starts, update, wait, trainer.learner)
        return Trainer(learner=learner, buffer=buffer, key=key, step=trainer.step + 1), m

    return cfg, hp, init, act, learn


def evaluate(env, act, learner: Learner, episodes: int, key: jax.Array) -> dict:
    """Deterministic episodes to the time limit (or termination): returns, and D4RL's success rule where the task has
    one (Adroit; else the success rate is None)."""
    return native_episodes(env, lambda obs, k, t: act(learner, obs, k, 0, True), jax.random.split(key, episodes))


def train(args: Args) -> list[dict]:
    """Train (or resume), saving a snapshot every ``snapshot_every`` steps; returns the snapshots' records."""
    cfg, hp, init, act, learn = make_trainer(args)
    env, eval_env, spec = native_env(args.env), native_env(args.env), envs.get_spec(args.env)
    trainer = init(jax.random.PRNGKey(args.seed))
    resume = Path(args.resume_dir) / args.env
    if (latest := checkpoints.latest_step(resume)) is not None:
        trainer, _ = checkpoints.restore(latest, trainer)
        print(f"[{args.env}] resuming at step {int(trainer.step)} (a fresh episode)", flush=True)
    # The host's own randomness (episode layouts, warm-up actions, exploration keys) restarts from the step reached:
    # after a resume the episodes differ from an uninterrupted run's.
    key_act, key_reset, key_eval = jax.random.split(jax.random.fold_in(jax.random.PRNGKey(args.seed),
                                                                       int(trainer.step)), 3)
    rng = np.random.default_rng([args.seed, int(trainer.step)])
    episodes = 0
    obs, t, ret, log, t0 = env.reset(jax.random.fold_in(key_reset, episodes)), 0, 0.0, [], time.time()
    train_returns: list[float] = []
    while int(trainer.step) < args.steps:
        if int(trainer.step) < args.learning_starts:  # uniform random actions, as the MJX behaviour runs' warm-up
            action = rng.uniform(-1.0, 1.0, env.action_size).astype(np.float32)
        else:
            action = np.asarray(act(trainer.learner, obs, key_act, trainer.step))
        next_obs, reward, terminal, _ = env.step(action)
        t, ret = t + 1, ret + reward
        timeout = t >= spec.episode_length and not terminal
        trainer, m = learn(trainer, Transition(observations=obs, actions=action.astype(np.float32),
                                               rewards=np.float32(reward), next_observations=next_obs,
                                               terminals=np.float32(terminal), timeouts=np.float32(timeout)))
        obs = next_obs
        if terminal or timeout:
            train_returns.append(ret)
            episodes += 1
            obs, t, ret = env.reset(jax.random.fold_in(key_reset, episodes)), 0, 0.0
        step = int(trainer.step)
        if step % args.snapshot_every == 0:
            ev = evaluate(eval_env, act, trainer.learner, args.eval_episodes, jax.random.fold_in(key_eval, step))
            dt = time.time() - t0
            rec = {"env": args.env, "backend": "native", "step": step, "seed": args.seed,
                   "eval_return_mean": ev["return_mean"], "eval_returns": ev["returns"],
                   "eval_success_rate": ev["success_rate"],
                   "train_return": float(np.mean(train_returns[-20:])) if train_returns else float("nan"),
                   "critic_loss": float(m["critic_loss"]), "alpha_sac": float(m["alpha_sac"]), "seconds": dt,
                   "steps_per_second": args.snapshot_every / dt,
                   "config": {"trainer": "native_behavior", "args": {k: str(v) if isinstance(v, Path) else v
                                                                     for k, v in dataclasses.asdict(args).items()},
                              "finetune": dataclasses.asdict(cfg), "hparams": SAC_SCRATCH},
                   "version": __version__}
            checkpoints.save(snapshot_dir(args.out, args.env, step), trainer.learner.actor, rec)
            checkpoints.save_step(resume, step, trainer, {"step": step, "env": args.env}, keep=1)
            success = "" if ev["success_rate"] is None else f" success {ev['success_rate']:.2f}"
            print(f"[{args.env}] step {step} eval {ev['return_mean']:.1f}{success} train {rec['train_return']:.1f} "
                  f"({rec['steps_per_second']:.0f} steps/s)", flush=True)
            log.append(rec)
            t0 = time.time()
    return log


if __name__ == "__main__":
    import tyro

    train(tyro.cli(Args))
