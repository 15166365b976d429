"""The published locomotion benchmark: its datasets, its methods and the paper's ablations (appendix), run by
``benchmarks/locomotion.py`` and reported by ``proto_brax.analysis.results_md``."""

from __future__ import annotations

from proto_brax.agents.registry import METHODS, Method
from proto_brax.sweep import PRESETS

DATASETS = tuple(f"{env}-{kind}" for env in ("hopper", "walker2d", "halfcheetah", "ant")
                 for kind in ("medium", "medium-replay", "random"))
PAPER_METHODS = ("proto-sac", "frozen", "direct", "iql", "sac-scratch", "proto-td3", "proto-bc")
PRESET = "paper-mujoco-100k"
TAU0, ETA0 = PRESETS[PRESET][1]["tau"][0], PRESETS[PRESET][1]["eta"][0]  # the ablations' middle values (proto-sac)
# Ablation -> the sweep flag and its two non-default values (0.5 and 2 × τ₀; η 0.8 and 1.0).
ABLATIONS = {"ablate-tau": ("--tau", (0.5 * TAU0, 2 * TAU0)), "ablate-eta": ("--eta", (0.8, 1.0))}


def method_of(name: str) -> Method:
    """The sweep method a runner method name stands for (an ablation is a PROTO-SAC sweep)."""
    return METHODS["proto-sac" if name in ABLATIONS else name]
