"""Figures and a JSON digest of one or more sweep directories (``python -m proto_brax.report DIR [DIR ...]``,
``proto_brax.cli.report``).

Each DIR is the ``--out`` of ``python -m proto_brax.sweep`` (one task per DIR). Written to ``--out`` (default:
``DIR/report`` of the first DIR), every file atomically (temp file + ``os.replace``):

* ``curves.png``     learning curves per grid point, one subplot per task: mean over seeds and the min–max band;
* ``aggregate.png``  per grid point present in every task, the IQM over all (task, seed) runs at each evaluation
  index with a 95% percentile-bootstrap band (:func:`proto_brax.analysis.stats.iqm_ci`);
* ``heatmap.png``    τ×η map of the final score (mean over seeds of the last evaluation), per task and α₀;
  skipped (with a note) where a task has fewer than 2 τ or 2 η values;
* ``deviation.png``  PROTO's Figure 7: deviation from π₀ (``dev_pi0`` at the last evaluation) against the final
  score, one point per run, coloured by grid point;
* ``cost.png``       updates/s and wall time per 10⁶ updates per task (mean over chunks after the first, which
  includes compilation); the same table is printed;
* ``report.json``    all the numbers behind the figures, the diverged runs and the list of files written.

The score is the D4RL-style normalized score where the env has reference returns, else the evaluation return.
Runs with any ``diverged`` row are left out of curves, aggregates, heat maps and the deviation plot, and listed.
NaN is stored as ``null`` in report.json.
"""

from __future__ import annotations

import dataclasses
import gzip
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from proto_brax.files import atomic_write, nan_for_null, strict_json

GRID_AXES = ("tau", "eta", "alpha0")
REQUIRED_KEYS = ("chunk", "run", "seed", "tau", "eta", "alpha0", "step", "eval_return", "normalized_score",
                 "dev_pi0", "diverged", "grid_updates_per_s")
SWEEP_HINT = "run python -m proto_brax.sweep ... --out {dir} first"
PNGS = ("curves.png", "aggregate.png", "heatmap.png", "deviation.png", "cost.png")


class ReportError(ValueError):
    """Input that is not a (usable) sweep directory."""


# --------------------------------------------------------------------------------------------------------- loading


@dataclasses.dataclass
class Run:
    run: int
    seed: int
    point: tuple[float, float, float]  # (tau, eta, alpha0)
    rows: list[dict]  # sorted by step

    @property
    def label(self) -> str:
        return point_label(self.point)

    @property
    def diverged(self) -> bool:
        return any(bool(r["diverged"]) for r in self.rows)


@dataclasses.dataclass
class Sweep:
    path: Path
    env: str
    name: str
    config: dict
    summary: dict | None
    rows: list[dict]
    runs: list[Run]
    metric: str  # "normalized_score" or "eval_return"

    @property
    def ok_runs(self) -> list[Run]:
        return [r for r in self.runs if not r.diverged]

    @property
    def axes(self) -> dict[str, list[float]]:
        return {k: sorted({r.point[i] for r in self.runs}) for i, k in enumerate(GRID_AXES)}


def point_label(point) -> str:
    tau, eta, alpha0 = point
    return f"τ={tau:g} η={eta:g} α₀={alpha0:g}"


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ReportError(f"{path} is not valid JSON ({e}).") from None


