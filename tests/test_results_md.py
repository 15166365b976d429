"""proto_brax.analysis.results_md (python benchmarks/results_md.py) on hand-made published sweeps: per-run
drop/final, claims verdicts, gzip metrics, PNG."""

from __future__ import annotations

import dataclasses
import gzip
import importlib
import importlib.util
import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from proto_brax import sweep
from proto_brax.analysis import locomotion_plan, report
from proto_brax.checkpoints import bundle_dataset_record

ROOT = Path(__file__).resolve().parents[1]
STEPS = (100, 200, 300, 1000)  # the first 10% of a 1000-step run holds the evaluations at 100 (not 200)


def load_module(name: str = "results_md"):
    """proto_brax.analysis.results_md, or the driver benchmarks/NAME.py as a module (registered before it runs: its
    dataclass needs its module), after the script's own first import ``_quiet``, as running the script finds it."""
    if name == "results_md":
        return importlib.import_module("proto_brax.analysis.results_md")
    for module in ("_quiet", name):
        if module not in sys.modules:
            spec = importlib.util.spec_from_file_location(module, ROOT / "benchmarks" / f"{module}.py")
            sys.modules[module] = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(sys.modules[module])
    return sys.modules[name]


def curve(method: str, seed: int, tau: float = 0.005) -> list[float]:
    """π₀ at 30; direct collapses early then recovers; PROTO dips a little and ends high; frozen ends lower; the τ
    ablation's PROTO ends 1000·τ higher."""
    return {"proto-sac": [30.0, 28.0 - seed, 50.0, 80.0 + seed],
            "direct": [30.0, 5.0 + seed, 40.0, 70.0 + seed],
            "frozen": [30.0, 31.0, 40.0, 60.0 + seed],
            "ablate-tau": [30.0, 20.0, 50.0, 80.0 + seed + 1000 * tau],
            "sac-scratch": [1.0, 2.0, 5.0, 10.0 + seed],
            "rlpd-utd1": [10.0, 20.0, 30.0, 40.0 + seed],
            "proto-official": [28.0 - seed, 50.0, 80.0 + seed, 80.0 + seed],
            "official-but-temperature": [28.0, 50.0, 60.0, 30.0 + seed],
            "ours-but-random-target": [30.0, 20.0, 30.0, 40.0 + seed],
            "ours-but-behaviour-eval": [30.0, 28.0, 50.0, 79.0 + seed]}[method]


def publish(root: Path, dataset: str, method: str, seeds=(0, 1, 2), taus=(0.005,), hashes=None,
            recorded=False) -> Path:
    """A published sweep as locomotion.py writes it; ``hashes`` = (the bundle's pretraining data, the buffer's)."""
    d = root / dataset / method
    d.mkdir(parents=True)
    rows = []
    for run, (tau, seed) in enumerate((t, s) for t in taus for s in seeds):
        base = {"run": run, "seed": seed, "tau": tau, "eta": 0.9, "alpha0": 2.0, "dev_pi0": 0.1, "diverged": False,
                "grid_updates_per_s": 100.0}
        rows.append({**base, "chunk": -1, "step": 0, "eval_return": 300.0, "normalized_score": 30.0, "initial": True})
        scores = curve(method, seed, tau)
        for c, (step, score) in enumerate(zip(STEPS, scores[1:] + [scores[-1]])):
            rows.append({**base, "chunk": c, "step": step, "eval_return": 10 * score, "normalized_score": score})
    with gzip.open(d / "metrics.jsonl.gz", "wt") as f:
        f.write("\n".join(json.dumps(r) for r in rows) + "\n")
    used = "none" if method == "sac-scratch" else dataset  # as the sweeps' configs: the dataset trained on
    config = {"sweep": {"env": dataset.split("-")[0], "algo": method, "dataset": used}}
    if hashes:  # as sweeps before session 8 (no dataset_vs_bundle record) or after (recorded)
        meta, dmeta = {"dataset": dataset, "dataset_content_hash": hashes[0]}, {"content_hash": hashes[1]}
        config |= {"checkpoint_metadata": meta, "dataset_metadata": dmeta}
        if recorded:
            config["dataset_vs_bundle"] = bundle_dataset_record(meta, dmeta)
    (d / "config.json").write_text(json.dumps(config))
    (d / "summary.json").write_text(json.dumps({"env": dataset.split("-")[0], "steps": STEPS[-1], "points": []}))
    return d


@pytest.fixture(scope="module")
def published(tmp_path_factory):
    root = tmp_path_factory.mktemp("published")
    for dataset in ("hopper-medium", "walker2d-medium"):
        for method in ("proto-sac", "direct", "frozen"):  # walker2d's direct ran on a regenerated dataset
            regenerated = dataset == "walker2d-medium" and method == "direct"
            publish(root / "locomotion", dataset, method, hashes=("ab", "cd" if regenerated else "ab"),
                    recorded=dataset == "walker2d-medium")
    publish(root / "locomotion", "hopper-medium", "ablate-tau", taus=(0.0025, 0.01))
    cost = {"command": "python benchmarks/methods_cost.py", "date": "today", "env": "hopper", "status": "test",
            "results": {"proto-sac": {"seconds_per_1e5_steps": 110.0, "ratio_to_proto_sac": 1.0},
                        "sac-scratch": {"seconds_per_1e5_steps": 100.0, "ratio_to_proto_sac": 100 / 110}}}
    (root / "cost.json").write_text(json.dumps(cost))
    pinned = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"  # as datasets_record.py records
    builds = {"walker2d-medium": {"builds": [{"content_hash": "ab", "xla_flags": pinned},
                                             {"content_hash": "cd", "xla_flags": None}]}}
    (root / "datasets.json").write_text(json.dumps(builds))
    return root


def test_provenance_names_the_side_of_each_regenerated_pair_that_is_the_pinned_build():
    mod = load_module()

    def sweep(bundle_hash, buffer_hash):
        meta, dmeta = {"dataset": "d", "dataset_content_hash": bundle_hash}, {"content_hash": buffer_hash}
        return {"config": {"dataset_vs_bundle": bundle_dataset_record(meta, dmeta)}}

    table = {"hopper-random": {"proto-sac": sweep("old", "new"), "iql": sweep("new", "new")},
             "hopper-medium": {"frozen": sweep("pin", "old"), "direct": sweep("x", "y")},
             "ant-random": {"iql": sweep("pin", "new")}}  # two pinned builds of other CPUs
    text = mod.provenance(table, pinned={"new", "pin"})[0]
    assert text.startswith("**Buffer data:** 4 sweep(s)")  # hopper-random/iql holds its bundle's rows
    assert ("By sweep: buffer generated before the pin, bundle's rows a pinned build: hopper-medium/frozen; bundle "
            "pretrained on rows generated before the pin, buffer a pinned build: hopper-random/proto-sac; both sides "
            "pinned builds, made on other CPUs: ant-random/iql; neither side a recorded pinned build: "
            "hopper-medium/direct.") in text
    assert mod.provenance({"hopper-random": {"iql": sweep("new", "new")}}, pinned=set()) == []


