"""Cost of every sweep method relative to PROTO-SAC on this machine: seconds per 10⁵ online steps (= updates).

Run (from the repository root, venv active)::

    python benchmarks/methods_cost.py                  # hopper, paper sizes (2x256, batch 256); ~15 min on 2 cores
    python benchmarks/methods_cost.py --quick --out /tmp/mc.json   # tiny sizes, end-to-end check

Each method's online program is the sweep's own (``proto_brax.sweep`` builds its ``FinetuneConfig`` from the method's
defaults): one compiled chunk of ``chunk_steps`` env steps, each one env step + replay insert + sample + update, on
hopper with a synthetic offline dataset and randomly initialized networks (costs do not depend on the weights).
Methods that compile to the same program as another (frozen, direct and proto-bc are PROTO-SAC with other traced
values or another bundle) are timed once and reported with it. Programs are timed interleaved (A B C … A B C …)
``reps`` times after a warm-up and the median is taken, so drift of a shared machine hits every ratio alike.
Writes JSON atomically.
"""

from __future__ import annotations

import dataclasses
import datetime
import os
import platform
import sys
from pathlib import Path

import _quiet  # noqa: F401  (first: the quiet start)
import jax
import jax.numpy as jnp
import tyro

from proto_brax import envs
from proto_brax.agents.registry import METHODS, agent, get_method
from proto_brax.analysis.timing import Case, aot, log, run_interleaved, synthetic_transitions, versions
from proto_brax.data.dataset import with_returns_to_go
from proto_brax.experiment.args import sweep_args
from proto_brax.experiment.plan import finetune_config
from proto_brax.files import strict_json, write_json_atomic
from proto_brax.train.online import make_finetune


@dataclasses.dataclass
class Args:
    """Per-method cost benchmark (see the module docstring)."""

    quick: bool = False  # tiny networks and chunks: an end-to-end check; timings are meaningless
    out: str = str(Path(__file__).resolve().parent / "results" / "methods_cost.json")
    env: str = "hopper"
    chunk_steps: int = 2_000  # env steps (= updates) per timed call
    reps: int = 3
    methods: tuple[str, ...] = tuple(METHODS)


def method_config(name: str, args: Args):
    """The sweep's own FinetuneConfig for the method (its sampling follows from its dataset use, as in a sweep)."""
    size = dict(hidden=(32, 32), batch_size=32) if args.quick else {}
    sa = sweep_args(name, env=args.env, steps=args.chunk_steps * 4, eval_every=args.chunk_steps,
                          learning_starts=1, **size)
    cfg = finetune_config(sa)  # reads only the dataset's name, never the data
    # eval_episodes 1 and a 10-step time limit make the end-of-chunk evaluation negligible (env_step computes a reset
    # state every step anyway, so the time limit does not change the cost of a training step).
    return dataclasses.replace(cfg, eval_episodes=1, episode_length=10), sa


def random_bundle(cfg, env, hp):
    """None (a random init), or for a method that carries the critic's pretraining state (the official variants) a
    random bundle holding one: costs do not depend on the weights."""
    if not cfg.fidelity.carry_critic_state:
        return None
    from proto_brax.agents.common import adam
    from proto_brax.agents.learner import Pretrained
    from proto_brax.networks import make_networks

    nets = make_networks(cfg.net, env.action_size)
    obs, act = jnp.zeros((1, env.observation_size)), jnp.zeros((1, env.action_size))
    critic = nets.critic.init(jax.random.PRNGKey(2), obs, act)
    return Pretrained(actor=nets.actor.init(jax.random.PRNGKey(3), obs), critic=critic, critic_target=critic,
                      critic_opt=adam(hp.lr_critic).init(critic))


def main(args: Args) -> dict:
    if envs.get_spec(args.env).default_backend == "mjx":  # before JAX starts its backend: the sweep's MJX flags
        os.environ["XLA_FLAGS"] = envs.mjx_xla_flags()
    rows = args.chunk_steps * 50
    groups: dict = {}
    for name in args.methods:
        cfg, sa = method_config(name, args)
        hp_over = {**get_method(name).hp, "alpha0": sa.alpha0[0], "tau": sa.tau[0]}
        groups.setdefault(cfg, {"methods": [], "hp": hp_over})["methods"].append(name)
    cases = []
    for cfg, g in groups.items():
        ft = make_finetune(cfg)
        env = envs.make_env(cfg.env, cfg.backend)
        data = None if cfg.sampling == "online" else synthetic_transitions(
            jax.random.PRNGKey(0), rows, env.observation_size, env.action_size)
        if data is not None and agent(cfg.algo).mc_returns:
            data = with_returns_to_go(jax.device_get(data), 0.99)
        hp = ft.hparams.create(**g["hp"])
        state = jax.jit(ft.init)(hp, jax.random.PRNGKey(1), random_bundle(cfg, env, hp), data)
        log(f"compiling {g['methods']} ({cfg.algo}, sampling {cfg.sampling}, regularizer {cfg.regularizer})")
        compiled, compile_s = aot(ft.chunk, state, hp, data, jnp.int32(0), donate_argnums=(0,))

        def step(s, compiled=compiled, hp=hp, data=data, cfg=cfg):
            return compiled(s, hp, data, jnp.int32(cfg.eval_every))  # past learning_starts: every step updates

        cases.append((g, Case("+".join(g["methods"]), step, state, cfg.eval_every, compile_s)))
    run_interleaved([c for _, c in cases], args.reps, warmup=1)
    ref = next(c for g, c in cases if "proto-sac" in g["methods"]) if "proto-sac" in args.methods else cases[0][1]
    results = {}
    for g, c in cases:
        for name in g["methods"]:
            results[name] = {"program": c.name, "seconds_per_1e5_steps": 1e5 / c.rate,
                             "ratio_to_proto_sac": ref.rate / c.rate, **c.record()}
    log("method          s / 1e5 steps   × PROTO-SAC")
    for name, r in results.items():
        log(f"{name:<15} {r['seconds_per_1e5_steps']:>12.0f}   {r['ratio_to_proto_sac']:>9.2f}")
    payload = {"benchmark": "methods_cost", "command": " ".join(["python benchmarks/methods_cost.py", *sys.argv[1:]]),
               "env": args.env, "status": f"median of {args.reps} interleaved repetitions; ratios are the result",
               "date": datetime.datetime.now().isoformat(timespec="seconds"),
               "args": dataclasses.asdict(args), "machine": platform.processor() or platform.machine(),
               "loadavg_end": list(os.getloadavg()),
               "versions": versions(), "results": results}
    write_json_atomic(args.out, strict_json(payload))
    log(f"wrote {args.out}")
    return payload


if __name__ == "__main__":
    main(tyro.cli(Args))
