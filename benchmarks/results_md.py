"""Write ``benchmarks/RESULTS.md`` from the published locomotion sweeps, the cost benchmark and the bundles.

    python benchmarks/results_md.py       # after `python benchmarks/locomotion.py run` has published sweeps

Reads every ``benchmarks/results/locomotion/DATASET/METHOD`` (summary.json, config.json, metrics.jsonl.gz as
``benchmarks/locomotion.py`` publishes them), the bundles' offline scores (``checkpoints/pretrained``),
``benchmarks/results/methods_cost.json`` and ``benchmarks/results/datasets.json`` (which dataset builds are
reproducible: run ``python benchmarks/datasets_record.py`` first after new builds); writes RESULTS.md (per-dataset
tables, aggregates, the paper's three claims checked against the numbers) and ``aggregate.png`` (IQM learning
curves over all datasets and seeds per method) next to the sweeps, and each dataset's ``curves.png`` (mean ± std over
seeds per method against online steps). Every number is computed here from those files: rerunning this script
regenerates the page.

Definitions (per run = one seed of one dataset × method): *initial* = π₀'s normalized score at step 0 (before any
online step); *drop* = the lowest score within the first 10% of the online steps (the sweep's
``min_normalized_first_10pct``); *final* = the score at the last evaluation; *late* = the mean of the last
``LATE_EVALS`` evaluations (claim (2) is checked on both: one evaluation of 10 episodes is noisy). Aggregates are
IQMs with 95% percentile bootstrap CIs over all (dataset, seed) runs of a method (:func:`proto_brax.stats.iqm_ci`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import sys
from pathlib import Path

import numpy as np
import tyro

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from locomotion import ABLATIONS, DATASETS, ETA0, PAPER_METHODS, TAU0, method_of  # noqa: E402

from proto_brax.checkpoints import bundle_dataset_record, write_json_atomic  # noqa: E402
from proto_brax.datasets import generation_numerics_pinned  # noqa: E402
from proto_brax.files import atomic_write, write_text_atomic  # noqa: E402
from proto_brax.report import Sweep, load_sweep  # noqa: E402
from proto_brax.stats import iqm_ci  # noqa: E402
from proto_brax.sweep import lowest_early_scores  # noqa: E402

ORDER = ("proto-sac", "frozen", "direct", "iql", "sac-scratch", "proto-td3", "proto-bc", "pex", "awac", "calql",
         "off2on", "td3-scratch", "sac-offline")


@dataclasses.dataclass
class Args:
    results: Path = ROOT / "benchmarks" / "results" / "locomotion"
    cost: Path = ROOT / "benchmarks" / "results" / "methods_cost.json"
    bundles: Path = ROOT / "checkpoints" / "pretrained"
    record: Path = ROOT / "benchmarks" / "results" / "datasets.json"  # the dataset builds (datasets_record.py)
    out: Path = ROOT / "benchmarks" / "RESULTS.md"


LATE_EVALS = 3  # at the default budget, the evaluations at 45k, 47.5k and 50k steps


def run_scores(sweep: Sweep) -> list[dict]:
    """Per run: initial, drop (lowest in the first 10% of the online steps), final; the sweep's own definitions."""
    out = []
    for r in sweep.runs:
        init = [row for row in r.rows if row.get("initial")]
        rows = [row for row in r.rows if not row.get("initial")]
        if not rows:
            continue
        curve = [float(row["normalized_score"]) for row in rows]
        out.append({"seed": r.seed, "point": r.point, "initial": init[0]["normalized_score"] if init else math.nan,
                    "drop": float(lowest_early_scores([rows])[0]), "final": curve[-1],
                    "late": float(np.mean(curve[-LATE_EVALS:])), "lowest": min(curve),
                    "diverged": r.diverged, "steps": [row["step"] for row in rows], "curve": curve})
    return out


def offline_score(bundles: Path, dataset: str, method: str) -> float:
    kinds = method_of(method).bundles
    if not kinds:
        return math.nan
    meta = bundles / dataset / kinds[0] / "metadata.json"
    if not meta.exists():
        return math.nan
    ev = json.loads(meta.read_text()).get("offline_eval") or {}
    return float(ev.get("normalized_score_mean", math.nan))


