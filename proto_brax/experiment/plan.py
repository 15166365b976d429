"""Plan a sweep: every check of the arguments, the bundle and the dataset, then the program to compile and
config.json's record, before anything is written (``plan_sweep``); ``--pretrain`` makes the bundle first
(``pretrain_into_out``)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from proto_brax.agents.registry import get_method, pretrain_flags
from proto_brax.experiment.args import SweepArgs, grid_axes, sweep_record, validate_args
from proto_brax.experiment.outdir import check_out, layout_record
from proto_brax.files import strict_json, write_json_atomic

REPO_ROOT = Path(__file__).resolve().parents[2]  # the repository: checkpoints/ lives there


def finetune_config(args: SweepArgs):
    from proto_brax.config import FinetuneConfig
    from proto_brax.envs import default_layer_norm
    from proto_brax.networks import NetworkConfig

    method = get_method(args.algo)
    dataset = resolve_dataset(args)
    sampling = args.sampling or ("symmetric" if dataset is not None else "online")
    if sampling != "online" and dataset is None:
        raise ValueError(f"--sampling {sampling} needs offline data: pass --dataset, or use --sampling online.")
    return FinetuneConfig(
        env=args.env, backend=args.backend, algo=method.algo, regularizer=method.regularizer,
        net=NetworkConfig(hidden=tuple(args.hidden), critic_layer_norm=(
            default_layer_norm(args.env) if args.critic_layer_norm is None else args.critic_layer_norm),
            policy=args.policy, num_qs=args.num_qs),
        steps=args.steps, eval_every=args.eval_every, eval_episodes=args.eval_episodes, batch_size=args.batch_size,
        learning_starts=args.learning_starts, updates_per_step=args.updates_per_step, sampling=sampling,
        offline_fraction=args.offline_fraction,
        value_reg_backup=args.value_reg_backup, clipped_double_q=args.clipped_double_q, fidelity=args.fidelity,
    )


def resolve_dataset(args: SweepArgs) -> str | None:
    """'none' -> None; 'auto' -> ENV-medium (AntMaze: ENV-diverse) when registered; else the given name or path."""
    from proto_brax.data.generate import ANTMAZE_ENVS, dataset_names

    if args.dataset in (None, "none"):
        return None
    if args.dataset == "auto":
        name = f"{args.env}-{'diverse' if args.env in ANTMAZE_ENVS else 'medium'}"
        return name if name in dataset_names() else None
    return args.dataset


DEFAULT_DATASET_SIZE = 100_000  # a sweep's default rows of a registered dataset (the registered size where smaller)


def resolve_dataset_size(args: SweepArgs, dataset_name: str | None) -> int:
    """--dataset-size, else 10⁵ capped at a registered dataset's own size (a default must not build a "human" set 40×
    larger than D4RL's 25 episodes). A file or Minari id keeps its own rows whatever this says."""
    from proto_brax.data.generate import dataset_names, default_size, parse_name

    if args.dataset_size is not None:
        return args.dataset_size
    if dataset_name in dataset_names():
        return min(DEFAULT_DATASET_SIZE, default_size(*parse_name(dataset_name)))
    return DEFAULT_DATASET_SIZE


def resolve_checkpoint(args: SweepArgs) -> Path | None:
    """'none' -> None; 'auto' -> the committed bundle of the dataset for the method's bundle kind; else the path.

    A method that needs a bundle (iql, pex, awac, proto-bc) stops with the commands that make one when 'auto' finds
    none; PROTO falls back to a random π₀ (announced)."""
    method = get_method(args.algo)
    if args.checkpoint == "none":
        return None
    if not method.bundles:
        if args.checkpoint != "auto":
            raise ValueError(f"--algo {args.algo} starts from a random init: drop --checkpoint (or use "
                             "--algo direct to finetune a bundle without regularization).")
        return None
    if args.checkpoint == "auto":
        dataset = resolve_dataset(args)
        kind = method.bundles[0]
        if dataset is None or Path(dataset).suffix:
            if method.requires_bundle and args.pretrain is None:
                raise ValueError(f"--algo {args.algo} starts from a {kind} bundle: pass --checkpoint PATH, or a "
                                 f"registered --dataset with a committed bundle.")
            return None
        auto = REPO_ROOT / "checkpoints" / "pretrained" / dataset / method.auto_bundle
        if (auto / "metadata.json").exists():
            return auto
        if args.pretrain is None:  # (with --pretrain the sweep makes its own bundle)
            rel = auto.relative_to(REPO_ROOT)
            extra = "".join(f" {f}" for f in pretrain_flags(args.policy, args.pretrain_hp))
            fix = (f"python -m proto_brax.pretrain --dataset {dataset} --algo {kind}{extra} --out {rel}, or add "
                   f"--pretrain {kind}, or pass --checkpoint PATH")
            if method.requires_bundle:
                raise FileNotFoundError(f"--algo {args.algo}: no committed {kind} bundle for {dataset}. Make one: "
                                        f"{fix}.")
            print(f"no committed {kind} bundle for {dataset}: π₀ is a random init (make one: {fix})", flush=True)
        return None
    return Path(args.checkpoint)


