"""``python benchmarks/results_md.py``: benchmarks/RESULTS.md, its aggregate PNG and the README's results summary from
the published locomotion sweeps (the logic: ``proto_brax.analysis.results_md``)."""

import tyro

from proto_brax.analysis.results_md import Args, main

if __name__ == "__main__":
    main(tyro.cli(Args))
