"""``python -m proto_brax.sweep``: a τ×η×α₀×seed grid of PROTO finetuning runs as one compiled, sharded program.

Every grid point and seed runs inside one ``jit(vmap(chunk))``; the grid axis is sharded over all devices (on a CPU,
one host device per core). Between chunks the host shows progress, appends evaluation rows to ``metrics.jsonl`` and
checkpoints the whole sweep state with orbax, so ``--resume`` continues an interrupted sweep and ends with the same
results as an uninterrupted one.

Outputs in ``--out``: ``config.json``, ``metrics.jsonl`` (one row per evaluation per run), ``summary.json`` (per grid
point: final and average return / normalized score over seeds, mean ± std, IQM with 95% bootstrap CI) and ``state/``.
This module parses the command line and starts the backend; the sweep itself is ``proto_brax.experiment``.
"""

from __future__ import annotations

import dataclasses
import os
import sys

from proto_brax.agents.registry import METHODS, agent, describe
from proto_brax.experiment.args import GRID_AXES, PRESETS, SweepArgs, validate_args
from proto_brax.experiment.run import run_sweep
from proto_brax.startup import exit_on_input_error, refuse_repeated


def _flag_value(argv: list[str], flag: str) -> str | None:
    for i, a in enumerate(argv):
        if a == flag:
            return argv[i + 1] if i + 1 < len(argv) else ""
        if a.startswith(flag + "="):
            return a.split("=", 1)[1]
    return None


def hparams_help(method) -> str:
    """The method's traced hyper-parameters (its agent's HParams fields) with the values its runs start from."""
    hparams = agent(method.algo).hparams
    values = {**{f.name: f.default for f in dataclasses.fields(hparams)}, **method.hp}
    own_flags = (*GRID_AXES, "anneal_horizon")  # set by --tau, --eta, --alpha0, --anneal-horizon
    listed = ", ".join(f"{k} {v:g}" for k, v in values.items() if k not in own_flags)
    return (f"Its traced hyper-parameters besides --tau/--eta/--alpha0/--anneal-horizon ({hparams.__name__}; set "
            f"with --hp NAME VALUE, grid with --grid NAME=V1,V2): {listed}.")


def parse_args(argv: list[str] | None = None) -> SweepArgs:
    """tyro CLI. ``--preset NAME`` then ``--algo NAME`` set the defaults that the other flags override."""
    import tyro

    argv = list(sys.argv[1:] if argv is None else argv)
    refuse_repeated(argv, ("--hp", "--pretrain-hp"))
    defaults = SweepArgs()
    if "--preset" in argv:
        i = argv.index("--preset")
        if i + 1 >= len(argv) or argv[i + 1] not in PRESETS:
            names = ", ".join(f"{k} ({v.summary})" for k, v in PRESETS.items())
            raise SystemExit(f"--preset needs one of: {names}")
        defaults = PRESETS[argv[i + 1]].apply(SweepArgs())
        del argv[i:i + 2]
    algo = _flag_value(argv, "--algo")
    description = f"{SweepArgs.__doc__}"
    if algo is not None:
        if algo not in METHODS:
            raise SystemExit(f"--algo needs one of: {describe()}")
        method = METHODS[algo]
        defaults = dataclasses.replace(defaults, algo=algo, **method.defaults)
        description += f" --algo {algo}: {method.summary}."
        if "-h" in argv or "--help" in argv:  # (the agent's module imports JAX: only when help is shown)
            description += f" {hparams_help(method)}"
    presets = "; ".join(f"{k}: {v.summary}" for k, v in PRESETS.items())
    description += f" Presets (--preset NAME, before other flags): {presets}."
    if "-h" in argv or "--help" in argv:  # the registry imports Brax: only when help is shown
        from proto_brax.envs import REGISTRY

        description += f" Envs (--env): {', '.join(REGISTRY)}."
    return tyro.cli(SweepArgs, default=defaults, args=argv, description=description)


def start_distributed(args: SweepArgs) -> None:
    """jax.distributed.initialize() from the flags, each missing one left to jax's cluster detection (SLURM, Open
    MPI, JAX_COORDINATOR_ADDRESS)."""
    import jax

    kw = {k: v for k, v in (("coordinator_address", args.coordinator), ("num_processes", args.num_processes),
                            ("process_id", args.process_id)) if v is not None}
    if args.coordinator is not None and (args.num_processes is None or args.process_id is None):
        raise ValueError("--coordinator needs --num-processes N and --process-id I too (the same command on every "
                         "process, each with its own --process-id).")
    jax.distributed.initialize(**kw)


def main(argv: list[str] | None = None) -> None:
    def run() -> None:
        args = parse_args(argv)
        validate_args(args)  # before any backend starts
        # Before JAX initializes its backend: host devices for sharding on CPU, and the scheduler fix MJX needs.
        from proto_brax import envs
        from proto_brax.train.grid import size_cpu_pool, use_host_devices

        mjx = (args.backend or envs.get_spec(args.env).default_backend) == "mjx"
        if mjx:
            os.environ["XLA_FLAGS"] = envs.mjx_xla_flags()
        if args.distributed or args.coordinator is not None:
            if args.devices is not None:  # (use_host_devices would start the backend: initialize() must come first)
                import jax

                jax.config.update("jax_num_cpu_devices", args.devices)
                size_cpu_pool(args.devices, spare_worker=mjx)
            start_distributed(args)
        else:
            use_host_devices(args.devices, spare_worker=mjx)
        run_sweep(args)

    exit_on_input_error(run, argv)