def reward_transform(args: SweepArgs, bundle_meta: dict | None, dataset) -> dict[str, float]:
    """{reward_scale, reward_shift} of the runs: the bundle's, whose critic learnt in those units (an explicit value
    that differs is an error), else the explicit values, else the env's rule on the (raw) dataset."""
    from proto_brax import envs

    if bundle_meta is not None:  # bundles from before the transform existed trained on raw rewards
        b = {"reward_scale": float(bundle_meta.get("reward_scale", 1.0)),
             "reward_shift": float(bundle_meta.get("reward_shift", 0.0))}
        for k, v in (("reward_scale", args.reward_scale), ("reward_shift", args.reward_shift)):
            if v is not None and not np.isclose(v, b[k]):
                raise ValueError(f"--{k.replace('_', '-')} {v}: the bundle was pretrained with {k} {b[k]:.6g} (its "
                                 f"critic is in those units): drop the flag, or pretrain a bundle with it.")
        return b
    scale, shift = envs.reward_transform(args.env, dataset, args.reward_scale, args.reward_shift)
    return {"reward_scale": scale, "reward_shift": shift}


def load_dataset(name_or_path: str | None, size: int | None = None):
    if name_or_path is None:
        return None, None
    from proto_brax.data import cache
    from proto_brax.data.generate import dataset_names

    if name_or_path in dataset_names():
        path = cache.dataset_path(name_or_path, size)
        hint = cache.rebuild_command(name_or_path, size, 0)
        stale = path.exists() and cache.stale_reason(cache.cached_metadata(path, hint))
        if stale or not path.exists():  # made from other behaviour snapshots than the current rule picks, or missing
            state = f"is stale ({stale})" if stale else "is not cached"
            argv = cache.make_argv(name_or_path, size, 0)
            print(f"dataset {name_or_path} {state}: building it (= python -m proto_brax.datasets {' '.join(argv)})",
                  flush=True)
            import subprocess
            import sys

            from proto_brax.data.dataset import load_npz

            # In a process of its own: generation runs under pinned XLA threading (datasets.generation_xla_flags),
            # which this process's jax, already started, may not have.
            subprocess.run([sys.executable, "-m", "proto_brax.datasets", *argv], check=True)
            # what was just built (re-checking it could call it stale again while its behaviour policy trains on)
            return load_npz(path)
    return cache.load_dataset(name_or_path, size)  # a file, or an error naming the problem