def collect(args: Args) -> dict[str, dict[str, dict]]:
    """{dataset: {method: {"runs": [...], "summary": {...}, "config": {...}, "offline": float}}}; the ablation sweeps
    (``ablate-*``) are listed as methods too, and kept out of the method tables by ``methods_of``."""
    table: dict[str, dict[str, dict]] = {}
    for d in sorted(p for p in args.results.glob("*/*") if (p / "summary.json").exists()):
        dataset, method = d.parent.name, d.name
        sweep = load_sweep(d)
        table.setdefault(dataset, {})[method] = {
            "runs": run_scores(sweep), "summary": sweep.summary, "config": sweep.config,
            "offline": offline_score(args.bundles, dataset, method),
            # a dataset-free method's sweep is copied to each dataset of its env: aggregates count each sweep once
            # (a sweep's config names its dataset and its output directory: distinct sweeps never share it)
            "sweep_id": hashlib.sha256(json.dumps([sweep.config, sweep.rows], sort_keys=True).encode()).hexdigest()}
    return table


def method_runs(table, m: str) -> tuple[list[str], list[dict]]:
    """(datasets, runs) of method ``m`` over the datasets, each distinct sweep once (shared copies dropped)."""
    seen, datasets, runs = set(), [], []
    for d, per in table.items():
        if m in per and per[m]["sweep_id"] not in seen:
            seen.add(per[m]["sweep_id"])
            datasets.append(d)
            runs += per[m]["runs"]
    return datasets, runs


def fmt(x: float, nd: int = 1) -> str:
    return "–" if x is None or not math.isfinite(x) else f"{x:.{nd}f}"


def ci(values) -> tuple[float, float, float]:
    return iqm_ci([v for v in values if math.isfinite(v)])


def ci_str(values) -> str:
    m, lo, hi = ci(values)
    return f"{fmt(m)} [{fmt(lo)}, {fmt(hi)}]"


def verdict(proto, other) -> str:
    """Whether PROTO's IQM is above the other method's: with separate 95% CIs, on the point estimate only, or not."""
    (pm, plo, _), (om, _, ohi) = ci(proto), ci(other)
    if plo > ohi:
        return "holds (CIs separate)"
    return "holds on the point estimate only (CIs overlap)" if pm > om else "does not hold"


def ordered(methods) -> list[str]:
    """The paper's methods first, in ORDER, then any others alphabetically."""
    present = set(methods)
    return [m for m in ORDER if m in present] + sorted(present - set(ORDER))


def methods_of(per: dict) -> list[str]:
    """A dataset's method sweeps (not its ablation sweeps), in ORDER."""
    return ordered(m for m in per if m not in ABLATIONS)


def methods_in(table) -> list[str]:
    return ordered(m for per in table.values() for m in methods_of(per))


def bundle_record(config: dict) -> dict:
    """The sweep's ``dataset_vs_bundle`` record (sweeps before session 8 did not store it: derived the same way)."""
    record = config.get("dataset_vs_bundle")
    if record is None and config.get("checkpoint_metadata") and config.get("dataset_metadata"):
        record = bundle_dataset_record(config["checkpoint_metadata"], config["dataset_metadata"])
    return record or {}


def buffer_data(config: dict) -> str:
    """Whether a sweep's dataset held the rows its bundle was pretrained on: "bundle's", "regenerated" (the same
    registered dataset with another content hash) or "–" (no bundle, or no dataset)."""
    return {True: "bundle's", False: "regenerated"}.get(bundle_record(config).get("same_content"), "–")


def pinned_builds(record: Path) -> set[str]:
    """Content hashes of the builds ``benchmarks/results/datasets.json`` saw generated under the pinned single XLA
    thread (``datasets.generation_xla_flags``): the builds ``python -m proto_brax.datasets make`` reproduces."""
    if not record.exists():
        return set()
    return {b["content_hash"] for entry in json.loads(record.read_text()).values() for b in entry["builds"]
            if generation_numerics_pinned(b.get("xla_flags") or "")}