def load_sweep(path: str | os.PathLike) -> Sweep:
    """Read config.json, metrics.jsonl and (if the sweep finished) summary.json of one sweep directory."""
    path = Path(path)
    hint = SWEEP_HINT.format(dir=path)
    if not path.is_dir():
        raise ReportError(f"not a sweep directory: {path} does not exist or is not a directory; {hint}.")
    metrics = path / "metrics.jsonl"
    if not metrics.is_file() and (path / "metrics.jsonl.gz").is_file():  # as benchmarks publish them
        metrics = path / "metrics.jsonl.gz"
    if not metrics.is_file():
        raise ReportError(f"not a sweep directory: {path} has no metrics.jsonl; {hint}.")
    config = _read_json(path / "config.json") if (path / "config.json").is_file() else {}
    summary = _read_json(path / "summary.json") if (path / "summary.json").is_file() else None
    if isinstance(summary, dict) and "points" in summary:  # strict JSON stores NaN statistics as null
        summary["points"] = nan_for_null(summary["points"])
    rows: dict[tuple[int, int], dict] = {}
    text = gzip.decompress(metrics.read_bytes()).decode() if metrics.suffix == ".gz" else metrics.read_text()
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            row = nan_for_null(json.loads(line))  # (NaN is stored as null: strict JSON)
        except json.JSONDecodeError as e:
            raise ReportError(f"{metrics}:{n} is not a JSON row ({e}).") from None
        missing = [k for k in REQUIRED_KEYS if k not in row]
        if missing:
            raise ReportError(f"{metrics}:{n} lacks the key(s) {missing}: not a proto_brax.sweep metrics file.")
        rows[(int(row["run"]), int(row["chunk"]))] = row  # a re-logged chunk (resume) replaces the older row
    if not rows:
        raise ReportError(f"{metrics} is empty: the sweep has not finished its first evaluation chunk; "
                          f"wait for it or {hint}.")
    by_run: dict[int, list[dict]] = {}
    for (run, _), row in sorted(rows.items()):
        by_run.setdefault(run, []).append(row)
    runs = []
    for run, rs in sorted(by_run.items()):
        rs.sort(key=lambda r: r["step"])
        point = tuple(float(rs[0][k]) for k in GRID_AXES)
        runs.append(Run(run=run, seed=int(rs[0]["seed"]), point=point, rows=rs))
    env = (summary or {}).get("env") or config.get("sweep", {}).get("env") or path.name
    all_rows = [r for rs in by_run.values() for r in rs]
    finite_norm = any(math.isfinite(float(r["normalized_score"])) for r in all_rows)
    name = env if path.name in (env, "") else f"{env} ({path.name})"
    return Sweep(path=path, env=env, name=name, config=config, summary=summary, rows=all_rows, runs=runs,
                 metric="normalized_score" if finite_norm else "eval_return")


# ------------------------------------------------------------------------------------------------------- numbers


def _f(x) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return float("nan")


def curves(sweep: Sweep) -> dict[str, dict]:
    """Per grid point label: steps, mean / min / max over non-diverged seeds of the sweep's score metric."""
    out = {}
    for label in _labels(sweep.runs):
        runs = [r for r in sweep.ok_runs if r.label == label]
        if not runs:
            continue
        steps = sorted({int(row["step"]) for r in runs for row in r.rows})
        m = np.full((len(runs), len(steps)), np.nan)
        for i, r in enumerate(runs):
            for row in r.rows:
                m[i, steps.index(int(row["step"]))] = _f(row[sweep.metric])
        with np.errstate(all="ignore"), _quiet():
            out[label] = {"step": steps, "mean": np.nanmean(m, 0).tolist(), "min": np.nanmin(m, 0).tolist(),
                          "max": np.nanmax(m, 0).tolist(), "seeds": [r.seed for r in runs]}
    return out


def aggregate(sweeps: list[Sweep]) -> dict:
    """IQM [95% bootstrap CI] over all (task, seed) runs per grid point label present in every task."""
    from proto_brax.analysis.stats import iqm_ci

    metric = "normalized_score" if all(s.metric == "normalized_score" for s in sweeps) else "eval_return"
    common = [lab for lab in _labels(sweeps[0].runs) if all(lab in {r.label for r in s.runs} for s in sweeps)]
    schedules = {tuple(int(row["step"]) for row in r.rows) for s in sweeps for r in s.ok_runs}
    shared_steps = list(next(iter(schedules))) if len(schedules) == 1 else None
    points = []
    for label in common:
        runs = [(s, r) for s in sweeps for r in s.ok_runs if r.label == label]
        n_eval = min((len(r.rows) for _, r in runs), default=0)
        rec = {"label": label, **dict(zip(GRID_AXES, next(r.point for s in sweeps for r in s.runs
                                                           if r.label == label))),
               "n_runs": len(runs), "runs": [{"task": s.name, "run": r.run, "seed": r.seed} for s, r in runs],
               "eval_index": list(range(n_eval)), "step": shared_steps[:n_eval] if shared_steps else None,
               "iqm": [], "low": [], "high": []}
        for k in range(n_eval):
            m, lo, hi = iqm_ci([_f(r.rows[k][metric]) for _, r in runs])
            rec["iqm"].append(m)
            rec["low"].append(lo)
            rec["high"].append(hi)
        points.append(rec)
    note = None
    if metric == "eval_return":
        no_ref = [s.name for s in sweeps if s.metric != "normalized_score"]
        note = f"normalized scores are NaN for {', '.join(no_ref)}: eval returns aggregated instead"
    return {"metric": metric, "note": note, "tasks": [s.name for s in sweeps], "points": points,
            "skipped_labels": sorted({r.label for s in sweeps for r in s.runs} - set(common))}