def load_checkpoint(path: Path | None, cfg, grid, method_name: str = "proto-sac"):
    """(pretrained, per_run, metadata): one bundle seed is shared by all runs; several are gathered per run."""
    if path is None:
        return None, False, None
    import jax.numpy as jnp

    from proto_brax import checkpoints
    from proto_brax.agents.learner import Pretrained
    from proto_brax.agents.registry import agent
    from proto_brax.envs import make_env

    env = make_env(cfg.env, cfg.backend)
    meta = checkpoints.read_metadata(path)
    checkpoints.validate_bundle(meta, cfg.env, env.observation_size, env.action_size, cfg.net)
    method = get_method(method_name)
    if meta.get("algo") not in method.bundles:
        raise ValueError(f"--algo {method_name} starts from a bundle pretrained with {' or '.join(method.bundles)}, "
                         f"but {path} holds {meta.get('algo')!r}: pass a matching --checkpoint or --pretrain "
                         f"{method.bundles[0]}.")
    state, meta = checkpoints.load_bundle(path)
    algo = agent(cfg.algo)
    value = state.value if algo.value else None
    if algo.value and value is None:
        raise ValueError(f"--algo {method_name} needs a bundle with a value network (IQL); {path} has none.")
    log_alpha = state.log_alpha_sac if algo.temperature else None  # only CQL bundles hold one
    carry = cfg.fidelity.carry_critic_state  # the critic's Adam state and target critic (FIDELITY.md row 5)
    pre = Pretrained(actor=state.actor, critic=state.critic, value=value, log_alpha_sac=log_alpha,
                     critic_target=state.critic_target if carry else None,
                     critic_opt=state.critic_opt if carry else None)
    seeds = list(meta["seeds"])
    if cfg.algo == "off2on":  # the bundle's seeds are one ensemble, shared by every run
        if len(seeds) != cfg.ensemble_size:
            want = " ".join(map(str, range(cfg.ensemble_size)))
            raise ValueError(f"--algo off2on uses the {cfg.ensemble_size} agents of one CQL bundle; {path} has "
                             f"{len(seeds)} seed(s): pretrain with --seeds {want}.")
        return pre, False, meta
    if len(seeds) == 1:
        return jax_tree_index(pre, 0), False, meta
    idx = [seeds.index(s) if s in seeds else s % len(seeds) for s in grid.seeds]
    return jax_tree_index(pre, jnp.asarray(idx)), True, meta


def jax_tree_index(tree, idx):
    import jax

    return jax.tree.map(lambda x: x[idx], tree)


@dataclasses.dataclass
class Plan:
    """A checked sweep, ready to run: everything a run needs, built before --out is touched."""

    args: SweepArgs
    cfg: Any  # FinetuneConfig
    axes: dict[str, list[float]]
    grid: Any  # train.grid.Grid
    ft: Any  # train.online.Finetune (None until --pretrain has made its bundle)
    pretrained: Any
    per_run: bool  # bundle seeds gathered per run (else one shared)
    dataset: Any
    dataset_name: str | None
    config: dict  # config.json
    lead: bool  # this process writes the outputs (process 0)


