"""``python -m proto_brax.pretrain``: offline pretraining saved as an orbax bundle (``proto_brax.experiment.pretrain``).

    python -m proto_brax.pretrain --dataset hopper-medium --algo eql --seeds 0 1 2 3 4 --steps 100000 --out DIR
"""

from __future__ import annotations

import sys

import tyro

from proto_brax.experiment.pretrain import PretrainArgs, pretrain
from proto_brax.startup import exit_on_input_error, refuse_repeated


def _runs_mjx(args: PretrainArgs) -> bool:
    """Whether the bundle's env (--env, else the registered dataset's) steps on MJX; a dataset file that names its
    env inside is not opened here (that would start JAX)."""
    from proto_brax import envs  # here: it imports MJX, after the entry point's quiet start
    from proto_brax.data.generate import dataset_names, parse_name

    env = args.env or (parse_name(args.dataset)[0] if args.dataset in dataset_names() else None)
    return env in envs.REGISTRY and envs.get_spec(env).default_backend == "mjx"


def main(argv: list[str] | None = None) -> None:
    def run():
        refuse_repeated(list(sys.argv[1:] if argv is None else argv), ("--hp",))
        args = tyro.cli(PretrainArgs, args=argv)
        if _runs_mjx(args):  # its evaluations batch MJX episodes on one device: one XLA pool thread, before JAX starts
            from proto_brax.train.grid import size_cpu_pool  # (grid.cpu_pool_threads: jaxlib's deadlock)

            size_cpu_pool(1)
        return pretrain(args)

    exit_on_input_error(run, argv)
