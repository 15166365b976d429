"""``python -m proto_brax.pretrain`` (the command line: ``proto_brax.cli.pretrain``) and pretraining's Python API.

    from proto_brax.pretrain import PretrainArgs, pretrain
    meta = pretrain(PretrainArgs(dataset="hopper-medium", algo="eql", seeds=(0, 1, 2, 3, 4)))

The work is ``proto_brax.experiment.pretrain``.
"""

from proto_brax.cli.pretrain import main
from proto_brax.experiment.pretrain import PretrainArgs, pretrain

__all__ = ["PretrainArgs", "main", "pretrain"]

if __name__ == "__main__":
    from proto_brax.startup import compilation_cache, quiet_start

    quiet_start()
    compilation_cache()
    main()