def final_scores(sweep: Sweep) -> list[dict]:
    """One record per run: grid point, seed, final score and dev_pi0 at the last evaluation, diverged flag."""
    out = []
    for r in sweep.runs:
        last = r.rows[-1]
        out.append({"run": r.run, "seed": r.seed, "label": r.label, **dict(zip(GRID_AXES, r.point)),
                    "step": int(last["step"]), "final_score": _f(last[sweep.metric]),
                    "dev_pi0": _f(last["dev_pi0"]), "diverged": r.diverged})
    return out


def heatmap(sweep: Sweep) -> dict:
    """τ×η matrices (rows τ, columns η) of the mean over non-diverged seeds of the final score, one per α₀."""
    axes = sweep.axes
    if len(axes["tau"]) < 2 or len(axes["eta"]) < 2:
        return {"skipped": f"{sweep.name}: needs at least 2 τ and 2 η values (has τ {axes['tau']}, "
                           f"η {axes['eta']})"}
    finals = final_scores(sweep)
    maps = []
    for a0 in axes["alpha0"]:
        mean = np.full((len(axes["tau"]), len(axes["eta"])), np.nan)
        n = np.zeros(mean.shape, int)
        n_div = np.zeros(mean.shape, int)
        for i, tau in enumerate(axes["tau"]):
            for j, eta in enumerate(axes["eta"]):
                cell = [f for f in finals if (f["tau"], f["eta"], f["alpha0"]) == (tau, eta, a0)]
                vals = [f["final_score"] for f in cell if not f["diverged"] and math.isfinite(f["final_score"])]
                n[i, j], n_div[i, j] = len(vals), sum(f["diverged"] for f in cell)
                if vals:
                    mean[i, j] = float(np.mean(vals))
        maps.append({"alpha0": a0, "mean": mean.tolist(), "n_seeds": n.tolist(), "n_diverged": n_div.tolist()})
    return {"tau": axes["tau"], "eta": axes["eta"], "maps": maps}


def cost(sweep: Sweep) -> dict:
    """Grid throughput: updates/s as the mean of grid_updates_per_s over chunks after the first (compilation).

    A sweep merged from one-seed parts (``locomotion_plan.merge_parts``; its layout says ``runs_per_program`` 1) ran
    as one-run programs: a chunk's rate is the mean over its parts, and it is the rate per run."""
    by_chunk: dict[int, list[float]] = {}
    for row in sweep.rows:
        if int(row["chunk"]) >= 0:  # chunk −1 is π₀'s evaluation at step 0: no updates
            by_chunk.setdefault(int(row["chunk"]), []).append(_f(row["grid_updates_per_s"]))
    # a one-program sweep logs one value per chunk (on each run's row): taken as it is, not re-rounded by a mean
    per_chunk = {c: v[0] if len(set(v)) == 1 else float(np.mean(v)) for c, v in by_chunk.items()}
    chunks = sorted(per_chunk)
    later = [per_chunk[c] for c in chunks[1:] if math.isfinite(per_chunk[c])]
    used = later or [per_chunk[c] for c in chunks[:1] if math.isfinite(per_chunk[c])]
    ups = float(np.mean(used)) if used else float("nan")
    n_runs = len(sweep.runs)
    per_program = (sweep.config.get("layout") or {}).get("runs_per_program") or n_runs
    return {
        "task": sweep.name, "env": sweep.env, "n_runs": n_runs, "n_chunks": len(chunks),
        "chunks_used": chunks[1:] if later else chunks[:1], "includes_compile": not later,
        "updates_per_s": ups, "updates_per_s_per_run": ups / per_program if per_program else float("nan"),
        "seconds_per_1e6_updates": 1e6 / ups if ups > 0 else float("nan"),
        "first_chunk_updates_per_s": per_chunk[chunks[0]],
        "first_chunk_seconds_incl_compile": _f((sweep.summary or {}).get("first_chunk_seconds_incl_compile")),
        "grid_updates_per_s_by_chunk": [per_chunk[c] for c in chunks],
    }


