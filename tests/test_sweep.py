"""The sweep CLI: outputs, refusal to clobber, validation before compiling, and SIGKILL + --resume."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from proto_brax import sweep
from proto_brax.agents.sac import SACHParams
from proto_brax.experiment.plan import REPO_ROOT, finetune_config, resolve_checkpoint, resolve_dataset, reward_transform
from proto_brax.experiment.run import metric_rows
from proto_brax.experiment.summary import steady_throughput, summarize_runs

TINY = ["--env", "point", "--dataset", "none", "--hidden", "32", "32", "--batch-size", "32", "--learning-starts", "64",
        "--eval-episodes", "2", "--tau", "0", "0.01", "--eta", "0.9", "--seeds", "0", "1"]


def _run(out: Path, *extra: str, steps: int = 1200) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "proto_brax.sweep", *TINY, "--steps", str(steps), "--eval-every", "200",
           "--out", str(out), *extra]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})


def _metrics(out: Path) -> dict:
    rows = [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()]
    return {(r["chunk"], r["run"]): r for r in rows}


def test_sigkill_then_resume_matches_uninterrupted(tmp_path):
    full, killed = tmp_path / "full", tmp_path / "killed"
    p = _run(full)
    p.communicate(timeout=600)
    assert p.returncode == 0
    summary = json.loads((full / "summary.json").read_text())
    assert len(summary["points"]) == 2 and (full / "config.json").exists()

    p = _run(killed)
    deadline = time.time() + 600
    while time.time() < deadline:  # kill once π₀'s rows and two chunks are logged (of six)
        if (killed / "metrics.jsonl").exists() and len((killed / "metrics.jsonl").read_text().splitlines()) >= 12:
            break
        time.sleep(0.2)
    p.send_signal(signal.SIGKILL)
    p.wait()
    n_before = len((killed / "metrics.jsonl").read_text().splitlines())
    assert n_before < 28, "the sweep finished before it could be killed"
    with open(killed / "metrics.jsonl", "a") as f:  # and a kill inside an append (issue 32): a torn last line
        f.write('{"chunk": 5, "run": 0, "eval_ret')

    p = _run(killed, "--resume")
    out, _ = p.communicate(timeout=600)
    assert p.returncode == 0, out
    assert "resumed after chunk" in out and "dropped a torn last line" in out
    a, b = _metrics(full), _metrics(killed)
    assert a.keys() == b.keys() and len(a) == 28  # 4 runs × (π₀ at step 0 + 6 chunks), none logged twice
    for k in a:
        metrics = ("eval_return", "critic_loss", "actor_loss", "q_mean", "dev_pi0") if k[0] >= 0 else ("eval_return",)
        for m in metrics:
            assert a[k][m] == b[k][m], (k, m)
    assert all(a[(-1, r)]["step"] == 0 and a[(-1, r)]["initial"] for r in range(4))
    point = summary["points"][0]
    assert point["initial_normalized_score"]["n"] == 2 and "min_normalized_first_10pct" in point


def test_existing_out_is_refused_without_resume_or_overwrite(tmp_path):
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "config.json").write_text("{}")
    args = sweep.SweepArgs(env="point", dataset="none", out=tmp_path / "x")
    with pytest.raises(FileExistsError, match="--resume .* --overwrite"):
        sweep.run_sweep(args)


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(tau=(2.0,)), "tau must lie in"),
        (dict(eta=(-1.0,)), "eta must be >= 0"),
        (dict(alpha0=()), "grid is empty"),
        (dict(seeds=(0, 0)), "Duplicate seeds"),
        (dict(env="hoper"), "Unknown env"),
        (dict(sampling="symmetric", dataset="none"), "needs offline data"),
        (dict(dataset="/nonexistent.npz"), "does not exist"),
        (dict(dataset="hopper-mediun"), "Unknown dataset"),
    ],
)
def test_bad_input_fails_before_compiling(tmp_path, kw, match):
    args = sweep.SweepArgs(out=tmp_path / "o", **kw)
    with pytest.raises((ValueError, FileNotFoundError), match=match):
        sweep.run_sweep(args)
    assert not (tmp_path / "o").exists()  # nothing written


def test_presets_set_defaults_that_flags_override():
    args = sweep.parse_args(["--preset", "paper-mujoco", "--env", "walker2d", "--seeds", "0"])
    assert args.tau == (5e-3,) and args.eta == (0.9,) and args.alpha0 == (2.0,) and args.steps == 1_000_000
    assert args.anneal_horizon == 1e6 and args.env == "walker2d" and args.seeds == (0,)
    assert sweep.parse_args(["--steps", "2000", "--preset", "smoke"]).steps == 2000
    am = sweep.parse_args(["--preset", "paper-antmaze", "--steps", "4000"])
    assert (am.env, am.tau, am.alpha0, am.value_reg_backup, am.clipped_double_q) == (
        "antmaze-medium", (5e-5,), (0.5,), False, False)
    assert am.steps == 4000 and am.pretrain_steps == 200_000 and am.pretrain_hp == {"alpha": 0.5}
    assert resolve_dataset(am) == "antmaze-medium-diverse"
    ad = sweep.parse_args(["--preset", "paper-adroit", "--env", "door", "--dataset", "D4RL/door/human-v2"])
    assert (ad.env, ad.tau, ad.alpha0, ad.value_reg_backup, ad.clipped_double_q, ad.pretrain_steps) == (
        "door", (5e-5,), (2.0,), False, True, 100_000)
    assert resolve_dataset(ad) == "D4RL/door/human-v2"
    with pytest.raises(SystemExit, match="--preset needs one of"):
        sweep.parse_args(["--preset", "paper-mujocoo"])


def test_diverged_run_is_marked_while_others_continue():
    from test_engine import SCRATCH, TINY, finetune_fn

    from proto_brax.train.grid import make_grid, run_grid

    ft, _ = finetune_fn(TINY)
    grid = make_grid({"lr_critic": [1e-3, 1e9]}, seeds=[0], base=SCRATCH, hparams=SACHParams)
    _, m = run_grid(ft, grid)
    rows = [r for c in range(TINY.num_chunks) for r in metric_rows(c, jax_tree_chunk(m, c), grid, "point", 0.0)]
    good = [r for r in rows if r["lr_critic"] == 1e-3]
    bad = [r for r in rows if r["lr_critic"] == 1e9]
    assert not any(r["diverged"] for r in good) and all(np.isfinite(r["eval_return"]) for r in good)
    assert any(r["diverged"] for r in bad)
    summary = summarize_runs(rows, ["lr_critic"])
    by = {s["lr_critic"]: s for s in summary}
    assert by[1e9]["diverged_seeds"] == [0] and by[1e-3]["diverged_seeds"] == []


def jax_tree_chunk(m, c):
    return {k: v[c] for k, v in m.items()}


def test_tensorboard_event_files_hold_the_metrics(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    args = sweep.parse_args(["--preset", "smoke", "--tau", "0.005", "--alpha0", "2.0", "--seeds", "0",
                             "--tensorboard", "--no-report", "--out", str(tmp_path / "tb")])
    sweep.run_sweep(args)
    runs = sorted((tmp_path / "tb" / "tensorboard").iterdir())
    assert [p.name for p in runs] == ["run_000"]
    acc = EventAccumulator(str(runs[0]))
    acc.Reload()
    rows = [json.loads(x) for x in (tmp_path / "tb" / "metrics.jsonl").read_text().splitlines()]
    got = [e.value for e in acc.Scalars("eval_return")]
    np.testing.assert_allclose(got, [r["eval_return"] for r in rows], rtol=1e-6)
    assert [e.step for e in acc.Scalars("eval_return")] == [r["step"] for r in rows]


def test_pretrain_then_finetune_in_one_command(tmp_path):
    import jax
    from test_engine import point_dataset

    from proto_brax.data.dataset import save_npz

    data = tmp_path / "pt.npz"
    save_npz(data, jax.device_get(point_dataset()), {"env": "point"})
    args = sweep.parse_args(["--preset", "smoke", "--tau", "0.005", "--alpha0", "1.0", "--seeds", "0", "1",
                             "--dataset", str(data), "--pretrain", "bc", "--pretrain-steps", "300",
                             "--reward-scale", "2.0", "--no-report", "--out", str(tmp_path / "o")])
    sweep.run_sweep(args)
    cfg = json.loads((tmp_path / "o" / "config.json").read_text())
    assert cfg["checkpoint_metadata"]["algo"] == "bc" and cfg["checkpoint_metadata"]["seeds"] == [0, 1]
    # the reward transform reaches the bundle (its FQE critic) and the finetuning runs alike
    assert cfg["checkpoint_metadata"]["reward_scale"] == 2.0 and cfg["finetune"]["reward_scale"] == 2.0
    assert (tmp_path / "o" / "pretrained" / "metadata.json").exists()
    with pytest.raises(ValueError, match="--pretrain needs --dataset"):
        sweep.run_sweep(dataclasses.replace(args, dataset=None, out=tmp_path / "x"))


def test_auto_dataset_and_checkpoint_resolution():
    args = sweep.SweepArgs(env="walker2d")
    assert resolve_dataset(args) == "walker2d-medium"
    assert resolve_dataset(dataclasses.replace(args, dataset="none")) is None
    assert resolve_checkpoint(dataclasses.replace(args, checkpoint="none")) is None
    assert resolve_checkpoint(dataclasses.replace(args, env="point")) is None  # no committed point bundle
    hm = resolve_checkpoint(sweep.SweepArgs())
    committed = REPO_ROOT / "checkpoints" / "pretrained" / "hopper-medium" / "eql"
    assert hm == (committed if (committed / "metadata.json").exists() else None)


def test_reward_transform_resolution():
    """Bundle's transform first (explicit disagreement is an error), then flags, then the env's rule on the data."""
    from test_engine import point_dataset

    from proto_brax.data.dataset import return_range_scale

    args = sweep.SweepArgs(env="hopper")
    assert reward_transform(args, {"reward_scale": 0.5, "reward_shift": 0.0}, None) == {
        "reward_scale": 0.5, "reward_shift": 0.0}
    assert reward_transform(args, {}, None) == {"reward_scale": 1.0, "reward_shift": 0.0}  # pre-transform bundle
    with pytest.raises(ValueError, match="pretrained with reward_scale 0.5"):
        reward_transform(dataclasses.replace(args, reward_scale=1.0), {"reward_scale": 0.5}, None)
    assert reward_transform(dataclasses.replace(args, reward_scale=0.5), {"reward_scale": 0.5}, None)[
        "reward_scale"] == 0.5
    data = point_dataset()  # several episodes with different returns: hopper's rule applies to any data
    assert reward_transform(args, None, data)["reward_scale"] == pytest.approx(return_range_scale(data))
    assert reward_transform(args, None, None) == {"reward_scale": 1.0, "reward_shift": 0.0}  # online only
    assert reward_transform(dataclasses.replace(args, reward_scale=3.0, reward_shift=-2.0), None, data) == {
        "reward_scale": 3.0, "reward_shift": -2.0}
    assert reward_transform(sweep.SweepArgs(env="point"), None, data) == {"reward_scale": 1.0,
                                                                                "reward_shift": 0.0}
    assert reward_transform(sweep.SweepArgs(env="antmaze-umaze"), None, None) == {"reward_scale": 1.0,
                                                                                        "reward_shift": -1.0}


def test_summary_reports_success_where_the_rows_have_it():
    """Adroit rows carry a success rate (no steps to goal), goal-task rows both, locomotion rows neither: the summary
    reports exactly what the rows hold, as mean over seeds of the last evaluation."""
    def rows(extra_by_seed):
        return [{"seed": s, "tau": 0.005, "step": step, "eval_return": 1.0, "normalized_score": 1.0, "dev_pi0": 0.0,
                 "diverged": False, **extra} for s, extra in extra_by_seed.items() for step in (100, 200)]

    adroit = summarize_runs(rows({0: {"success_rate": 0.2}, 1: {"success_rate": 0.6}}), ["tau"])[0]
    assert adroit["final_success_rate"]["mean"] == pytest.approx(0.4) and "final_steps_to_goal" not in adroit
    goal = summarize_runs(rows({0: {"success_rate": 1.0, "steps_to_goal": 300.0},
                                      1: {"success_rate": 0.5, "steps_to_goal": 500.0}}), ["tau"])[0]
    assert goal["final_success_rate"]["mean"] == 0.75 and goal["final_steps_to_goal"]["mean"] == 400.0
    loco = summarize_runs(rows({0: {}, 1: {}}), ["tau"])[0]
    assert "final_success_rate" not in loco and "final_steps_to_goal" not in loco


def test_steady_throughput_leaves_out_the_first_and_the_warm_up_chunks():
    """Chunk 0 compiles; chunk 1 is half warm-up (fewer updates, same time): neither is steady throughput."""
    rows = [{"chunk": c, "run": r, "updates": u, "grid_updates_per_s": v}
            for c, u, v in ((0, 100, 5.0), (1, 50, 40.0), (2, 100, 90.0), (3, 100, 110.0)) for r in range(3)]
    rows.append({"initial": True, "chunk": -1, "grid_updates_per_s": float("nan")})  # π₀'s row
    assert steady_throughput(rows, 100) == 100.0
    assert steady_throughput(rows[:6], 100) is None


def test_help_lists_every_registered_env(capsys):
    from proto_brax.envs import REGISTRY

    with pytest.raises(SystemExit):
        sweep.parse_args(["--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "Envs (--env):" in out and all(name in out for name in REGISTRY)


def test_critic_layer_norm_rule_is_the_registrys():
    """The paper's rule (LayerNorm on Q and V except halfcheetah) is one registry field, read by sweep and pretrain."""
    from proto_brax.envs import default_layer_norm

    assert default_layer_norm("hopper") and default_layer_norm("ant-v5")
    assert not default_layer_norm("halfcheetah") and not default_layer_norm("halfcheetah-v5")
    cfg = finetune_config(sweep.SweepArgs(env="halfcheetah", dataset="none", checkpoint="none"))
    assert cfg.net.critic_layer_norm is False
    cfg = finetune_config(sweep.SweepArgs(env="halfcheetah", dataset="none", checkpoint="none",
                                                 critic_layer_norm=True))
    assert cfg.net.critic_layer_norm is True


def test_default_dataset_size_never_exceeds_the_registered_set():
    """The default 10⁵ rows is capped at a registered dataset's own size (pen-human: 25 episodes of 100 steps), so
    `--dataset pen-human` loads the registered human set instead of building one 40× its size; what config.json
    records for the other defaults is unchanged (10⁵), so sweeps started before resume."""
    from proto_brax.experiment.args import SweepArgs
    from proto_brax.experiment.plan import resolve_dataset, resolve_dataset_size

    def size(**kw):
        args = SweepArgs(**kw)
        return resolve_dataset_size(args, resolve_dataset(args))

    assert size(env="pen", dataset="pen-human") == 2_500 and size(env="door", dataset="door-human") == 5_000
    assert size(env="hopper", dataset="hopper-medium") == 100_000 and size(env="hopper") == 100_000  # (auto)
    assert size(env="hopper", dataset="none") == 100_000 and size(env="pen", dataset="x.npz") == 100_000
    assert size(env="pen", dataset="pen-human", dataset_size=5_000) == 5_000  # an explicit size is the user's