def dataset_table(dataset: str, per: dict[str, dict]) -> list[str]:
    methods = " ".join(m for m in methods_of(per))
    lines = [f"### {dataset}", "",
             f"`python benchmarks/locomotion.py run --datasets {dataset} --methods {methods}`, then "
             "`python benchmarks/results_md.py`.", "",
             "| method | offline | initial (π₀) | lowest in first 10% | final mean ± std | final IQM [95% CI] "
             "| seeds | buffer data |",
             "|---|---|---|---|---|---|---|---|"]
    for m in methods_of(per):
        lines.append(f"| {m} | {fmt(per[m]['offline'])} | {score_cells(per[m]['runs'])} | "
                     f"{buffer_data(per[m]['config'])} |")
    return lines + ["", f"![{dataset} learning curves](results/locomotion/{dataset}/curves.png)", ""]


def provenance(table, pinned: set[str]) -> list[str]:
    """Which published sweeps finetuned with other rows of their bundle's dataset in the buffer than the bundle was
    pretrained on, and which side of each pair is the reproducible (pinned) build."""
    sides: dict[str, list[str]] = {"buffer": [], "bundle": [], "neither": []}
    for d, per in sorted(table.items()):
        for m in methods_of(per):
            record = bundle_record(per[m]["config"])
            if record.get("same_content") is False:
                side = ("buffer" if record["bundle_content_hash"] in pinned else
                        "bundle" if record["content_hash"] in pinned else "neither")
                sides[side].append(f"{d}/{m}")
    n = sum(map(len, sides.values()))
    if not n:
        return []
    which = {"buffer": "buffer generated before the pin, bundle's rows a pinned build",
             "bundle": "bundle pretrained on rows generated before the pin, buffer a pinned build",
             "neither": "neither side a recorded pinned build"}
    parts = [f"{which[k]}: {', '.join(v)}" for k, v in sides.items() if v]
    return [f"**Buffer data:** {n} sweep(s) put a regenerated copy of their bundle's dataset in the buffer "
            "(column *buffer data*): the same registered dataset, generator and behaviour policies, other rows. "
            "Copies generated before `python -m proto_brax.datasets make` pinned one XLA thread "
            "(`datasets.generation_xla_flags`) cannot be regenerated: multi-threaded XLA rounds differently, which "
            "changes hopper's and walker2d's episodes (they end on falls). By sweep: "
            f"{'; '.join(parts)}. The bundle (π₀, critic, reward scale) is the committed one either way; "
            "`benchmarks/results/datasets.json` lists every build (`python benchmarks/datasets_record.py`).", ""]


def score_cells(runs: list[dict]) -> str:
    """The table cells initial | lowest in first 10% | final mean ± std | final IQM [95% CI] | seeds (over runs; a
    diverged run's non-finite final is left out of the mean and counted)."""
    if not runs:
        return "– | – | – | – | 0"
    fin = [r["final"] for r in runs]
    finite = [v for v in fin if math.isfinite(v)]
    bad = f" ({len(fin) - len(finite)} diverged)" if len(finite) < len(fin) else ""
    return (f"{fmt(np.nanmean([r['initial'] for r in runs]))} | {fmt(np.nanmean([r['drop'] for r in runs]))} | "
            f"{fmt(np.mean(finite)) if finite else '–'} ± {fmt(np.std(finite)) if finite else '–'} | "
            f"{ci_str(fin)} | {len(runs)}{bad}")


def compare(table, pairs: list[str], other: str, key: str) -> tuple[int, str]:
    """PROTO against ``other`` on the runs' ``key`` score over the datasets ``pairs``: on how many datasets its mean
    is higher, and the IQMs with their verdict."""
    p_all = [r[key] for d in pairs for r in table[d]["proto-sac"]["runs"]]
    o_all = [r[key] for d in pairs for r in table[d][other]["runs"]]
    wins = sum(np.nanmean([r[key] for r in table[d]["proto-sac"]["runs"]])
               > np.nanmean([r[key] for r in table[d][other]["runs"]]) for d in pairs)
    return wins, f"PROTO {ci_str(p_all)} vs {ci_str(o_all)}: {verdict(p_all, o_all)}"