def print_cost_table(costs: list[dict]) -> None:
    w = max([len(c["task"]) for c in costs] + [4])
    print(f"\n{'task':<{w}} | {'runs':>4} | {'updates/s (grid)':>16} | {'updates/s/run':>13} | "
          f"{'s per 1e6 updates':>17} | {'1st chunk s (compile)':>21}")
    for c in costs:
        note = " *" if c["includes_compile"] else ""
        print(f"{c['task']:<{w}} | {c['n_runs']:>4} | {c['updates_per_s']:>16.1f} | "
              f"{c['updates_per_s_per_run']:>13.1f} | {c['seconds_per_1e6_updates']:>17.1f} | "
              f"{c['first_chunk_seconds_incl_compile']:>21.1f}{note}")
    if any(c["includes_compile"] for c in costs):
        print("* single chunk: the rate includes compilation")


# ------------------------------------------------------------------------------------------------------- figures


class _quiet:
    """Silence numpy's all-NaN-slice RuntimeWarnings."""

    def __enter__(self):
        import warnings

        self._w = warnings.catch_warnings()
        self._w.__enter__()
        warnings.simplefilter("ignore", RuntimeWarning)

    def __exit__(self, *exc):
        self._w.__exit__(*exc)


def _labels(runs: list[Run]) -> list[str]:
    return [point_label(p) for p in sorted({r.point for r in runs})]


def _colors(labels: list[str]) -> dict[str, Any]:
    from matplotlib import colormaps

    cmap = colormaps["tab10" if len(labels) <= 10 else "tab20"]
    return {lab: cmap(i % cmap.N) for i, lab in enumerate(labels)}


def _metric_name(metric: str) -> str:
    return "normalized score" if metric == "normalized_score" else "eval return"


def _figure(n_panels: int, panel_w=5.0, panel_h=3.8, ncols_max=3):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    ncols = min(n_panels, ncols_max)
    nrows = math.ceil(n_panels / ncols)
    fig = Figure(figsize=(panel_w * ncols, panel_h * nrows), layout="constrained")
    FigureCanvasAgg(fig)  # Agg backend, without touching pyplot's global state
    axs = fig.subplots(nrows, ncols, squeeze=False).ravel()
    for ax in axs[n_panels:]:
        ax.set_visible(False)
    return fig, axs[:n_panels]


def _save(fig, path: Path) -> None:
    with atomic_write(path, "wb") as f:
        fig.savefig(f, format="png", dpi=110)


def plot_curves(sweeps: list[Sweep], curve_data: list[dict], colors: dict, path: Path) -> None:
    fig, axs = _figure(len(sweeps))
    for ax, s, cd in zip(axs, sweeps, curve_data):
        for label, c in cd.items():
            x = np.asarray(c["step"])
            ax.plot(x, c["mean"], color=colors[label], label=f"{label} (n={len(c['seeds'])})", marker=".")
            ax.fill_between(x, c["min"], c["max"], color=colors[label], alpha=0.2, linewidth=0)
        n_div = sum(r.diverged for r in s.runs)
        ax.set_title(s.name + (f" — {n_div} diverged run(s) excluded" if n_div else ""))
        ax.set_xlabel("env step")
        ax.set_ylabel(_metric_name(s.metric) + " (mean, min–max over seeds)")
        ax.grid(alpha=0.3)
        if cd:
            ax.legend(fontsize=7)
        else:
            ax.text(0.5, 0.5, "all runs diverged", ha="center", va="center", transform=ax.transAxes)
    fig.suptitle("Learning curves per grid point")
    _save(fig, path)


