"""A quiet start for the command lines: the known start-up noise of our dependencies, filtered at our entry points only.

``mujoco.mjx`` prints "Failed to import warp" (an optional GPU backend that this CPU suite never uses) on import, and
Brax warns that its own pipelines are no longer maintained each time it loads an MJCF model. Neither is actionable for
a user of the suite. ``quiet_start`` imports MJX with those two lines filtered (anything else it prints passes
through) and ignores that one Brax warning by its message; every other warning stays visible. Importing MJX does not
start JAX's backend, so the commands can still set XLA flags afterwards.
"""

from __future__ import annotations

import contextlib
import io
import sys
import warnings

KNOWN_LINES = ("Failed to import warp:", "Failed to import mujoco_warp:")
BRAX_UNMAINTAINED = "Brax System, piplines and environments are not actively being maintained"


def quiet_start() -> None:
    warnings.filterwarnings("ignore", message=BRAX_UNMAINTAINED, category=UserWarning)
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        import mujoco.mjx  # noqa: F401  (its import prints the warp lines)
    for line in buf.getvalue().splitlines():
        if not line.startswith(KNOWN_LINES):
            print(line, file=sys.stdout)