def claims(table, cost: dict | None) -> list[str]:
    out = ["## The paper's three claims on Brax", ""]
    # (1) initial drop: PROTO's lowest early score relative to π₀ against direct finetuning's
    both = [d for d, per in table.items() if {"proto-sac", "direct"} <= set(per)]
    if both:
        rows, wins, p_all, q_all = [], 0, [], []
        for d in both:
            p = [r["drop"] - r["initial"] for r in table[d]["proto-sac"]["runs"]]
            q = [r["drop"] - r["initial"] for r in table[d]["direct"]["runs"]]
            p_all, q_all = p_all + p, q_all + q
            pm, qm = float(np.nanmean(p)), float(np.nanmean(q))
            wins += pm > qm
            # the lowest score of the whole run: a collapse after the first 10% does not show in the drop
            pl, ql = (float(np.nanmean([r["lowest"] - r["initial"] for r in table[d][m]["runs"]]))
                      for m in ("proto-sac", "direct"))
            rows.append(f"| {d} | {fmt(pm)} | {fmt(qm)} | {fmt(pl)} | {fmt(ql)} |")
        out += [f"**(1) PROTO avoids the initial drop of direct finetuning.** Lowest score in the first 10% minus π₀'s "
                f"score (mean over seeds; 0 = no drop). PROTO's drop is smaller on {wins} of {len(both)} datasets; "
                f"IQM over all runs PROTO {ci_str(p_all)} vs direct {ci_str(q_all)}: {verdict(p_all, q_all)}. The "
                "last two columns take the lowest score of the whole run instead, which shows a collapse that comes "
                "later.", "",
                "| dataset | PROTO, first 10% | direct, first 10% | PROTO, whole run | direct, whole run |",
                "|---|---|---|---|---|", *rows, ""]
    # (2) final: PROTO against Frozen and IQL
    for other, name in (("frozen", "Frozen (τ = 0)"), ("iql", "IQL finetune")):
        pairs = [d for d, per in table.items() if {"proto-sac", other} <= set(per)]
        if not pairs:
            out += [f"**(2) PROTO ends above {name}:** not measured yet (no dataset has both sweeps).", ""]
            continue
        (wins, iqms), (late_wins, late_iqms) = (compare(table, pairs, other, key) for key in ("final", "late"))
        out += [f"**(2) PROTO ends above {name}** on {wins} of {len(pairs)} datasets (mean final score); IQM over all "
                f"runs {iqms}. With the mean of the last {LATE_EVALS} evaluations of each run instead: {late_wins} of "
                f"{len(pairs)} datasets, IQM {late_iqms}.", ""]
    # (3) cost
    if cost and "proto-sac" in cost.get("results", {}):
        res = cost["results"]
        sac = res.get("sac-scratch", {}).get("seconds_per_1e5_steps")
        ratio = res["proto-sac"]["seconds_per_1e5_steps"] / sac if sac else math.nan
        out += [f"**(3) PROTO costs about what SAC costs:** PROTO-SAC / SAC-from-scratch wall time per online step = "
                f"{fmt(ratio, 2)} (`{cost.get('command', '')}`, {cost.get('date', '')}; "
                f"{cost.get('status', '')}).", ""]
    return out


