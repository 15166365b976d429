"""``python -m proto_brax.pretrain``: offline pretraining saved as an orbax bundle (``proto_brax.experiment.pretrain``).

    python -m proto_brax.pretrain --dataset hopper-medium --algo eql --seeds 0 1 2 3 4 --steps 100000 --out DIR
"""

from __future__ import annotations

import sys
from pathlib import Path

import tyro

from proto_brax.experiment.pretrain import PretrainArgs, pretrain
from proto_brax.startup import exit_on_input_error, refuse_repeated


def _dataset_env(dataset: str) -> str | None:
    """The env a dataset names, read without its rows and without starting JAX: a registered name's, an .npz file's
    metadata entry, an exported Minari dataset's metadata.json; None where only --env can say (a D4RL file, a
    Farama Minari id) or the file is unreadable (loading it then names the fix)."""
    from proto_brax.data.cache import cached_metadata
    from proto_brax.data.dataset import CorruptDatasetError
    from proto_brax.data.generate import dataset_names, parse_name
    from proto_brax.data.minari_io import exported_env

    if dataset in dataset_names():
        return parse_name(dataset)[0]
    path = Path(dataset)
    if path.suffix != ".npz":
        return exported_env(path)
    try:
        return cached_metadata(path).get("env") if path.is_file() else None
    except CorruptDatasetError:
        return None


def _runs_mjx(args: PretrainArgs) -> bool:
    """Whether the bundle's env (--env, else the one the dataset names) steps on MJX."""
    from proto_brax import envs  # here: it imports MJX, after the entry point's quiet start

    env = args.env or _dataset_env(str(args.dataset))
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