def plan_sweep(args: SweepArgs) -> Plan:
    """Every check of the command line, the bundle and the dataset, then the compiled-to-be program and config.json's
    record; nothing is written."""
    from proto_brax.train.grid import make_grid

    validate_args(args)
    # the default size resolved (and recorded in config.json as before: 10⁵ unless the registered set is smaller)
    args = dataclasses.replace(args, dataset_size=resolve_dataset_size(args, resolve_dataset(args)))
    cfg = finetune_config(args)
    method = get_method(args.algo)
    axes = grid_axes(args)
    base = {"anneal_horizon": float(args.anneal_horizon or args.steps), **method.hp, **args.hp}
    from proto_brax.agents.registry import agent

    # validated before anything compiles; the leaves are the agent's own HParams fields
    grid = make_grid(axes, list(args.seeds), base=base, hparams=agent(method.algo).hparams)
    sweep_cfg = sweep_record(args)
    import jax

    lead = jax.process_index() == 0  # with --distributed, process 0 writes; the others compute their shards
    layout = {**layout_record(grid.size, jax.devices(), args.block), "processes": jax.process_count()}
    if lead:  # (another process must not look at --out: process 0 may have created it already)
        check_out(args, sweep_cfg, layout)
    if jax.process_count() > 1 and args.resume:
        raise ValueError("--resume is not supported across several processes yet: resume on one host.")
    dataset_name = resolve_dataset(args)
    ckpt = resolve_checkpoint(args)
    if args.pretrain is not None and (dataset_name is None or args.checkpoint not in ("auto", "none")):
        raise ValueError("--pretrain needs --dataset (the data to pretrain on) and no --checkpoint.")
    if args.pretrain is not None and args.pretrain not in method.bundles:
        raise ValueError(f"--algo {args.algo} cannot start from a {args.pretrain} bundle: --pretrain "
                         f"{' or '.join(method.bundles) or '(none: it starts from a random init)'}.")
    # The bundle is validated (and loaded: a few MB) before any dataset is built or read.
    pretrained, per_run, bmeta = load_checkpoint(None if args.pretrain else ckpt, cfg, grid, args.algo)
    from proto_brax.checkpoints import bundle_dataset_record, regenerated_note, validate_bundle_dataset
    from proto_brax.data.generate import dataset_names

    if bmeta is not None and dataset_name in dataset_names():  # by name, before a registered dataset is built;
        validate_bundle_dataset(bmeta, dataset_name)  # a file or Minari id may hold the bundle's rows: by content
    dataset, dmeta = load_dataset(dataset_name, args.dataset_size)  # non-finite values are refused here
    if bmeta is not None and dataset_name is not None:
        validate_bundle_dataset(bmeta, dataset_name, (dmeta or {}).get("content_hash"))
    from proto_brax.agents.registry import agent
    from proto_brax.data.dataset import validate_for_env
    from proto_brax.train.online import make_finetune

    if dataset is not None:  # every check of the data before --out is touched
        from proto_brax.envs import make_env

        env = make_env(cfg.env, cfg.backend)
        validate_for_env(dataset, env.observation_size, env.action_size, str(dataset_name), env_name=cfg.env)
        if agent(cfg.algo).mc_returns and np.unique(np.asarray(grid.hparams.gamma)).size != 1:
            raise ValueError(f"--algo {args.algo} computes the dataset's returns-to-go once: use one gamma.")
    if args.pretrain is None:
        cfg = dataclasses.replace(cfg, **reward_transform(args, bmeta, dataset))
    ft = make_finetune(cfg) if args.pretrain is None else None  # (errors surface here, before --out is written)
    config = {"sweep": sweep_cfg, "method": dataclasses.asdict(method), "finetune": dataclasses.asdict(cfg),
              "grid": list(grid.points),
              "layout": layout,
              "dataset_metadata": dmeta,
              "checkpoint_metadata": bmeta}
    if bmeta is not None and dmeta is not None:
        config["dataset_vs_bundle"] = bundle_dataset_record(bmeta, dmeta)
        if note := regenerated_note(config["dataset_vs_bundle"]):
            print(note, flush=True)
    return Plan(args=args, cfg=cfg, axes=axes, grid=grid, ft=ft, pretrained=pretrained, per_run=per_run,
                dataset=dataset, dataset_name=dataset_name, config=config, lead=lead)


def pretrain_into_out(plan: Plan) -> Plan:
    """--pretrain: the bundle in OUT/pretrained (one bundle seed per run seed; a resumed sweep reuses it), then the
    finetuning program from it."""
    from proto_brax.checkpoints import bundle_dataset_record
    from proto_brax.experiment.pretrain import PretrainArgs, pretrain
    from proto_brax.train.online import make_finetune

    args, cfg = plan.args, plan.cfg
    bundle = Path(args.out) / "pretrained"
    if not (bundle / "metadata.json").exists():
        # Off2On's ensemble is the bundle's seeds (shared by every run); otherwise one bundle seed per run seed.
        seeds = tuple(range(cfg.ensemble_size)) if cfg.algo == "off2on" else tuple(args.seeds)
        pretrain(PretrainArgs(dataset=plan.dataset_name, dataset_size=args.dataset_size, algo=args.pretrain,
                              env=args.env, seeds=seeds,
                              steps=args.pretrain_steps, log_every=min(10_000, args.pretrain_steps),
                              hidden=tuple(args.hidden), critic_layer_norm=cfg.net.critic_layer_norm,
                              policy=cfg.net.policy,
                              reward_scale=args.reward_scale, reward_shift=args.reward_shift,
                              hp=dict(args.pretrain_hp),
                              out=bundle, overwrite=True))
    pretrained, per_run, bmeta = load_checkpoint(bundle, cfg, plan.grid, args.algo)
    cfg = dataclasses.replace(cfg, **reward_transform(args, bmeta, plan.dataset))
    config = {**plan.config, "checkpoint_metadata": bmeta, "finetune": dataclasses.asdict(cfg),
              "dataset_vs_bundle": bundle_dataset_record(bmeta, plan.config["dataset_metadata"])}
    if plan.lead:
        write_json_atomic(Path(args.out) / "config.json", strict_json(config))
    return dataclasses.replace(plan, cfg=cfg, ft=make_finetune(cfg), pretrained=pretrained, per_run=per_run,
                               config=config)