def ablation_tables(table) -> list[str]:
    """The appendix's ablations: per dataset and value, PROTO-SAC's scores; the default value (1 × τ₀, η = 0.9) is
    the dataset's proto-sac sweep, the others its ablate-tau / ablate-eta sweep (one vmapped program each)."""
    out = []
    for ablation, (axis, name, default) in {"ablate-tau": (0, "τ", TAU0), "ablate-eta": (1, "η", ETA0)}.items():
        datasets = [d for d in sorted(table) if ablation in table[d]]
        if not datasets:
            continue
        flag, others = ABLATIONS[ablation]
        values = sorted({default, *others})
        rows = []
        for d in datasets:
            runs = table[d][ablation]["runs"] + table[d].get("proto-sac", {}).get("runs", [])
            for v in values:
                rs = [r for r in runs if math.isclose(r["point"][axis], v, rel_tol=1e-9)]
                rows.append(f"| {d} | {v:g}{' (default)' if v == default else ''} | {score_cells(rs)} |")
        scale = f" = {{{', '.join(f'{v / TAU0:g}' for v in values)}}} × τ₀" if axis == 0 else ""
        out += [f"### {name} ∈ {{{', '.join(f'{v:g}' for v in values)}}}{scale}", "",
                f"`python benchmarks/locomotion.py run --methods proto-sac {ablation}`: PROTO-SAC with "
                f"`{flag} {' '.join(f'{v:g}' for v in others)}` in one sweep; the default value is the proto-sac "
                "sweep.",
                "", f"| dataset | {name} | initial (π₀) | lowest in first 10% | final mean ± std | final IQM [95% CI] "
                "| seeds |", "|---|---|---|---|---|---|---|", *rows, ""]
    return ["## Ablations (the paper's appendix)", "", *out] if out else []


def cost_table(cost: dict | None) -> list[str]:
    if not cost:
        return []
    lines = ["## Compute cost per method", "", f"`{cost.get('command', '')}` ({cost.get('date', '')}; env "
             f"{cost.get('env', '')}; {cost.get('status', '')})", "",
             "| method | s per 10⁵ online steps | × PROTO-SAC |", "|---|---|---|"]
    for m, r in cost.get("results", {}).items():
        lines.append(f"| {m} | {fmt(r['seconds_per_1e5_steps'], 0)} | {fmt(r['ratio_to_proto_sac'], 2)} |")
    return lines + [""]


