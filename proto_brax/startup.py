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


def refuse_repeated(argv: list[str], flags: tuple[str, ...]) -> None:
    """A dict flag (``--hp k v``) given twice keeps only its last occurrence (tyro replaces, it does not merge):
    refuse it, naming the fix, instead of silently dropping the earlier pairs."""
    for flag in flags:
        if argv.count(flag) > 1:
            raise ValueError(f"{flag} is given {argv.count(flag)} times, and only the last would count: give every "
                             f"pair after one {flag} (e.g. {flag} name1 value1 name2 value2).")


def quiet_start() -> None:
    warnings.filterwarnings("ignore", message=BRAX_UNMAINTAINED, category=UserWarning)
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        import mujoco.mjx  # noqa: F401  (its import prints the warp lines)
    for line in buf.getvalue().splitlines():
        if not line.startswith(KNOWN_LINES):
            print(line, file=sys.stdout)
