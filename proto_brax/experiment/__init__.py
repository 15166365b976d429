"""A sweep as data and steps: ``args`` (SweepArgs, presets, grid axes), ``plan`` (every check, nothing written),
``outdir`` (what --out may hold, --resume and --overwrite), ``run`` (chunks, metrics, checkpoints; ``run_sweep``) and
``summary`` (per grid point over seeds, summary.json, the report). The command line is ``proto_brax.cli.sweep``."""