def test_published_gzip_metrics_load_as_a_sweep(published):
    sweep = report.load_sweep(published / "locomotion" / "hopper-medium" / "direct")
    assert len(sweep.runs) == 3 and sweep.metric == "normalized_score"


def test_run_scores_follow_the_sweep_definitions(published):
    mod = load_module()
    runs = mod.run_scores(report.load_sweep(published / "locomotion" / "hopper-medium" / "direct"))
    # seed s: evaluations at 100, 200, 300, 1000 are 5 + s, 40, 70 + s, 70 + s; the first 10% is step 100 only
    assert [(r["initial"], r["drop"], r["final"]) for r in runs] == [(30.0, 5.0, 70.0), (30.0, 6.0, 71.0),
                                                                     (30.0, 7.0, 72.0)]
    # late = the mean of the last 3 evaluations: (40 + 2 (70 + s)) / 3
    assert [r["late"] for r in runs] == pytest.approx([60.0, 60 + 2 / 3, 60 + 4 / 3])


def test_results_page_states_the_claims_with_numbers(published):
    mod = load_module()
    readme = published / "README.md"
    readme.write_text(f"intro\n{mod.README_BEGIN}\nstale numbers\n{mod.README_END}\nafter\n")
    args = mod.Args(results=published / "locomotion", cost=published / "cost.json", bundles=published / "none",
                    record=published / "datasets.json", out=published / "RESULTS.md", readme=readme,
                    overhead=published / "none.json")
    mod.main(args)
    text = args.out.read_text()
    # the README's block: RESULTS.md's coverage and claim paragraphs, nothing else of the README touched
    head, block = readme.read_text().split(mod.README_BEGIN + "\n")
    block, tail = block.split(mod.README_END + "\n")
    assert head == "intro\n" and tail == "after\n" and "stale" not in block
    paragraphs = block.strip().split("\n\n")
    assert [p[:6] for p in paragraphs] == ["**Cove", "**(1) ", "**(2) ", "**(2) ", "**(3) "]
    assert all(p in text for p in paragraphs)
    # (1) drop relative to π₀: PROTO (28 - s) - 30 -> -3 on average; direct (5 + s) - 30 -> -24
    assert "PROTO's drop is smaller on 2 of 2 datasets" in text
    # IQM of drops: PROTO -2, -3, -4 (twice) -> -3; direct -25, -24, -23 -> -24; the CIs separate
    assert "IQM over all runs PROTO -3.0 [" in text and "vs direct -24.0 [" in text
    assert text.split("vs direct -24.0 [")[1].split(": ")[1].startswith("holds (CIs separate)")
    assert "| hopper-medium | -3.0 | -24.0 | -3.0 | -24.0 |" in text  # the lowest of each run is its early dip
    # (2) PROTO 80..82 against Frozen 60..62 on every run: the CIs separate; IQL was not run
    assert "PROTO ends above Frozen (τ = 0)** on 2 of 2 datasets" in text and "holds (CIs separate)" in text
    # late: PROTO (50 + 2 (80 + s)) / 3 = 70, 70.7, 71.3 against Frozen (40 + 2 (60 + s)) / 3 = 53.3, 54, 54.7
    assert ("With the mean of the last 3 evaluations of each run instead: 2 of 2 datasets, IQM PROTO 70.7 [" in text
            and "vs 54.0 [" in text)
    assert "PROTO ends above IQL finetune:** not measured yet" in text
    assert "= 1.10" in text  # (3) 110 / 100
    assert "| proto-sac | 2 | 6 | 81.0 [80.2, 81.8] | 27.0 [" in text  # IQM of 80, 81, 82 twice
    assert "**Buffer data:** 1 sweep(s) put a regenerated copy" in text
    assert "By sweep: buffer generated before the pin, bundle's rows a pinned build: walker2d-medium/direct. " in text
    assert "| direct | – | 30.0 | 6.0 | 71.0 ± 0.8 | 71.0 [70.0, 72.0] | 3 | regenerated |" in text
    assert "| frozen | – | 30.0 | 31.0 | 61.0 ± 0.8 | 61.0 [60.0, 62.0] | 3 | bundle's |" in text
    assert "**Coverage:** 6 of the 84 planned sweeps" in text  # 2 datasets × 3 methods; the ablation is not one
    assert "Partial: hopper-medium (missing iql, sac-scratch, proto-td3, proto-bc); walker2d-medium (missing" in text
    # the τ ablation: its two values from its sweep, τ₀ from the proto-sac sweep; kept out of the method tables
    assert "| hopper-medium | 0.0025 | 30.0 | 20.0 | 83.5 ± 0.8 | 83.5 [" in text
    assert "| hopper-medium | 0.005 (default) | 30.0 | 27.0 | 81.0 ± 0.8 | 81.0 [" in text
    assert "| hopper-medium | 0.01 | 30.0 | 20.0 | 91.0 ± 0.8 | 91.0 [" in text
    # seeds 82.5..84.5 and 90..92 against the default's 80..82: both CIs lie above the default's
    assert "**Reading:** on 0 of 2 (dataset, τ) pairs the final IQM's 95% CI overlaps the default's; separate: " \
        "hopper-medium τ 0.0025 (83.5 [" in text and "; hopper-medium τ 0.01 (91.0 [" in text
    assert "= {0.5, 1, 2} × τ₀" in text and "| ablate-tau |" not in text and "η ∈" not in text
    png = published / "locomotion" / "aggregate.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    agg = json.loads((published / "locomotion" / "aggregate.json").read_text())
    assert agg["frozen"]["iqm"][-1] == pytest.approx(61.0) and agg["direct"]["n_runs"] == 6
    assert agg["direct"]["fraction"][:2] == [0.0, 0.25] and agg["direct"]["iqm"][0] == 30.0  # from π₀ at step 0
    for dataset in ("hopper-medium", "walker2d-medium"):  # each dataset's learning curves, linked from its section
        assert (published / "locomotion" / dataset / "curves.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"![{dataset} learning curves](results/locomotion/{dataset}/curves.png)" in text


def test_claim_3_takes_its_ratio_from_the_dedicated_overhead_measurement_with_its_spread(published, tmp_path):
    mod = load_module()
    # interleaved repetitions: PROTO 10.5, 12, 9 s against SAC 10, 10, 10 s -> per repetition 1.05, 1.20, 0.90
    overhead = {"command": "python benchmarks/methods_cost.py --reps 3", "date": "later", "status": "dedicated",
                "results": {"proto-sac": {"seconds_per_1e5_steps": 105.0, "times_s": [10.5, 12.0, 9.0]},
                            "sac-scratch": {"seconds_per_1e5_steps": 100.0, "times_s": [10.0, 10.0, 10.0]}}}
    (tmp_path / "overhead.json").write_text(json.dumps(overhead))
    args = mod.Args(results=published / "locomotion", cost=published / "cost.json", bundles=published / "none",
                    record=published / "datasets.json", out=tmp_path / "RESULTS.md", readme=None,
                    overhead=tmp_path / "overhead.json")
    mod.main(args)
    text = args.out.read_text()
    assert ("wall time per online step = 1.05 (`python benchmarks/methods_cost.py --reps 3`, later; dedicated; "
            "per-repetition ratios 0.90–1.20)." in text)
    assert "= 1.10" not in text and "| proto-sac | 110 |" in text  # the cost table still shows the full run
    sac_only = {"results": {"sac-scratch": overhead["results"]["sac-scratch"]}}  # lacks PROTO: the table's run
    (tmp_path / "overhead.json").write_text(json.dumps(sac_only))
    assert mod.claim_cost(args, json.loads(args.cost.read_text()))["status"] == "test"


def test_a_readme_without_the_markers_is_refused_before_anything_is_written(published, tmp_path):
    mod = load_module()
    readme = tmp_path / "README.md"
    readme.write_text(f"{mod.README_END}\nno begin marker\n{mod.README_BEGIN}\n")  # the markers out of order
    results = tmp_path / "locomotion"  # a copy without the plots, to see that none is written
    shutil.copytree(published / "locomotion", results, ignore=shutil.ignore_patterns("*.png", "aggregate.json"))
    args = mod.Args(results=results, cost=published / "cost.json", bundles=published / "none",
                    record=published / "datasets.json", out=tmp_path / "RESULTS.md", readme=readme,
                    overhead=published / "none.json")
    with pytest.raises(SystemExit, match="lacks the lines"):
        mod.main(args)
    assert not args.out.exists() and "no begin marker" in readme.read_text()
    assert not list(results.rglob("*.png")) and not (results / "aggregate.json").exists()


def test_dataset_curves_are_mean_and_std_over_seeds_from_pi0(published, tmp_path):
    mod = load_module()
    table = mod.collect(published / "locomotion", published / "none")
    curves = mod.dataset_curves("hopper-medium", table["hopper-medium"], tmp_path / "curves.png")
    assert list(curves) == ["proto-sac", "frozen", "direct"]  # the paper's order; the τ ablation is not a method
    c = curves["proto-sac"]  # seed s: π₀ 30, then 28 - s, 50, 80 + s, 80 + s at steps 100, 200, 300, 1000
    assert c["steps"] == [0, 100, 200, 300, 1000] and c["n_runs"] == 3
    assert c["center"] == pytest.approx([30.0, 27.0, 50.0, 81.0, 81.0])
    sd = (2 / 3) ** 0.5  # population std of {s, s + 1, s + 2}
    assert c["high"] == pytest.approx([30.0, 27.0 + sd, 50.0, 81.0 + sd, 81.0 + sd])
    assert c["low"] == pytest.approx([30.0, 27.0 - sd, 50.0, 81.0 - sd, 81.0 - sd])
    assert (tmp_path / "curves.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_locomotion_runner_publishes_a_finished_sweep_reproducibly(tmp_path):
    """benchmarks/locomotion.py's publish (``locomotion_plan.publish``): config, gzipped metrics (same bytes on a
    rerun) and summary last."""
    src = tmp_path / "runs" / "hopper-medium" / "direct"
    (src / "report").mkdir(parents=True)
    rows = "".join(json.dumps({"step": s, "normalized_score": float(s)}) + "\n" for s in (0, 100))
    (src / "metrics.jsonl").write_text(rows)
    (src / "config.json").write_text("{}")
    (src / "summary.json").write_text('{"points": []}')
    (src / "report" / "curves.png").write_bytes(b"png")
    dst = tmp_path / "results" / "hopper-medium" / "direct"
    locomotion_plan.publish(src, dst)
    first = (dst / "metrics.jsonl.gz").read_bytes()
    assert gzip.decompress(first).decode() == rows
    assert (dst / "summary.json").read_text() == '{"points": []}' and (dst / "report" / "curves.png").exists()
    assert sorted(p.name for p in dst.iterdir()) == ["config.json", "metrics.jsonl.gz", "report", "summary.json"]
    locomotion_plan.publish(src, dst)
    assert (dst / "metrics.jsonl.gz").read_bytes() == first


def test_locomotion_runner_publishes_a_finished_unpublished_sweep_without_rerunning(tmp_path, capsys):
    """A sweep that finished (summary.json in its working dir) while the runner was stopped is published, not rerun."""
    loco = load_module("locomotion")
    src = tmp_path / "runs" / "hopper-medium" / "direct"
    src.mkdir(parents=True)
    (src / "metrics.jsonl").write_text(json.dumps({"step": 0}) + "\n")
    (src / "config.json").write_text("{}")
    summary = {"grid_keys": ["tau"], "points": [{"tau": 0.005, "final_normalized_score": {"mean": 50.0, "std": 1.0}}]}
    (src / "summary.json").write_text(json.dumps(summary))
    args = loco.Args(datasets=("hopper-medium",), methods=("direct",), runs=tmp_path / "runs",
                     results=tmp_path / "results")
    loco.main(args)  # a rerun would start `python -m proto_brax.sweep` and print its command line first
    out = capsys.readouterr().out
    assert "proto_brax.sweep" not in out and "tau 0.005: final normalized 50.0 ± 1.0" in out
    assert json.loads((tmp_path / "results" / "hopper-medium" / "direct" / "summary.json").read_text()) == summary


def test_a_dataset_free_sweep_is_shared_by_its_envs_datasets_and_counted_once(tmp_path, capsys):
    """sac-scratch trains on no dataset: the runner copies hopper-medium's published sweep to hopper-random instead of
    rerunning it (walker2d's is not hopper's), and the aggregate counts its runs once."""
    loco, mod = load_module("locomotion"), load_module()
    results = tmp_path / "locomotion"
    publish(results, "hopper-medium", "proto-sac")
    publish(results, "hopper-medium", "sac-scratch")
    publish(results, "hopper-random", "proto-sac")
    args = loco.Args(datasets=("hopper-random",), methods=("sac-scratch",), runs=tmp_path / "runs", results=results)
    assert locomotion_plan.shared_sweep("walker2d-medium", "sac-scratch", results) is None
    # proto-sac trains on its dataset: never shared
    assert locomotion_plan.shared_sweep("hopper-random", "proto-sac", results) is None
    loco.main(args)
    assert "the same runs as hopper-medium" in capsys.readouterr().out
    copy = results / "hopper-random" / "sac-scratch"
    assert (copy / "metrics.jsonl.gz").read_bytes() == (results / "hopper-medium" / "sac-scratch" /
                                                        "metrics.jsonl.gz").read_bytes()
    out = tmp_path / "RESULTS.md"
    mod.main(mod.Args(results=results, cost=tmp_path / "none.json", bundles=tmp_path / "none", out=out, readme=None,
                      overhead=tmp_path / "none.json"))
    text = out.read_text()
    assert "| sac-scratch | 1 | 3 | 11.0 [" in text and "| proto-sac | 2 | 6 |" in text
    assert text.count("| sac-scratch | – | 30.0 | 2.0 | 11.0 ± 0.8 |") == 2  # one row in each hopper table


def test_locomotion_publish_copies_a_finished_sweep_reproducibly(tmp_path):
    """publish: config, gzipped metrics (same bytes on a rerun), report PNGs and summary.json (written last)."""
    src = tmp_path / "runs" / "hopper-medium" / "frozen"
    (src / "report").mkdir(parents=True)
    (src / "config.json").write_text('{"sweep": {}}')
    (src / "metrics.jsonl").write_text('{"chunk": 0, "step": 5}\n{"chunk": 1, "step": 10}\n')
    (src / "report" / "curves.png").write_bytes(b"\x89PNG fake")
    (src / "summary.json").write_text('{"steps": 10}')
    dst = tmp_path / "results" / "hopper-medium" / "frozen"
    locomotion_plan.publish(src, dst)
    first = (dst / "metrics.jsonl.gz").read_bytes()
    assert gzip.decompress(first).decode() == (src / "metrics.jsonl").read_text()
    assert (dst / "report" / "curves.png").read_bytes() == b"\x89PNG fake"
    assert json.loads((dst / "summary.json").read_text()) == {"steps": 10}
    locomotion_plan.publish(src, dst)
    assert (dst / "metrics.jsonl.gz").read_bytes() == first
    assert sorted(p.name for p in dst.iterdir()) == ["config.json", "metrics.jsonl.gz", "report", "summary.json"]


def one_seed_part(root: Path, seed: int, rate: float, content_hash: str = "ab", lr: float = 3e-4) -> Path:
    """A published one-seed part (``locomotion.py run --per-seed``): the rows of ``publish``'s proto-sac sweep for
    ``seed`` (run 0), its grid point, its layout and its dataset build."""
    d = publish(root / f"seed{seed}" / "hopper-medium", "x", "proto-sac", seeds=(seed,))
    rows = [json.loads(line) for line in gzip.decompress((d / "metrics.jsonl.gz").read_bytes()).decode().splitlines()]
    with gzip.open(d / "metrics.jsonl.gz", "wt") as f:
        f.write("".join(json.dumps({**r, "grid_updates_per_s": rate}) + "\n" for r in rows))
    point = {"tau": 0.005, "eta": 0.9, "alpha0": 2.0, "seed": seed}
    config = {"sweep": {"env": "hopper", "algo": "proto-sac", "seeds": [seed], "lr": lr}, "grid": [point],
              "layout": {"devices": 1, "runs_per_device": 1}, "dataset_metadata": {"content_hash": content_hash,
                                                                                 "seconds": 10.0 + seed}}
    (d / "config.json").write_text(json.dumps(config))
    (d / "summary.json").write_text(json.dumps({"env": "hopper", "steps": STEPS[-1], "grid_keys": ["tau"],
                                                "method": "proto-sac", "first_chunk_seconds_incl_compile": 60.0 + seed,
                                                "points": []}))
    return d


def test_one_seed_parts_merge_into_the_sweep_their_seeds_make_together(tmp_path):
    """``locomotion_plan.merge_parts``: the parts' rows renumbered by seed give the summary that the same rows run as
    one grid give (``publish`` of seeds 0-2); the config lists the grid in seed order and where each part ran; the
    report's cost is per run (each part's program ran one run); parts that differ in a setting or a dataset build, or
    repeat a seed, are refused before anything is written."""
    from proto_brax.experiment.summary import summarize_runs

    parts = [one_seed_part(tmp_path / "parts", s, rate) for s, rate in ((2, 30.0), (0, 10.0), (1, 20.0))]
    dst = tmp_path / "results" / "hopper-medium" / "proto-sac"
    summary = locomotion_plan.merge_parts(parts, dst)
    together = publish(tmp_path / "together", "hopper-medium", "proto-sac", seeds=(0, 1, 2))
    want = report.load_sweep(together).rows
    assert summary["points"] == summarize_runs(want, ["tau"]) and summary["points"][0]["seeds"] == [0, 1, 2]
    assert json.loads((dst / "summary.json").read_text())["first_chunk_seconds_incl_compile"] == 62.0
    merged = report.load_sweep(dst)
    assert [(r.run, r.seed) for r in merged.runs] == [(0, 0), (1, 1), (2, 2)]
    assert [r.rows for r in merged.runs] == [[{**x, "grid_updates_per_s": rate} for x in r.rows]
                                             for r, rate in zip(report.load_sweep(together).runs, (10.0, 20.0, 30.0))]
    config = json.loads((dst / "config.json").read_text())
    assert [p["seed"] for p in config["grid"]] == config["sweep"]["seeds"] == [0, 1, 2]
    assert [m["first_chunk_seconds_incl_compile"] for m in config["merged_from"]] == [60.0, 61.0, 62.0]
    cost = report.cost(merged)
    assert cost["updates_per_s"] == 20.0 and cost["updates_per_s_per_run"] == 20.0  # the parts' mean, per run
    assert (dst / "report" / "curves.png").exists()
    named = load_module().merged_sweeps(load_module().collect(tmp_path / "results", tmp_path / "none"))
    assert named[0].startswith("**Run seed by seed:** hopper-medium/proto-sac ran each seed")
    # refused: another dataset build, another setting, a repeated seed; nothing written
    for odd, why in ((one_seed_part(tmp_path / "odd", 3, 1.0, content_hash="cd"), "dataset_content_hash"),
                     (one_seed_part(tmp_path / "odd2", 3, 1.0, lr=1e-3), "sweep"),
                     (parts[0], "repeat a seed")):
        with pytest.raises(ValueError, match=why):
            locomotion_plan.merge_parts([*parts, odd], tmp_path / "refused")
        assert not (tmp_path / "refused").exists()


def test_the_runner_runs_seed_by_seed_and_merges_when_all_parts_are_in(tmp_path, capsys, monkeypatch):
    """``locomotion.py run --per-seed``: one-run sweeps (``--seeds K``, no report) into runs/.../parts/seed-K,
    each published as it finishes; merged into the sweep once seeds 0-4 are in, not before."""
    loco = load_module("locomotion")
    ran = []

    def fake_run(cmd, cwd, env):  # the sweep: leaves a finished one-seed sweep in --out
        args = sweep.parse_args(cmd[3:])
        assert args.seeds == (args.seeds[0],) and not args.report
        part = one_seed_part(tmp_path / "made", args.seeds[0], 5.0)
        out = Path(args.out)
        out.mkdir(parents=True)
        for f in ("config.json", "summary.json"):
            shutil.copy(part / f, out / f)
        (out / "metrics.jsonl").write_bytes(gzip.decompress((part / "metrics.jsonl.gz").read_bytes()))
        ran.append(args.seeds[0])
        return subprocess.CompletedProcess(cmd, 0)

    monkeypatch.setattr(loco.subprocess, "run", fake_run)
    args = loco.Args(datasets=("hopper-medium",), methods=("sac-scratch",), runs=tmp_path / "runs",
                     results=tmp_path / "results", per_seed=True, seeds=(3, 1))
    dst = tmp_path / "results" / "hopper-medium" / "sac-scratch"
    loco.main(args)
    assert ran == [3, 1] and not (dst / "summary.json").exists()
    assert (locomotion_plan.part_dir(dst, 3) / "summary.json").exists()
    assert "parts published for seeds [1, 3] of [0, 1, 2, 3, 4]" in capsys.readouterr().out
    assert "parts of seeds [1, 3]" in locomotion_plan.sweep_status("hopper-medium", "sac-scratch", args.runs,
                                                                   args.results, tmp_path)
    loco.main(dataclasses.replace(args, seeds=(0, 1, 2, 3, 4)))  # the other runner: 1 and 3 are not rerun
    assert ran == [3, 1, 0, 2, 4] and (dst / "summary.json").exists()
    assert json.loads((dst / "config.json").read_text())["sweep"]["seeds"] == [0, 1, 2, 3, 4]


def test_locomotion_queue_runs_the_ablations_only_on_their_datasets():
    plan = locomotion_plan.planned_sweeps(("hopper-medium", "ant-random"), ("proto-sac", "ablate-tau", "direct"),
                                          ablation_datasets=("hopper-medium",))
    assert plan == [("hopper-medium", "proto-sac"), ("hopper-medium", "ablate-tau"), ("hopper-medium", "direct"),
                    ("ant-random", "proto-sac"), ("ant-random", "direct")]


def test_locomotion_status_of_each_sweep_from_its_directories(tmp_path):
    """``locomotion.py status``: published -> done; no bundle of the method's first kind -> the command that makes it
    (with the variant's flags); a dataset-free method published on another dataset of the env -> shared; a working
    directory -> started; else pending."""
    runs, results, pretrained = tmp_path / "runs", tmp_path / "results", tmp_path / "pretrained"

    def status(dataset, method):
        return locomotion_plan.sweep_status(dataset, method, runs, results, pretrained)

    for d in (results / "hopper-medium" / "proto-sac", results / "hopper-medium" / "sac-scratch",
              pretrained / "hopper-random" / "eql", runs / "hopper-random" / "direct"):
        d.mkdir(parents=True)
    for d in (results / "hopper-medium" / "proto-sac", results / "hopper-medium" / "sac-scratch"):
        (d / "summary.json").write_text("{}")
    (pretrained / "hopper-random" / "eql" / "metadata.json").write_text("{}")
    (results / "hopper-medium" / "direct").mkdir(parents=True)  # an unfinished publish: no summary.json

    assert status("hopper-medium", "proto-sac") == "done"
    assert status("hopper-medium", "direct") == ("needs bundle: python -m proto_brax.pretrain --dataset hopper-medium "
                                                 "--algo eql --out checkpoints/pretrained/hopper-medium/eql")
    assert status("walker2d-random", "proto-official") == (
        "needs bundle: python -m proto_brax.pretrain --dataset walker2d-random --algo eql --policy gaussian --hp "
        "eql_weight_scale 1 eql_z_clip 7 --out checkpoints/pretrained/walker2d-random/eql-official")
    assert status("hopper-random", "sac-scratch") == "shared: copies hopper-medium's on run"
    assert status("walker2d-random", "sac-scratch") == "pending"  # hopper's sweep is not walker2d's
    assert status("hopper-random", "direct") == "started"
    assert status("hopper-random", "ablate-eta") == "pending"  # a PROTO-SAC sweep from the same eql bundle
    assert status("hopper-random", "iql") == ("needs bundle: python -m proto_brax.pretrain --dataset hopper-random "
                                              "--algo iql --out checkpoints/pretrained/hopper-random/iql")


def test_datasets_record_keeps_each_build_once_with_where_it_was_seen(tmp_path):
    rec_mod = load_module("datasets_record")
    meta = {"name": "hopper-medium", "content_hash": "ab" * 32, "size": 10, "kind": "medium", "env": "hopper",
            "seed": 0, "seconds": 1.0, "xla_flags": "", "returns": {"num_episodes": 2, "mean": 5.0}}
    for method in ("frozen", "direct"):  # two published sweeps that had the same copy in their buffer
        d = tmp_path / "sweeps" / "hopper-medium" / method
        d.mkdir(parents=True)
        (d / "config.json").write_text(json.dumps({"dataset_metadata": meta}))
    (tmp_path / "bundles" / "hopper-medium" / "eql").mkdir(parents=True)
    (tmp_path / "bundles" / "hopper-medium" / "eql" / "metadata.json").write_text(
        json.dumps({"dataset_content_hash": "ab" * 32}))
    args = rec_mod.Args(out=tmp_path / "datasets.json", bundles=tmp_path / "bundles", sweeps=tmp_path / "sweeps",
                        cache_dir=tmp_path / "empty-cache")
    rec_mod.main(args)
    rec = rec_mod.main(args)  # a rerun adds nothing
    (build,) = rec["hopper-medium"]["builds"]
    assert build["seen"] == [{"sweep": "hopper-medium/direct"}, {"sweep": "hopper-medium/frozen"}]
    assert build["bundles"] == ["hopper-medium/eql"] and build["returns"]["num_episodes"] == 2
    assert rec_mod.merge(rec, "hopper-medium", {**build, "content_hash": "cd" * 32}, {"date": "x"})  # another build
    assert len(rec["hopper-medium"]["builds"]) == 2


def test_ablation_reading_counts_values_whose_final_ci_overlaps_the_defaults():
    """η 0.8 and 1.0 spread over the default's finals (CIs overlap); the verdict names no value as separate."""
    mod = load_module()

    def run(eta: float, final: float) -> dict:
        return {"point": (mod.TAU0, eta, 1.0), "initial": 30.0, "drop": 25.0, "final": final}

    table = {"hopper-medium": {"proto-sac": {"runs": [run(mod.ETA0, f) for f in (80.0, 81.0, 82.0)]},
                               "ablate-eta": {"runs": [run(e, f) for e in (0.8, 1.0) for f in (78.0, 81.0, 84.0)]}}}
    text = "\n".join(mod.ablation_tables(table))
    assert "| hopper-medium | 0.9 (default) | 30.0 | 25.0 | 81.0 ± 0.8 | 81.0 [" in text
    assert ("**Reading:** on 2 of 2 (dataset, η) pairs the final IQM's 95% CI overlaps the default's: at these seed "
            "counts no η in the range is told apart from the default") in text
    assert "τ ∈" not in text and "separate:" not in text


def test_pre_fix_proto_td3_sweeps_are_named_and_marked():
    """A proto-td3 sweep whose final score is the one recorded before issue 35's backup fix is pre-fix: the status
    line counts and names it, its table row carries †; a rerun (another score) is neither."""
    rmd = load_module()

    def sweep(final):
        return {"summary": {"points": [{"final_normalized_score": {"mean": final}}]}}

    before = {"a-medium": {"final_normalized_score": {"mean": 41.5}},
              "b-medium": {"final_normalized_score": {"mean": 50.0}}}
    table = {"a-medium": {"proto-td3": sweep(41.5)}, "b-medium": {"proto-td3": sweep(47.25)},
             "c-medium": {"proto-sac": sweep(41.5)}}
    assert rmd.pre_fix_td3(table["a-medium"]["proto-td3"], "a-medium", before)
    assert not rmd.pre_fix_td3(table["b-medium"]["proto-td3"], "b-medium", before)
    assert not rmd.pre_fix_td3(sweep(41.5), "z-medium", before)  # no record: not pre-fix
    (status, _), = [rmd.td3_fix_status(table, before)]
    assert "1 of 2 published proto-td3 sweeps ran with the fixed backup" in status and "a-medium" in status
    assert "b-medium" not in status
    assert rmd.label("proto-td3", table["a-medium"]["proto-td3"], "a-medium", before) == "proto-td3†"
    assert rmd.label("proto-td3", table["b-medium"]["proto-td3"], "b-medium", before) == "proto-td3"
    assert rmd.label("proto-sac", sweep(41.5), "a-medium", before) == "proto-sac"
    (done, _), = [rmd.td3_fix_status({"b-medium": {"proto-td3": sweep(47.25)}}, before)]
    assert done.startswith("**PROTO-TD3 backup fix (issue 35):** all 1 published proto-td3 sweeps ran with the fixed")
    assert rmd.td3_fix_status({"c-medium": {"proto-sac": sweep(41.5)}}, before) == []  # no proto-td3: nothing to say


def test_rounding_check_tells_overlapping_final_cis_from_separate_ones(tmp_path):
    mod = load_module("rounding_check")

    def sweep(name: str, finals: list[tuple[float, float, float]]) -> Path:
        points = [{"tau": tau, "final_normalized_score": {"iqm": (lo + hi) / 2, "iqm_low": lo, "iqm_high": hi,
                                                          "mean": (lo + hi) / 2, "std": 1.0}}
                  for tau, lo, hi in finals]
        d = tmp_path / name
        d.mkdir()
        (d / "summary.json").write_text(json.dumps({"grid_keys": ["tau"], "points": points}))
        (d / "config.json").write_text(json.dumps({"dataset_vs_bundle": name}))
        return d

    published = sweep("published", [(0.0, 60.0, 70.0), (0.005, 80.0, 90.0)])
    touching = sweep("touching", [(0.0, 70.0, 75.0), (0.005, 70.0, 80.0)])  # CIs meeting at one end still overlap
    apart = sweep("apart", [(0.0, 50.0, 59.9), (0.005, 85.0, 86.0)])
    out = tmp_path / "rc.json"
    result = mod.main(mod.Args(new=touching, published=published, out=out))
    assert [r["ci_overlap"] for r in result["rows"]] == [True, True] and result["all_final_cis_overlap"]
    result = mod.main(mod.Args(new=apart, published=published, out=out))
    assert [r["ci_overlap"] for r in result["rows"]] == [False, True] and not result["all_final_cis_overlap"]
    assert json.loads(out.read_text())["dataset_vs_bundle"] == {"new": "apart", "published": "published"}
    other_grid = sweep("other", [(0.01, 60.0, 70.0), (0.005, 80.0, 90.0)])
    with pytest.raises(SystemExit, match="grids differ"):
        mod.compare(json.loads((other_grid / "summary.json").read_text()),
                    json.loads((published / "summary.json").read_text()))


def test_comparisons_beside_the_papers_pair_datasets_and_say_whether_cis_separate(tmp_path):
    """RLPD ends 40 below PROTO-SAC on every seed: CIs separate; the official variant ends where PROTO-SAC does: CIs
    overlap. Unpublished comparisons name the command that runs them."""
    mod = load_module()
    root = tmp_path / "locomotion"
    for method in ("proto-sac", "rlpd-utd1", "proto-official"):
        d = publish(root, "hopper-medium", method)
        config = json.loads((d / "config.json").read_text())
        (d / "config.json").write_text(json.dumps({**config, "finetune": {"updates_per_step": 1}}))
    publish(root, "walker2d-medium", "rlpd-utd1")  # no proto-sac there: not paired
    table = mod.collect(root, tmp_path / "none")
    rlpd, official = (mod.comparison(table, c) for c in mod.COMPARISONS)
    text = "\n".join(rlpd)
    # finals: RLPD 40 + s, PROTO-SAC 80 + s over seeds 0, 1, 2 (population std √(2/3) = 0.8)
    assert "| hopper-medium | rlpd-utd1 | UTD 1, 1,000 steps | 41.0 ± 0.8 |" in text
    assert "| 81.0 ± 0.8 |" in text and "walker2d-medium" not in text
    assert "over 1 dataset(s) (hopper-medium)" in text and "CIs separate (PROTO-SAC higher)" in text
    assert "CIs overlap" in "\n".join(official)
    table.pop("hopper-medium")
    empty = "\n".join(mod.comparison(table, mod.COMPARISONS[0]))
    assert ("Not published yet: `python benchmarks/locomotion.py run --methods rlpd-utd1 rlpd --datasets hopper-medium "
            "halfcheetah-medium`") in empty


def test_fidelity_ablations_are_tabled_against_proto_official(tmp_path):
    """proto-official's rows one at a time: each ablation's scores, what it puts back, and whether its final CI
    separates from proto-official's (here the temperature ablation ends near 31, proto-official near 81)."""
    mod = load_module()
    root = tmp_path / "locomotion"
    for method in ("proto-sac", "proto-official", "official-but-temperature"):
        publish(root, "hopper-medium", method)
    publish(root, "walker2d-medium", "proto-official")  # no ablation there: no rows
    table = mod.collect(root, tmp_path / "none")
    text = "\n".join(mod.fidelity_ablations(table))
    assert "| hopper-medium | official-but-temperature | row 2: the temperature loss log α·(H − H̄) |" in text
    assert "| 31.0 ± 0.8 |" in text and "CIs separate (proto-official higher)" in text
    assert "| hopper-medium | proto-sac | none of them |" in text and "CIs overlap |" in text
    assert "walker2d-medium" not in text and "official-but-actor-q |" not in text  # unpublished rows are left out
    assert "official-but-temperature" not in mod.methods_of(table["hopper-medium"])  # not a method column
    table.pop("hopper-medium")
    assert mod.fidelity_ablations(table) == []


def test_other_domains_get_a_section_with_success_rates_and_claims(tmp_path):
    """An Adroit sweep published as locomotion.py --domain adroit writes it: the section states its budget, the
    methods' final scores and final success rates (IQM over seeds: the middle of three), the claims on its own
    sweeps, and its curves; a domain with nothing published names the command that runs it."""
    mod = load_module()
    root = tmp_path / "adroit"
    for method in ("proto-sac", "direct", "frozen"):
        d = publish(root, "pen-human", method)
        rows = [json.loads(line) for line in gzip.open(d / "metrics.jsonl.gz", "rt")]
        with gzip.open(d / "metrics.jsonl.gz", "wt") as f:  # success = score / 100, as distinct per seed
            f.write("\n".join(json.dumps({**r, "success_rate": r["normalized_score"] / 100}) for r in rows) + "\n")
    text = "\n".join(mod.domain_section(locomotion_plan.DOMAINS["adroit"], root, tmp_path / "none"))
    assert "## Adroit (pen, door, hammer on MJX)" in text
    assert "online budget 1,000 steps per run" in text and "Published: 3 of the 12 planned sweeps" in text
    # finals: proto-sac 80 + s, frozen 60 + s, direct 70 + s; success the same / 100
    assert "| proto-sac | 1 | 3 | 81.0 [" in text and "| 0.81 [" in text
    assert "| direct | – | 30.0 | 6.0 | 71.0 ± 0.8 | 71.0 [" in text and "| 3 | 0.71 [" in text
    assert "### The paper's three claims on adroit" in text
    assert ("(3) PROTO costs about what SAC costs:** not measured on adroit yet: `python benchmarks/methods_cost.py "
            "--env pen --methods proto-sac sac-scratch --reps 7 --out benchmarks/results/methods_cost_adroit.json`"
            in text)
    (tmp_path / "methods_cost_adroit.json").write_text(json.dumps({  # claim 3 from the domain's own measurement
        "command": "python benchmarks/methods_cost.py --env pen", "date": "d", "status": "median of 2",
        "results": {"proto-sac": {"seconds_per_1e5_steps": 130.0, "times_s": [1.3, 1.2]},
                    "sac-scratch": {"seconds_per_1e5_steps": 100.0, "times_s": [1.0, 1.2]}}}))
    text = "\n".join(mod.domain_section(locomotion_plan.DOMAINS["adroit"], root, tmp_path / "none"))
    assert ("PROTO-SAC / SAC-from-scratch wall time per online step = 1.30 (`python benchmarks/methods_cost.py --env "
            "pen`, d; median of 2; per-repetition ratios 1.00–1.30)") in text
    assert "PROTO ends above Frozen (τ = 0)** on 1 of 1 datasets" in text
    assert "--domain adroit --datasets pen-human --methods proto-sac frozen direct" in text
    assert (root / "pen-human" / "curves.png").stat().st_size > 0 and (root / "aggregate.png").exists()
    assert "FIDELITY.md's rows on" not in text  # none of them ran on adroit
    # FIDELITY.md's AntMaze rows: PROTO-SAC with one official choice, each against proto-sac
    maze = tmp_path / "antmaze"
    for method in ("proto-sac", "ours-but-random-target", "ours-but-behaviour-eval"):
        publish(maze, "antmaze-umaze-diverse", method)
    text = "\n".join(mod.domain_section(locomotion_plan.DOMAINS["antmaze"], maze, tmp_path / "none"))
    assert "### FIDELITY.md's rows on antmaze" in text
    assert "--methods ours-but-random-target ours-but-behaviour-eval --ablation-datasets DATASET" in text
    assert ("| antmaze-umaze-diverse | ours-but-random-target | row 3: one target critic drawn at random per update "
            "(clipped double-Q off) | 30.0 | 20.0 | 41.0 ± 0.8 | 41.0 [") in text
    assert "CIs separate (proto-sac higher) |" in text and "| 80.0 ± 0.8 | 80.0 [" in text
    assert "| ours-but-behaviour-eval | row 11: evaluated with sampled actions, as the policy trains |" in text
    assert text.count("CIs overlap |") == 1  # 79 + s against 80 + s
    assert "| ours-but-random-target |" not in text.split("FIDELITY.md's rows")[0]  # not a method of the tables
    empty = "\n".join(mod.domain_section(locomotion_plan.DOMAINS["antmaze"], tmp_path / "antmaze2", tmp_path / "none"))
    assert "Not published yet: `python benchmarks/locomotion.py run --domain antmaze --single-core`" in empty
    v5 = locomotion_plan.DOMAINS["mujoco-v5"]
    assert v5.datasets[0] == "hopper-v5-medium" and locomotion_plan.env_of(v5.datasets[0]) == "hopper-v5"
    assert "--domain mujoco-v5" in "\n".join(mod.domain_section(v5, tmp_path / "mujoco-v5", tmp_path / "none"))


def test_the_page_says_how_many_pretrained_seeds_the_sweeps_start_from(tmp_path):
    """A one-seed bundle is broadcast to every run seed, so its runs share π₀: the page counts those sweeps among the
    sweeps that start from a bundle (a sweep without one, or whose record lacks the seeds, is not counted) and names
    the sweeps whose bundle has one seed per run."""
    mod = load_module()
    root = tmp_path / "locomotion"
    bundle_seeds = {"proto-sac": [0], "frozen": [0], "rlpd-utd1": [0, 1, 2], "sac-scratch": None,
                    "direct": "unrecorded"}
    for method, seeds in bundle_seeds.items():
        d = publish(root, "hopper-medium", method)
        config = json.loads((d / "config.json").read_text())
        if seeds is not None:
            config["checkpoint_metadata"] = {} if seeds == "unrecorded" else {"seeds": seeds}
        (d / "config.json").write_text(json.dumps(config))
    text = "\n".join(mod.pretrained_seeds(mod.collect(root, tmp_path / "none")))
    assert text.startswith("**Pretrained seeds:** 2 of the 3 sweeps that start from a bundle finetune every run")
    assert "Bundles with several seeds (one per run seed): 3 pretrained seeds: hopper-medium/rlpd-utd1." in text
    assert mod.pretrained_seeds({}) == []


def test_a_goal_task_gets_its_final_steps_to_goal_over_the_runs_that_reached_it(tmp_path):
    """AntMaze's evaluations log steps_to_goal (the successful episodes' mean length, NaN when none succeeded): the
    dataset table gets a column with its mean over the runs whose final evaluation reached the goal, and how many
    did; a domain whose evaluations log none (Adroit) gets no such column."""
    mod = load_module()
    root = tmp_path / "antmaze"
    finals = {"proto-sac": (400.0, math.nan, 610.0), "frozen": (math.nan,) * 3}
    for method, goal in finals.items():
        d = publish(root, "antmaze-umaze-diverse", method)
        rows = [json.loads(line) for line in gzip.open(d / "metrics.jsonl.gz", "rt")]
        with gzip.open(d / "metrics.jsonl.gz", "wt") as f:  # an earlier evaluation's length must not count
            f.write("\n".join(json.dumps({**r, "success_rate": 0.5, "steps_to_goal": goal[r["seed"]]
                                          if r["step"] == STEPS[-1] else 1.0}) for r in rows) + "\n")
    text = "\n".join(mod.domain_section(locomotion_plan.DOMAINS["antmaze"], root, tmp_path / "none"))
    assert "| final success IQM [95% CI] | final steps to goal | buffer data |" in text
    assert "| 0.50 [0.50, 0.50] | 505 (2 of 3) |" in text  # (400 + 610) / 2; seed 1 never reached it
    assert "| 0.50 [0.50, 0.50] | – (0 of 3) |" in text
    adroit = tmp_path / "adroit"
    publish(adroit, "pen-human", "proto-sac")
    assert "steps to goal |" not in "\n".join(mod.domain_section(locomotion_plan.DOMAINS["adroit"], adroit,
                                                                    tmp_path / "none"))


def test_a_method_beyond_a_domains_plan_is_tabled_but_not_counted_as_planned(tmp_path):
    """Published: N of the planned sweeps counts the plan's (dataset, method) pairs only: an extra method (here
    rlpd-utd1 on pen-human) read "13 of the 12 planned sweeps" on Adroit."""
    mod = load_module()
    root = tmp_path / "adroit"
    for method in ("proto-sac", "rlpd-utd1"):
        publish(root, "pen-human", method)
    text = "\n".join(mod.domain_section(locomotion_plan.DOMAINS["adroit"], root, tmp_path / "none"))
    assert "Published: 1 of the 12 planned sweeps" in text and "| rlpd-utd1 | 1 | 3 |" in text


def test_offline_score_reads_the_bundle_the_method_starts_from(tmp_path):
    """proto-official starts from its eql-official bundle: its offline column is that bundle's score, not eql's (the
    column showed our eql bundle's 48.9 for proto-official on halfcheetah-medium, whose π₀ scored 44.5)."""
    mod = load_module("results_md")
    for kind, score in (("eql", 48.9), ("eql-official", 44.5)):
        (tmp_path / "d" / kind).mkdir(parents=True)
        (tmp_path / "d" / kind / "metadata.json").write_text(json.dumps({"offline_eval": {"normalized_score_mean":
                                                                                          score}}))
    assert mod.offline_score(mod.bundle_meta(tmp_path, "d", "proto-sac")) == 48.9
    assert mod.offline_score(mod.bundle_meta(tmp_path, "d", "proto-official")) == 44.5
    assert math.isnan(mod.offline_score(mod.bundle_meta(tmp_path, "d", "sac-scratch")))


def test_the_critic_switch_table_sets_each_methods_online_loss_against_its_bundles(tmp_path):
    """The jump at the offline → online switch: first-period online critic loss (mean over seeds) over the loss of
    the bundle the method starts from; Q mean offline → first → last period. Distinct numbers per seed, period and
    bundle, so a mix-up of first and last or of the two bundles changes the table."""
    mod = load_module()
    root = tmp_path / "adroit"
    for method, scale in (("proto-sac", 1.0), ("direct", 3.0)):
        d = publish(root, "pen-human", method)
        rows = [json.loads(line) for line in gzip.open(d / "metrics.jsonl.gz", "rt")]
        with gzip.open(d / "metrics.jsonl.gz", "wt") as f:  # loss 1000·scale·(1 + seed) first, then 10× lower
            f.write("\n".join(json.dumps({**r, **({} if r.get("initial") else {
                "critic_loss": scale * 1000.0 * (1 + r["seed"]) / (1 if r["step"] == STEPS[0] else 10),
                "q_mean": 50.0 + r["step"] / 100})}) for r in rows) + "\n")
    bundles = tmp_path / "bundles"
    for kind, loss in (("eql", [40.0, 60.0]),):
        (bundles / "pen-human" / kind).mkdir(parents=True)
        (bundles / "pen-human" / kind / "metadata.json").write_text(json.dumps(
            {"final_losses": {"critic_loss": loss, "q_mean": [70.0, 90.0]}}))
    table = mod.collect(root, bundles)
    text = "\n".join(mod.critic_switch(table))
    # seeds 0-2: first-period losses 1000, 2000, 3000 (mean 2000) against the bundle's 50: a 40× jump; Q 51 at the
    # first evaluation (step 100), 60 at the last (step 1000)
    assert "| pen-human | proto-sac | 50 | 2000 | 40.0× | 200 | 80 → 51 → 60 |" in text
    assert "| pen-human | direct | 50 | 6000 | 120.0× | 600 | 80 → 51 → 60 |" in text
    assert mod.critic_switch(mod.collect(root, tmp_path / "none")) != []  # no bundle: the jump is "–"
    assert "| – | 2000 | –× |" in "\n".join(mod.critic_switch(mod.collect(root, tmp_path / "none")))


