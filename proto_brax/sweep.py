"""``python -m proto_brax.sweep`` (the command line: ``proto_brax.cli.sweep``) and the sweep's Python API.

    from proto_brax.sweep import run_sweep, sweep_args
    summary = run_sweep(sweep_args("proto-sac", preset="smoke", out=Path("runs/smoke"), overwrite=True))

The steps behind it are ``proto_brax.experiment``: args -> plan -> run -> summary.
"""

from proto_brax.cli.sweep import main, parse_args
from proto_brax.experiment.args import PRESETS, SweepArgs, sweep_args
from proto_brax.experiment.run import run_sweep

__all__ = ["PRESETS", "SweepArgs", "main", "parse_args", "run_sweep", "sweep_args"]

if __name__ == "__main__":
    from proto_brax.startup import compilation_cache, quiet_start

    quiet_start()
    compilation_cache()
    main()