def plot_aggregate(agg: dict, colors: dict, path: Path) -> None:
    fig, (ax,) = _figure(1, panel_w=7.5, panel_h=4.8)
    for p in agg["points"]:
        x = np.asarray(p["step"] if p["step"] is not None else p["eval_index"])
        ax.plot(x, p["iqm"], color=colors.get(p["label"]), marker=".", label=f"{p['label']} ({p['n_runs']} runs)")
        ax.fill_between(x, p["low"], p["high"], color=colors.get(p["label"]), alpha=0.2, linewidth=0)
    shared = bool(agg["points"]) and agg["points"][0]["step"] is not None
    ax.set_xlabel("env step" if shared else "evaluation index")
    ylabel = f"IQM {_metric_name(agg['metric'])} (95% bootstrap CI)"
    if agg["metric"] == "eval_return":
        ylabel += "\n(returns: normalized scores are NaN)"
    ax.set_ylabel(ylabel)
    ax.set_title(f"Aggregate over {len(agg['tasks'])} task(s): {', '.join(agg['tasks'])}", fontsize=10)
    ax.grid(alpha=0.3)
    if agg["points"]:
        ax.legend(fontsize=7)
    else:
        ax.text(0.5, 0.5, "no grid point with non-diverged runs in every task", ha="center", va="center",
                transform=ax.transAxes)
    _save(fig, path)


def plot_heatmaps(sweeps: list[Sweep], maps: list[dict], path: Path) -> None:
    panels = []  # (sweep, heat record, map or None)
    for s, h in zip(sweeps, maps):
        if "skipped" in h:
            panels.append((s, h, None))
        else:
            panels.extend((s, h, m) for m in h["maps"])
    fig, axs = _figure(len(panels), panel_w=4.8, panel_h=4.0)
    for ax, (s, h, m) in zip(axs, panels):
        if m is None:
            ax.set_axis_off()
            ax.text(0.5, 0.5, f"heat map skipped:\n{h['skipped']}", ha="center", va="center", wrap=True,
                    transform=ax.transAxes, fontsize=9)
            continue
        z = np.asarray(m["mean"], float)
        im = ax.imshow(np.ma.masked_invalid(z), origin="lower", aspect="auto", cmap="viridis")
        ax.set_xticks(range(len(h["eta"])), [f"{v:g}" for v in h["eta"]])
        ax.set_yticks(range(len(h["tau"])), [f"{v:g}" for v in h["tau"]])
        ax.set_xlabel("η (annealing speed)")
        ax.set_ylabel("τ (π̄ Polyak speed)")
        ax.set_title(f"{s.name}, α₀={m['alpha0']:g}")
        finite = z[np.isfinite(z)]
        mid = (finite.min() + finite.max()) / 2 if finite.size else 0.0
        for i in range(z.shape[0]):
            for j in range(z.shape[1]):
                div = m["n_diverged"][i][j]
                txt = "all\ndiverged" if not np.isfinite(z[i, j]) else f"{z[i, j]:.3g}" + ("†" if div else "")
                ax.text(j, i, txt, ha="center", va="center", fontsize=9,
                        color="black" if np.isfinite(z[i, j]) and z[i, j] > mid else "white"
                        if np.isfinite(z[i, j]) else "gray")
        fig.colorbar(im, ax=ax, label=f"final {_metric_name(s.metric)} (mean over seeds)")
    fig.suptitle("Final score over τ × η" + (" (†: some seeds diverged, excluded)" if any(
        m is not None and np.any(np.asarray(m["n_diverged"])) for _, _, m in panels) else ""))
    _save(fig, path)


def plot_deviation(sweeps: list[Sweep], finals: list[list[dict]], colors: dict, path: Path) -> None:
    fig, axs = _figure(len(sweeps))
    for ax, s, fs in zip(axs, sweeps, finals):
        seen = set()
        for f in fs:
            if f["diverged"]:
                continue
            lab = f["label"] if f["label"] not in seen else None
            seen.add(f["label"])
            ax.scatter(f["dev_pi0"], f["final_score"], color=colors[f["label"]], label=lab, s=36,
                       edgecolors="black", linewidths=0.4)
        n_div = sum(f["diverged"] for f in fs)
        ax.set_title(s.name + (f" — {n_div} diverged run(s) excluded" if n_div else ""))
        ax.set_xlabel("policy deviation from π₀ (dev_pi0, last evaluation)")
        ax.set_ylabel(f"final {_metric_name(s.metric)}")
        ax.grid(alpha=0.3)
        if seen:
            ax.legend(fontsize=7)
    fig.suptitle("Deviation from π₀ vs. final score (one point per run)")
    _save(fig, path)


