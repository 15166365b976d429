"""proto_brax.report on hand-made sweep directories (no training): files, IQM aggregates, divergence, cost table."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from matplotlib import image as mpimg
from scipy import stats

from proto_brax.analysis import report
from proto_brax.cli import report as report_cli

TAUS = (0.0, 0.005)
ETAS = (0.5, 1.0)
SEEDS = (0, 1, 2)
STEPS = (100, 200, 300)
# grid throughput per chunk: the first includes compilation
UPS = {"hopper": (50.0, 1000.0, 3000.0), "walker2d": (20.0, 400.0, 600.0)}
PNG_SIG = b"\x89PNG\r\n\x1a\n"


def score(task: str, run: int, chunk: int) -> float:
    """Hand-made normalized scores: distinct, deterministic, spread so the 25% trimming matters."""
    base = {"hopper": 10.0, "walker2d": 40.0}[task]
    return base + 7.0 * run + 11.0 * chunk + ((run * 37 + chunk * 13) % 17)


def make_sweep(root: Path, task: str, *, taus=TAUS, etas=ETAS, seeds=SEEDS, steps=STEPS, ups=None,
               diverged: set[int] = frozenset(), normalized: bool = True, summary: bool = True) -> Path:
    d = root / task
    d.mkdir(parents=True)
    ups = ups or UPS[task]
    grid = [{"anneal_horizon": float(steps[-1]), "tau": t, "eta": e, "alpha0": 2.0, "seed": s}
            for t in taus for e in etas for s in seeds]
    config = {"sweep": {"env": task, "tau": list(taus), "eta": list(etas), "alpha0": [2.0], "seeds": list(seeds),
                        "steps": steps[-1], "algo": "proto-sac"}, "finetune": {}, "grid": grid}
    (d / "config.json").write_text(json.dumps(config))
    lines = []
    for c, step in enumerate(steps):
        for i, p in enumerate(grid):
            ns = score(task, i, c)
            bad = i in diverged and c == len(steps) - 1
            ret = float("nan") if bad else ns / 2
            lines.append(json.dumps({
                "chunk": c, "run": i, **p, "step": step, "eval_return": ret,
                "normalized_score": (float("nan") if bad else ns) if normalized else float("nan"),
                "eval_returns": [ret, ret], "alpha": 1.0, "alpha_sac": 0.1, "dev_pibar": 0.01,
                "dev_pi0": 0.01 * i + 0.001 * c, "kl_pibar": 0.0, "q_mean": float("nan") if bad else 1.0,
                "q_max": 2.0, "critic_loss": 0.5, "actor_loss": -1.0, "entropy": 0.3, "train_return": ret,
                "updates": 10.0, "diverged": bad, "grid_updates_per_s": ups[c]}))
    (d / "metrics.jsonl").write_text("\n".join(lines) + "\n")
    if summary:
        (d / "summary.json").write_text(json.dumps({
            "grid_keys": ["tau", "eta"], "points": [], "env": task, "steps": steps[-1],
            "first_chunk_seconds_incl_compile": 12.5}))
    return d


def label(tau, eta, alpha0=2.0) -> str:
    return f"τ={tau:g} η={eta:g} α₀={alpha0:g}"


def run_index(tau, eta, seed) -> int:
    return (TAUS.index(tau) * len(ETAS) + ETAS.index(eta)) * len(SEEDS) + SEEDS.index(seed)


def check_png(path: Path) -> None:
    assert path.read_bytes()[:8] == PNG_SIG, path
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] > 200 and img.shape[1] > 200 and img.shape[2] in (3, 4), img.shape
    rgb = img[..., :3].reshape(-1, 3)
    assert rgb.std() > 0.05, f"{path.name} looks blank"
    assert len(np.unique(np.round(rgb, 2), axis=0)) > 20, f"{path.name} has too few colours"


@pytest.fixture(scope="module")
def two_tasks(tmp_path_factory):
    root = tmp_path_factory.mktemp("sweeps")
    # hopper: run of (τ=0.005, η=1, seed 2) diverges at its last evaluation
    bad = run_index(0.005, 1.0, 2)
    dirs = [make_sweep(root, "hopper", diverged={bad}), make_sweep(root, "walker2d")]
    out = root / "report_out"
    rep = report.make_report(dirs, out, verbose=False)
    return dirs, out, rep, bad


def test_writes_valid_pngs_and_report_json(two_tasks):
    _, out, rep, _ = two_tasks
    for name in report.PNGS:
        check_png(out / name)
    on_disk = json.loads((out / "report.json").read_text())  # strict JSON: NaN stored as null
    assert on_disk == rep
    assert sorted(on_disk["files"]) == sorted([*report.PNGS, "report.json"])
    assert not [p.name for p in out.iterdir() if p.name.endswith(".tmp")], "temp files left behind"


def test_aggregate_iqm_matches_trim_mean(two_tasks):
    dirs, _, rep, bad = two_tasks
    agg = rep["aggregate"]
    assert agg["metric"] == "normalized_score" and agg["note"] is None
    assert len(agg["points"]) == len(TAUS) * len(ETAS)
    n_checked = 0
    for p in agg["points"]:
        assert p["label"] == label(p["tau"], p["eta"])
        assert p["step"] == list(STEPS)
        runs = [(task, run_index(p["tau"], p["eta"], s)) for task in ("hopper", "walker2d") for s in SEEDS]
        runs = [(t, i) for t, i in runs if not (t == "hopper" and i == bad)]
        assert p["n_runs"] == len(runs)
        for k in range(len(STEPS)):
            vals = np.array([score(t, i, k) for t, i in runs])
            expected = stats.trim_mean(vals, 0.25)
            assert p["iqm"][k] == pytest.approx(expected, rel=1e-12)
            assert p["low"][k] <= p["iqm"][k] + 1e-9 <= p["high"][k] + 2e-9
            n_checked += 1
    assert n_checked == 12


def test_diverged_runs_excluded_and_listed(two_tasks):
    _, _, rep, bad = two_tasks
    assert rep["diverged_runs"] == [{
        "task": "hopper", "dir": rep["dirs"][0]["dir"], "run": bad, "seed": 2, "label": label(0.005, 1.0),
        "tau": 0.005, "eta": 1.0, "alpha0": 2.0, "first_diverged_step": STEPS[-1]}]
    c = rep["curves"]["hopper"][label(0.005, 1.0)]
    assert c["seeds"] == [0, 1]
    good = [run_index(0.005, 1.0, s) for s in (0, 1)]
    for k in range(len(STEPS)):
        vals = [score("hopper", i, k) for i in good]
        assert c["mean"][k] == pytest.approx(np.mean(vals))
        assert (c["min"][k], c["max"][k]) == (pytest.approx(min(vals)), pytest.approx(max(vals)))
    assert rep["curves"]["walker2d"][label(0.005, 1.0)]["seeds"] == [0, 1, 2]
    # heat map: mean over the non-diverged seeds of the final score; the diverged seed is counted
    h = rep["heatmap"]["hopper"]
    assert h["tau"] == list(TAUS) and h["eta"] == list(ETAS)
    (m,) = h["maps"]
    assert m["mean"][1][1] == pytest.approx(np.mean([score("hopper", i, 2) for i in good]))
    assert m["n_diverged"][1][1] == 1 and m["n_seeds"][1][1] == 2
    assert m["mean"][0][0] == pytest.approx(np.mean([score("hopper", run_index(0.0, 0.5, s), 2) for s in SEEDS]))
    dev = {d["run"]: d for d in rep["deviation"]["hopper"]}
    assert dev[bad]["diverged"] and not dev[0]["diverged"]
    assert dev[4]["dev_pi0"] == pytest.approx(0.04 + 0.002)
    assert dev[4]["final_score"] == pytest.approx(score("hopper", 4, 2))


def test_cost_table_numbers(two_tasks, capsys):
    _, _, rep, _ = two_tasks
    n = len(TAUS) * len(ETAS) * len(SEEDS)
    expected = {"hopper": (2000.0, 500.0), "walker2d": (500.0, 2000.0)}  # mean of chunks 1, 2; 1e6 / that
    for c in rep["cost"]:
        ups, sec = expected[c["env"]]
        assert c["updates_per_s"] == pytest.approx(ups)
        assert c["seconds_per_1e6_updates"] == pytest.approx(sec)
        assert c["updates_per_s_per_run"] == pytest.approx(ups / n)
        assert c["chunks_used"] == [1, 2] and not c["includes_compile"]
        assert c["first_chunk_seconds_incl_compile"] == 12.5
    report.print_cost_table(rep["cost"])
    printed = capsys.readouterr().out
    assert "2000.0" in printed and "500.0" in printed and "hopper" in printed


def test_single_chunk_cost_uses_first_chunk(tmp_path):
    d = make_sweep(tmp_path, "hopper", steps=(100,), ups=(250.0,), summary=False)
    rep = report.make_report([d], verbose=False)  # default out: DIR/report
    (c,) = rep["cost"]
    assert c["includes_compile"] and c["updates_per_s"] == 250.0 and c["seconds_per_1e6_updates"] == 4000.0
    assert c["first_chunk_seconds_incl_compile"] is None  # no summary.json (interrupted sweep)
    assert (d / "report" / "report.json").is_file()


def test_nan_normalized_scores_fall_back_to_returns(tmp_path):
    dirs = [make_sweep(tmp_path, "hopper", normalized=False), make_sweep(tmp_path, "walker2d")]
    rep = report.make_report(dirs, tmp_path / "out", verbose=False)
    agg = rep["aggregate"]
    assert agg["metric"] == "eval_return" and "hopper" in agg["note"]
    p = agg["points"][0]
    vals = [score(t, run_index(p["tau"], p["eta"], s), 0) / 2 for t in ("hopper", "walker2d") for s in SEEDS]
    assert p["iqm"][0] == pytest.approx(stats.trim_mean(vals, 0.25))
    assert rep["dirs"][0]["metric"] == "eval_return" and rep["dirs"][1]["metric"] == "normalized_score"
    check_png(tmp_path / "out" / "aggregate.png")


def test_heatmap_skipped_with_note_for_one_eta(tmp_path):
    d = make_sweep(tmp_path, "hopper", etas=(1.0,))
    rep = report.make_report([d], tmp_path / "out", verbose=False)
    assert "skipped" in rep["heatmap"]["hopper"] and any("2 τ and 2 η" in n for n in rep["notes"])
    assert "heatmap.png" not in rep["files"] and not (tmp_path / "out" / "heatmap.png").exists()
    for name in ("curves.png", "aggregate.png", "deviation.png", "cost.png"):
        check_png(tmp_path / "out" / name)


def test_missing_metrics_raises(tmp_path):
    d = tmp_path / "notasweep"
    d.mkdir()
    with pytest.raises(report.ReportError, match=r"not a sweep directory.*metrics\.jsonl.*python -m proto_brax\.sweep"):
        report.make_report([d])
    with pytest.raises(SystemExit, match="not a sweep directory"):
        report_cli.main([str(d)])
    with pytest.raises(report.ReportError, match="not a sweep directory"):
        report.load_sweep(tmp_path / "missing")


def test_empty_metrics_raises(tmp_path):
    d = make_sweep(tmp_path, "hopper")
    (d / "metrics.jsonl").write_text("\n")
    with pytest.raises(report.ReportError, match="metrics.jsonl is empty"):
        report.load_sweep(d)


def test_cli(tmp_path, capsys):
    d = make_sweep(tmp_path, "hopper", diverged={0})
    report_cli.main([str(d), "--out", str(tmp_path / "cli")])
    out = capsys.readouterr().out
    assert "s per 1e6 updates" in out and "diverged runs" in out and "run 0 seed 0" in out
    rep = json.loads((tmp_path / "cli" / "report.json").read_text())
    assert len(rep["diverged_runs"]) == 1 and all(math.isfinite(v) for v in rep["curves"]["hopper"][
        label(0.0, 0.5)]["mean"])
