"""A sweep's summary: per grid point over seeds (final and average scores, mean ± std, IQM with bootstrap CI,
the initial drop), the printed table and throughput, summary.json and the PNG report."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from proto_brax.files import read_jsonl, strict_json, write_json_atomic

if TYPE_CHECKING:
    from proto_brax.experiment.plan import Plan


def episode_stats(env: str, returns, lengths, success_steps=None) -> dict[str, float]:
    """Mean evaluation episode length; on a goal task (``EnvSpec.goal_task``: return 1 at the goal, which ends the
    episode) also the success rate and the mean steps to the goal of the successful episodes (the paper's Fig. 5); on
    a task with a success-step rule (``EnvSpec.success_steps``, Adroit) the success rate by that rule."""
    from proto_brax.envs import get_spec

    spec = get_spec(env)
    returns, lengths = np.asarray(returns), np.asarray(lengths)
    out = {"eval_length": float(lengths.mean())}
    if spec.goal_task:
        success = returns > 0
        out["success_rate"] = float(success.mean())
        out["steps_to_goal"] = float(lengths[success].mean()) if success.any() else float("nan")
    elif spec.success_steps is not None and success_steps is not None:
        out["success_rate"] = float((np.asarray(success_steps) > spec.success_steps).mean())
    return out


def steady_throughput(rows: list[dict], full_updates: int) -> float | None:
    """Mean grid updates/s over the chunks after the first (which includes compilation) whose runs updated at every
    step: a warm-up chunk does fewer updates, or none, in the same time and would under-report it."""
    per_chunk = {r["chunk"]: r["grid_updates_per_s"] for r in rows
                 if r.get("chunk", 0) > 0 and r.get("updates") == full_updates}
    return float(np.mean(list(per_chunk.values()))) if per_chunk else None


def lowest_early_scores(runs: list[list[dict]], fraction: float = 0.1) -> list[float]:
    """The paper's initial drop, per run (its evaluation rows after step 0, sorted by step): the lowest normalized
    score within the first ``fraction`` of the online steps (of the longest run), or the first evaluation's score
    where none falls inside."""
    horizon = max(r["step"] for rs in runs for r in rs)
    return [min([r["normalized_score"] for r in rs if r["step"] <= fraction * horizon] or [rs[0]["normalized_score"]])
            for rs in runs]


def summarize_runs(rows: list[dict], grid_keys: list[str]) -> list[dict]:
    """Per grid point (over seeds): final and average return/normalized score with mean ± std and IQM [95% CI]."""
    from proto_brax.analysis.stats import summarize

    by_point: dict[tuple, dict[int, list[dict]]] = {}
    for r in rows:
        by_point.setdefault(tuple(r[k] for k in grid_keys), {}).setdefault(r["seed"], []).append(r)
    out = []
    for point, seeds in by_point.items():
        initial = [[r for r in rs if r.get("initial")] for rs in seeds.values()]
        runs = [sorted((r for r in rs if not r.get("initial")), key=lambda r: r["step"]) for rs in seeds.values()]
        rec = dict(zip(grid_keys, point))
        rec["seeds"] = sorted(seeds)
        rec["diverged_seeds"] = sorted(s for s, rs in seeds.items() if any(r["diverged"] for r in rs))
        for key in ("eval_return", "normalized_score"):
            rec[f"final_{key}"] = summarize([rs[-1][key] for rs in runs])
            rec[f"average_{key}"] = summarize([np.mean([r[key] for r in rs]) for rs in runs])
        rec["final_dev_pi0"] = summarize([rs[-1]["dev_pi0"] for rs in runs])
        if all("success_rate" in rs[-1] for rs in runs):  # goal tasks and Adroit: success rate
            rec["final_success_rate"] = summarize([rs[-1]["success_rate"] for rs in runs])
        if all("steps_to_goal" in rs[-1] for rs in runs):  # goal tasks: the paper's steps to the goal (Fig. 5)
            rec["final_steps_to_goal"] = summarize([rs[-1]["steps_to_goal"] for rs in runs])
        if all(initial):  # π₀ at step 0, and the initial drop: the lowest score within the first 10% of the run
            rec["initial_normalized_score"] = summarize([i[0]["normalized_score"] for i in initial])
            rec["min_normalized_first_10pct"] = summarize(lowest_early_scores(runs))
        out.append(rec)
    return out


def print_table(summary: list[dict], grid_keys: list[str]) -> None:
    head = " ".join(f"{k:>8}" for k in grid_keys)
    print(f"\n{head} | {'final return':>20} | {'IQM [95% CI]':>26} | {'norm. score':>14} | diverged")
    for rec in summary:
        f = rec["final_eval_return"]
        n = rec["final_normalized_score"]
        vals = " ".join(f"{rec[k]:>8.4g}" for k in grid_keys)
        print(f"{vals} | {f['mean']:>9.1f} ± {f['std']:>8.1f} | {f['iqm']:>8.1f} [{f['iqm_low']:>7.1f}, "
              f"{f['iqm_high']:>7.1f}] | {n['mean']:>6.1f} ± {n['std']:>5.1f} | {rec['diverged_seeds'] or '-'}")


def summarize(plan: Plan, first_chunk_seconds: float | None) -> list[dict]:
    """summary.json, the results table, the throughput line and the PNG report from metrics.jsonl."""
    args, cfg, axes = plan.args, plan.cfg, plan.axes
    out = Path(args.out)
    rows, _ = read_jsonl(out / "metrics.jsonl")  # (null, as the file stores NaN, read back as NaN)
    grid_keys = [k for k in axes if len(axes[k]) > 1] or ["tau"]
    summary = summarize_runs(rows, grid_keys)
    write_json_atomic(out / "summary.json", strict_json({
        "grid_keys": grid_keys, "points": summary, "env": cfg.env, "steps": cfg.steps, "method": args.algo,
        "dataset": plan.dataset_name,
        "first_chunk_seconds_incl_compile": first_chunk_seconds,
    }))
    print_table(summary, grid_keys)
    steady = steady_throughput(rows, cfg.eval_every * cfg.updates_per_step)
    throughput = f"{steady:.0f} updates/s over the grid" if steady else "not measured (no full chunk after the first)"
    if first_chunk_seconds is None:
        print(f"\nno chunk left to run: the sweep in {out} was complete; steady throughput {throughput}")
    else:
        print(f"\ncompile + first chunk: {first_chunk_seconds:.1f} s; steady throughput {throughput}")
    if args.report:
        from proto_brax.analysis.report import make_report

        make_report([out], out / "report", verbose=False)
    print(f"\nwrote {out}/config.json, metrics.jsonl ({len(rows)} rows), summary.json"
          + (", report/ (PNG plots)" if args.report else ""))
    return summary