def plot_cost(costs: list[dict], path: Path) -> None:
    fig, axs = _figure(2, panel_w=max(4.5, 1.2 * len(costs) + 2.5), panel_h=3.8)
    names = [c["task"] for c in costs]
    for ax, key, ylabel in ((axs[0], "updates_per_s", "updates/s (whole grid)"),
                            (axs[1], "seconds_per_1e6_updates", "wall seconds per 10⁶ updates")):
        vals = [c[key] for c in costs]
        bars = ax.bar(range(len(costs)), vals, color="tab:blue", width=0.6)
        ax.bar_label(bars, labels=[f"{v:,.0f}" if abs(v) >= 100 else f"{v:.3g}" for v in vals], fontsize=8)
        ax.set_xticks(range(len(costs)), names, rotation=20 if len(costs) > 2 else 0, fontsize=8)
        ax.set_ylabel(ylabel)
        ax.margins(y=0.15)
        ax.grid(axis="y", alpha=0.3)
    note = " (* includes compilation: single chunk)" if any(c["includes_compile"] for c in costs) else ""
    fig.suptitle("Compute cost: mean over chunks after the first" + note, fontsize=10)
    _save(fig, path)


# -------------------------------------------------------------------------------------------------------- report


def make_report(dirs, out: str | os.PathLike | None = None, verbose: bool = True) -> dict:
    """Load the sweep directories, write the PNGs and report.json into ``out``; returns the report dict."""
    dirs = [Path(d) for d in dirs]
    if not dirs:
        raise ReportError("give at least one sweep directory: python -m proto_brax.report DIR [DIR ...] "
                          "[--out OUTDIR]")
    sweeps = [load_sweep(d) for d in dirs]
    out = Path(out) if out is not None else dirs[0] / "report"
    out.mkdir(parents=True, exist_ok=True)

    labels = sorted({r.label for s in sweeps for r in s.runs}, key=lambda lab: next(
        r.point for s in sweeps for r in s.runs if r.label == lab))
    colors = _colors(labels)
    curve_data = [curves(s) for s in sweeps]
    agg = aggregate(sweeps)
    heat = [heatmap(s) for s in sweeps]
    finals = [final_scores(s) for s in sweeps]
    costs = [cost(s) for s in sweeps]
    diverged = [{"task": s.name, "dir": str(s.path), "run": r.run, "seed": r.seed, "label": r.label,
                 **dict(zip(GRID_AXES, r.point)),
                 "first_diverged_step": next(int(x["step"]) for x in r.rows if x["diverged"])}
                for s in sweeps for r in s.runs if r.diverged]

    files = []
    plot_curves(sweeps, curve_data, colors, out / "curves.png")
    files.append("curves.png")
    plot_aggregate(agg, colors, out / "aggregate.png")
    files.append("aggregate.png")
    notes = [h["skipped"] for h in heat if "skipped" in h]
    if len(notes) < len(heat):
        plot_heatmaps(sweeps, heat, out / "heatmap.png")
        files.append("heatmap.png")
    plot_deviation(sweeps, finals, colors, out / "deviation.png")
    files.append("deviation.png")
    plot_cost(costs, out / "cost.png")
    files.append("cost.png")

    report = {
        "dirs": [{"dir": str(s.path), "task": s.name, "env": s.env, "metric": s.metric, "n_runs": len(s.runs),
                  "n_rows": len(s.rows), "axes": s.axes,
                  "grid_keys": (s.summary or {}).get("grid_keys")} for s in sweeps],
        "diverged_runs": diverged,
        "curves": {s.name: cd for s, cd in zip(sweeps, curve_data)},
        "aggregate": agg,
        "heatmap": {s.name: h for s, h in zip(sweeps, heat)},
        "deviation": {s.name: f for s, f in zip(sweeps, finals)},
        "cost": costs,
        "notes": notes + ([agg["note"]] if agg["note"] else []),
        "files": files + ["report.json"],
    }
    report = strict_json(report)  # report.json is strict JSON
    from proto_brax.files import write_json_atomic

    write_json_atomic(out / "report.json", report)
    if verbose:
        print_cost_table(costs)
        if diverged:
            print(f"\ndiverged runs (excluded from curves and aggregates): {len(diverged)}")
            for d in diverged:
                print(f"  {d['task']}: run {d['run']} seed {d['seed']} {d['label']} "
                      f"(first non-finite at step {d['first_diverged_step']})")
        else:
            print("\nno diverged runs")
        for n in report["notes"]:
            print(f"note: {n}")
        print(f"\nwrote {out}/: {', '.join(report['files'])}")
    return report
