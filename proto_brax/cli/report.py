"""``python -m proto_brax.report DIR [DIR ...]``: figures and a JSON digest of sweep directories
(``proto_brax.analysis.report``: what each file holds)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import tyro

from proto_brax.analysis.report import ReportError, make_report


@dataclasses.dataclass
class ReportArgs:
    """Figures and report.json for sweep directories written by ``python -m proto_brax.sweep``."""

    dirs: tyro.conf.Positional[tuple[Path, ...]]
    """Sweep output directories, one per task."""
    out: Path | None = None
    """Output directory; default: DIR/report of the first DIR."""


def main(argv: list[str] | None = None) -> None:
    args = tyro.cli(ReportArgs, args=argv)
    try:
        make_report(args.dirs, args.out)
    except ReportError as e:
        raise SystemExit(f"error: {e}") from None
