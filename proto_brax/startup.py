"""What every command line shares: a quiet start (the known start-up noise of our dependencies, filtered at our entry
points only), one-line input errors, and the refusal of a repeated dict flag.

``mujoco.mjx`` prints "Failed to import warp" (an optional GPU backend that this CPU suite never uses) on import, and
Brax warns that its own pipelines are no longer maintained each time it loads an MJCF model. Neither is actionable for
a user of the suite. ``quiet_start`` imports MJX with those two lines filtered (anything else it prints passes
through) and ignores that one Brax warning by its message; every other warning stays visible. Importing MJX does not
start JAX's backend, so the commands can still set XLA flags afterwards.
"""

from __future__ import annotations

import contextlib
import io
import os
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


CACHE_VAR = "PROTO_BRAX_JAX_CACHE"


def compilation_cache() -> str | None:
    """Turn on JAX's persistent compilation cache at $PROTO_BRAX_JAX_CACHE (default ~/.cache/proto_brax/jax; an
    empty value leaves it off) and return its folder. A resumed sweep, or another sweep of the same program (Frozen
    and direct are PROTO's program with other traced values), loads its compiled chunks instead of compiling them
    again: an MJX hand's chunk takes several minutes to compile here (docs/MEASUREMENTS.md). JAX keys each entry on
    the program, the XLA flags, the device and the versions, so a changed program compiles anew."""
    path = os.environ.get(CACHE_VAR, os.path.join(os.path.expanduser("~"), ".cache", "proto_brax", "jax"))
    if not path:
        return None
    import jax

    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)  # JAX's default: skip the cheap ones
    return path


def debug_enabled(argv: list[str] | None = None) -> bool:
    """Tracebacks of input errors: --debug on the command line or PROTO_BRAX_DEBUG=1 in the environment."""
    argv = sys.argv[1:] if argv is None else argv
    return "--debug" in argv or os.environ.get("PROTO_BRAX_DEBUG", "") not in ("", "0")


# Errors that describe a bad input (flag, file, directory) and name the fix: one line, no traceback, exit status 2.
INPUT_ERRORS = (ValueError, FileNotFoundError, FileExistsError, NotADirectoryError, IsADirectoryError)


def exit_on_input_error(fn, argv: list[str] | None = None):
    """Run ``fn()``; an input error prints ``error: MESSAGE`` and exits with status 2 (the traceback with --debug or
    PROTO_BRAX_DEBUG=1)."""
    try:
        return fn()
    except INPUT_ERRORS as e:
        if debug_enabled(argv):
            raise
        print(f"error: {e}\n(the traceback: rerun with --debug or PROTO_BRAX_DEBUG=1)", file=sys.stderr, flush=True)
        raise SystemExit(2) from None
