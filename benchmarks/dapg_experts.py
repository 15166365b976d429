"""D4RL's DAPG experts on the suite's capsule model, on cylinders as convex prisms, and on gymnasium-robotics' original
cylinder model (issue 36): what each MJX-compatible stand-in for the cylinders costs the experts the Adroit data come
from.

    python benchmarks/dapg_experts.py                 # pen, door, hammer; 100 episodes each way
    python benchmarks/dapg_experts.py --episodes 5    # a quick look

Each task's snapshot (``checkpoints/behavior/TASK/step_0000000``, written by ``python -m proto_brax.data.dapg``) is run
with sampled and with mean actions on each model, natively, over D4RL's horizon (pen 100, door and hammer 200 steps),
with D4RL's success rule. Writes ``benchmarks/results/dapg_experts.json``.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import _quiet  # noqa: F401  (first: the quiet start)
import tyro

from proto_brax.checkpoints import restore
from proto_brax.data import dapg
from proto_brax.data.generate import list_snapshots
from proto_brax.files import write_json_atomic


@dataclasses.dataclass
class Args:
    tasks: tuple[str, ...] = ("pen", "door", "hammer")
    models: tuple[str, ...] = ("capsule", "prism", "original")
    """capsule: the MJX env's model; prism: cylinders as convex 16-gon prisms; original: gymnasium-robotics'."""
    episodes: int = 100
    seed: int = 0
    out: Path = Path(__file__).resolve().parent / "results" / "dapg_experts.json"


def main(args: Args) -> dict:
    result = {"what": "DAPG experts (hand_dapg) on the suite's capsule model vs gymnasium-robotics' original model: "
                      "success rate by D4RL's rule and returns over D4RL's horizon, native MuJoCo",
              "episodes": args.episodes, "seed": args.seed, "date": time.strftime("%Y-%m-%dT%H:%M:%S"), "tasks": {}}
    for task in args.tasks:
        snap = list_snapshots(task)[-1]
        if snap.metadata.get("policy_class") != dapg.POLICY_CLASS:
            raise SystemExit(f"{snap.path} is not a DAPG expert: python -m proto_brax.data.dapg --task {task} ...")
        params, _ = restore(snap.path, dapg.template(snap.metadata))
        nonlinearity = snap.metadata["dapg"]["nonlinearity"]
        rows = {}
        for model in args.models:
            for sampled in (True, False):
                r = dapg.evaluate(task, params, nonlinearity, args.episodes, args.seed, sampled, model)
                rows[f"{model}/{'sampled' if sampled else 'mean'}"] = r
                print(f"{task:6s} {model:8s} {r['actions']:18s} success {r['success_rate']:.2f}  return "
                      f"{r['return_mean']:8.1f} ± {r['return_std']:7.1f}  normalized {r['normalized']:6.1f}",
                      flush=True)
        result["tasks"][task] = {"snapshot": str(snap.path), **rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out, result)
    return result


if __name__ == "__main__":
    main(tyro.cli(Args))
