"""``python -m proto_brax.pretrain``: offline pretraining saved as an orbax bundle (``proto_brax.experiment.pretrain``).

    python -m proto_brax.pretrain --dataset hopper-medium --algo eql --seeds 0 1 2 3 4 --steps 100000 --out DIR
"""

from __future__ import annotations

import sys

import tyro

from proto_brax.experiment.pretrain import PretrainArgs, pretrain
from proto_brax.startup import exit_on_input_error, refuse_repeated


def main(argv: list[str] | None = None) -> None:
    def run():
        refuse_repeated(list(sys.argv[1:] if argv is None else argv), ("--hp",))
        return pretrain(tyro.cli(PretrainArgs, args=argv))

    exit_on_input_error(run, argv)
