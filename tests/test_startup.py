"""The command lines start quietly: MJX's warp lines and Brax's unmaintained-pipelines warning are filtered, at our
entry points only, and other output and warnings still get through."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SCRIPT = """
import warnings
{start}
from proto_brax import envs
envs.make_env("hopper")  # loads an MJCF model: Brax's warning
warnings.warn("a real warning")
print("done")
"""


def _run(start: str) -> str:
    out = subprocess.run([sys.executable, "-c", SCRIPT.format(start=start)], capture_output=True, text=True,
                         check=True)
    return out.stdout + out.stderr


def test_quiet_start_filters_only_the_known_noise():
    noisy = _run("")
    assert "Failed to import warp" in noisy and "not actively being maintained" in noisy  # what is filtered exists
    quiet = _run("from proto_brax.startup import quiet_start; quiet_start()")
    assert "warp" not in quiet and "not actively being maintained" not in quiet
    assert "a real warning" in quiet and "done" in quiet


def test_a_repeated_dict_flag_is_refused_not_silently_dropped():
    """tyro keeps only the last of two --hp flags: the CLIs refuse the repetition, naming the fix; one --hp with
    several pairs still parses to all of them."""
    import pytest

    from proto_brax import sweep

    with pytest.raises(ValueError, match="--hp is given 2 times"):
        sweep.parse_args(["--hp", "lr_actor", "1e-4", "--hp", "gamma", "0.9"])
    with pytest.raises(ValueError, match="--pretrain-hp is given 2 times"):
        sweep.parse_args(["--pretrain-hp", "alpha", "1", "--pretrain-hp", "eql_z_clip", "7"])
    assert sweep.parse_args(["--hp", "lr_actor", "1e-4", "gamma", "0.9"]).hp == {"lr_actor": 1e-4, "gamma": 0.9}


def test_every_benchmark_script_starts_quietly():
    """Each benchmark driver imports ``_quiet`` (the quiet start) before any import that may load MuJoCo or Brax:
    top-level imports of jax, brax, mujoco, proto_brax or another script, and imports inside functions."""
    import ast
    from pathlib import Path

    heavy = ("jax", "brax", "mujoco", "proto_brax", "throughput", "numpy")
    for path in sorted((Path(__file__).resolve().parents[1] / "benchmarks").glob("*.py")):
        if path.name == "_quiet.py":
            continue
        names = [(node.lineno, alias.name if isinstance(node, ast.Import) else node.module or "")
                 for node in ast.walk(ast.parse(path.read_text())) if isinstance(node, (ast.Import, ast.ImportFrom))
                 for alias in (node.names if isinstance(node, ast.Import) else node.names[:1])]
        light = ("proto_brax.analysis.results_md",)  # RESULTS.md's driver loads neither MuJoCo nor Brax
        loads = [line for line, name in names if name.split(".")[0] in heavy and name not in light]
        if not loads:
            continue
        quiet = [line for line, name in names if name == "_quiet"]
        assert quiet and quiet[0] < min(loads), f"{path.name}: import _quiet before line {min(loads)}"


def test_every_python_m_entry_point_starts_quietly():
    """Each package module runnable with ``python -m`` (an ``if __name__ == "__main__":`` block, or a package's
    ``__main__.py``) prints neither MJX's warp lines nor Brax's unmaintained-pipelines warning: run with --help."""
    import ast
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    modules = []
    for path in sorted((root / "proto_brax").rglob("*.py")):
        tree = ast.parse(path.read_text())
        if path.name == "__main__.py" or any(isinstance(n, ast.If) and "__main__" in ast.unparse(n.test)
                                             for n in tree.body):
            parts = path.relative_to(root).with_suffix("").parts
            modules.append(".".join(parts[:-1] if parts[-1] == "__main__" else parts))
    assert {"proto_brax.sweep", "proto_brax.data.behavior", "proto_brax.data.native_behavior",
            "proto_brax.checkpoints"} <= set(modules)
    for module in modules:
        p = subprocess.run([sys.executable, "-m", module, "--help"], capture_output=True, text=True, cwd=root,
                           timeout=300)
        out = p.stdout + p.stderr
        assert "warp" not in out and "not actively being maintained" not in out, (module, out[:300])


def test_the_commands_turn_on_jaxs_persistent_compilation_cache(tmp_path, monkeypatch):
    """``python -m proto_brax.sweep`` / ``pretrain`` call ``startup.compilation_cache``: JAX's persistent cache at
    $PROTO_BRAX_JAX_CACHE (default under ~/.cache/proto_brax), off when the variable is empty."""
    import jax

    from proto_brax import startup

    before = (jax.config.jax_compilation_cache_dir, jax.config.jax_persistent_cache_min_compile_time_secs)
    try:
        monkeypatch.setenv(startup.CACHE_VAR, str(tmp_path / "jc"))
        assert startup.compilation_cache() == str(tmp_path / "jc")
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "jc")
        monkeypatch.setenv(startup.CACHE_VAR, "")
        jax.config.update("jax_compilation_cache_dir", before[0])
        assert startup.compilation_cache() is None and jax.config.jax_compilation_cache_dir == before[0]
        monkeypatch.delenv(startup.CACHE_VAR)
        monkeypatch.setenv("HOME", str(tmp_path))
        assert startup.compilation_cache() == str(tmp_path / ".cache" / "proto_brax" / "jax")
    finally:
        jax.config.update("jax_compilation_cache_dir", before[0])
        jax.config.update("jax_persistent_cache_min_compile_time_secs", before[1])
    for module in ("sweep", "pretrain"):
        source = (Path(__file__).resolve().parents[1] / "proto_brax" / f"{module}.py").read_text()
        assert "compilation_cache()" in source.split('if __name__ == "__main__":')[1]