def plot_curves(curves: dict, x: str, xlabel: str, ylabel: str, title: str, path: Path) -> None:
    """One line per method (``curves[m][x]`` against ``curves[m]["center"]``) with its ``low``–``high`` band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for m, c in curves.items():
        ax.plot(c[x], c["center"], label=f"{m} ({c['n_runs']} runs)")
        ax.fill_between(c[x], c["low"], c["high"], alpha=0.15)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_write(path, "wb") as f:
        fig.savefig(f, format="png", dpi=120)
    plt.close(fig)


def from_initial(runs: list[dict]) -> tuple[bool, np.ndarray]:
    """(starts at π₀, [run, point]): each run's evaluations cut to the shortest run, led by π₀'s step-0 score where
    every run has one (so that the initial drop shows)."""
    n = min(len(r["curve"]) for r in runs)
    start = all(math.isfinite(r["initial"]) for r in runs)
    return start, np.asarray([[r["initial"]] * start + r["curve"][:n] for r in runs], dtype=float)


def aggregate_curves(table, path: Path) -> dict:
    """IQM [95% CI] over all (dataset, seed) runs per method at step 0 (π₀) and each evaluation index; one PNG."""
    curves = {}
    for m in methods_in(table):
        runs = method_runs(table, m)[1]
        start, ys = from_initial(runs)
        n = ys.shape[1] - start
        frac = [0.0] * start + [(k + 1) / n for k in range(n)]
        stats = [ci(v) for v in ys.T]
        curves[m] = {"fraction": frac, "iqm": [s[0] for s in stats], "low": [s[1] for s in stats],
                     "high": [s[2] for s in stats], "n_runs": len(runs)}
    plot_curves({m: {**c, "center": c["iqm"]} for m, c in curves.items()}, "fraction",
                "fraction of the online budget", "normalized score (IQM, 95% CI)", "All locomotion datasets", path)
    return curves


def dataset_curves(dataset: str, per: dict[str, dict], path: Path) -> dict:
    """Learning curves of one dataset: mean ± std over seeds per method against online steps, from π₀ at step 0 (a
    diverged run's non-finite scores are left out, as in the tables)."""
    curves = {}
    for m in methods_of(per):
        runs = per[m]["runs"]
        start, ys = from_initial(runs)
        steps = [0] * start + runs[0]["steps"][:ys.shape[1] - start]
        mean, std = np.nanmean(ys, axis=0), np.nanstd(ys, axis=0)
        curves[m] = {"steps": steps, "center": mean.tolist(), "low": (mean - std).tolist(),
                     "high": (mean + std).tolist(), "n_runs": len(runs)}
    plot_curves(curves, "steps", "online steps", "normalized score (mean ± std over seeds)", dataset, path)
    return curves


def coverage(table) -> list[str]:
    """Which of the planned sweeps (``locomotion.py``'s datasets × the paper's methods) are published."""
    done = {(d, m) for d, per in table.items() for m in methods_of(per)}
    planned = [(d, m) for d in DATASETS for m in PAPER_METHODS]
    missing = {d: [m for m in PAPER_METHODS if (d, m) not in done] for d in DATASETS}
    full = [d for d in DATASETS if not missing[d]]
    none = [d for d in DATASETS if len(missing[d]) == len(PAPER_METHODS)]
    partial = [f"{d} (missing {', '.join(missing[d])})" for d in DATASETS if d not in full + none]
    return [f"**Coverage:** {sum(p in done for p in planned)} of the {len(planned)} planned sweeps ({len(DATASETS)} "
            f"datasets × {len(PAPER_METHODS)} methods: {', '.join(PAPER_METHODS)}) are published. Complete: "
            f"{', '.join(full) or 'none'}. Partial: {'; '.join(partial) or 'none'}. Not started: "
            f"{', '.join(none) or 'none'}. Every claim below is about the published sweeps only.", ""]


def render(args: Args) -> str:
    table = collect(args)
    cost = json.loads(args.cost.read_text()) if args.cost.exists() else None
    if not table:
        raise SystemExit(f"No published sweeps under {args.results}: run `python benchmarks/locomotion.py run`.")
    budgets = sorted({per[m]["summary"].get("steps") for per in table.values() for m in per})
    curves = aggregate_curves(table, args.results / "aggregate.png")
    write_json_atomic(args.results / "aggregate.json", curves)
    lines = ["# Results: PROTO and its baselines on Brax locomotion (reduced scale)", "",
             "Generated by `python benchmarks/results_md.py` from the sweeps `python benchmarks/locomotion.py run` "
             "published under `benchmarks/results/locomotion/` (each sweep's `config.json` holds its full command "
             "line). Do not edit by hand.", "",
             f"Online budget: {', '.join(f'{b:,}' for b in budgets)} steps per run (the paper: 10⁶), α annealed over "
             "the same fraction of the run; normalized scores use this suite's Brax references "
             "(`proto_brax/envs.py`), so they are not comparable to D4RL numbers.", ""]
    lines += coverage(table)
    lines += provenance(table, pinned_builds(args.record))
    lines += claims(table, cost)
    lines += ["## Aggregate over datasets", "", "`python benchmarks/results_md.py` over every published sweep "
              "(`benchmarks/results/locomotion/aggregate.json` holds the curves).", "",
              "![aggregate](results/locomotion/aggregate.png)", "",
              "Each distinct sweep counts once: SAC from scratch trains on no dataset, so its one sweep per env stands "
              "in the table of every dataset of that env. Until every sweep is published the rows cover different "
              "datasets (column 2): compare methods in the claims above (which pair datasets) or per dataset.", "",
              "| method | datasets | runs | final IQM [95% CI] | lowest-in-first-10% IQM [95% CI] |",
              "|---|---|---|---|---|"]
    for m in methods_in(table):
        ds, runs = method_runs(table, m)
        lines.append(f"| {m} | {len(ds)} | {len(runs)} | {ci_str([r['final'] for r in runs])} | "
                     f"{ci_str([r['drop'] for r in runs])} |")
    lines += ["", "## Per dataset", ""]
    for d in sorted(d for d, per in table.items() if methods_of(per)):
        dataset_curves(d, table[d], args.results / d / "curves.png")
        lines += dataset_table(d, table[d])
    lines += ablation_tables(table)
    lines += cost_table(cost)
    return "\n".join(lines).rstrip() + "\n"


def main(args: Args) -> None:
    text = render(args)
    write_text_atomic(args.out, text)
    print(text)


if __name__ == "__main__":
    main(tyro.cli(Args))
