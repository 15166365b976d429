"""Fault injection (issue 32): one test per defect found by breaking things on purpose, so they stay fixed.

Fast tests use the point task, tiny networks and few steps; those that run several sweeps in subprocesses are marked
slow. The SIGKILL + --resume test (with a torn metrics line) is ``test_sweep.test_sigkill_then_resume_matches_...``.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from proto_brax import checkpoints, pretrain, sweep
from proto_brax.cli import datasets as datasets_cli
from proto_brax.cli.sweep import start_distributed
from proto_brax.data import cache as datasets
from proto_brax.data import dataset as ds
from proto_brax.experiment.outdir import append_rows, truncate_metrics
from proto_brax.experiment.plan import load_dataset

REPO = Path(__file__).resolve().parents[1]
SMALL = dict(env="point", dataset="none", hidden=(32, 32), batch_size=32, learning_starts=64, eval_episodes=2,
             tau=(0.0, 0.01), eta=(0.9,), seeds=(0,), steps=400, eval_every=200, report=False)
CLI = ["--env", "point", "--dataset", "none", "--hidden", "32", "32", "--batch-size", "32", "--learning-starts", "64",
       "--eval-episodes", "2", "--tau", "0", "0.01", "--eta", "0.9", "--seeds", "0", "--steps", "400",
       "--eval-every", "200", "--no-report"]


def _strict(text: str):
    """json.loads that rejects NaN/Infinity, as JavaScript's JSON.parse does."""
    def refuse(c):
        raise ValueError(f"not strict JSON: {c}")

    return json.loads(text, parse_constant=refuse)


def _random_data(n=60, obs=2, act=2, seed=0):
    r = np.random.default_rng(seed)
    f = lambda *s: r.uniform(-1, 1, s).astype(np.float32)  # noqa: E731
    term = np.zeros(n, np.float32)
    term[9::10] = 1
    return ds.Transition(observations=f(n, obs), actions=f(n, act), rewards=f(n), next_observations=f(n, obs),
                         terminals=term, timeouts=np.zeros(n, np.float32))


def _save_npz_unchecked(path: Path, data, meta: dict) -> None:
    """An .npz of our format (valid content hash) that save_npz itself would refuse (e.g. NaN rewards)."""
    arrays = {k: np.ascontiguousarray(np.asarray(getattr(data, k)), np.float32) for k in ds.FIELDS}
    h = hashlib.sha256()
    for k in ds.FIELDS:
        h.update(f"{k}|{arrays[k].dtype.str}|{list(arrays[k].shape)}\n".encode())
        h.update(arrays[k].tobytes())
    meta = {**meta, "format_version": ds.FORMAT_VERSION, "content_hash": h.hexdigest()}
    with open(path, "wb") as f:
        np.savez(f, **arrays, metadata=np.array(json.dumps(meta)))


@pytest.fixture(scope="module")
def tiny_sweep(tmp_path_factory):
    """One finished tiny sweep, run in this process (2 runs, 2 chunks)."""
    out = tmp_path_factory.mktemp("tiny") / "sweep"
    sweep.run_sweep(sweep.SweepArgs(out=out, **SMALL))
    return out


# 1. --overwrite deletes any directory ----------------------------------------------------------------------------


def test_overwrite_refuses_a_directory_that_is_not_a_sweep(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    (tmp_path / "src").mkdir()
    with pytest.raises(FileExistsError, match=r"not a sweep's output \(it holds notes.txt, src"):
        sweep.run_sweep(sweep.SweepArgs(out=tmp_path, overwrite=True, **SMALL))
    assert (tmp_path / "notes.txt").read_text() == "mine" and (tmp_path / "src").is_dir()
    # a sweep's config.json beside a foreign file does not make the directory a sweep's either
    (tmp_path / "config.json").write_text(json.dumps({"sweep": {}, "finetune": {}}))
    with pytest.raises(FileExistsError, match="notes.txt"):
        sweep.run_sweep(sweep.SweepArgs(out=tmp_path, overwrite=True, **SMALL))


def test_overwrite_keeps_the_old_sweep_when_a_later_check_fails(tmp_path):
    old = tmp_path / "old"
    old.mkdir()
    (old / "config.json").write_text(json.dumps({"sweep": {"steps": 1}, "finetune": {}}))
    (old / "metrics.jsonl").write_text('{"chunk": 0}\n')
    bad = tmp_path / "wrong-sizes.npz"  # point has 2-d observations and actions: this dataset has 5 and 3
    ds.save_npz(bad, _random_data(obs=5, act=3), {"env": "point"})
    args = sweep.SweepArgs(out=old, overwrite=True, **{**SMALL, "dataset": str(bad)})
    with pytest.raises(ValueError, match="observation size"):
        sweep.run_sweep(args)
    assert (old / "metrics.jsonl").read_text() == '{"chunk": 0}\n'  # the old sweep is untouched


# 2. a corrupted bundle loads silently ----------------------------------------------------------------------------


def test_corrupted_bundle_is_refused_naming_the_rebuild_command(tmp_path):
    src = REPO / "checkpoints" / "pretrained" / "hopper-medium" / "eql"
    bundle = tmp_path / "eql"
    shutil.copytree(src, bundle)
    checkpoints.load_bundle(bundle)  # intact: loads
    big = max((p for p in (bundle / "state").rglob("*") if p.is_file()), key=lambda p: p.stat().st_size)
    raw = bytearray(big.read_bytes())
    raw[len(raw) // 2: len(raw) // 2 + 4096] = np.random.default_rng(0).integers(0, 256, 4096, np.uint8).tobytes()
    big.write_bytes(bytes(raw))
    with pytest.raises(checkpoints.CheckpointError, match=r"(?s)corrupt.*python -m proto_brax.pretrain --dataset "
                       r"hopper-medium --algo eql .*--overwrite"):
        checkpoints.load_bundle(bundle)


def test_every_committed_bundle_records_a_content_checksum():
    bundles = [p.parent for p in (REPO / "checkpoints" / "pretrained").rglob("metadata.json")]
    assert bundles
    missing = [str(p) for p in bundles if not json.loads((p / "metadata.json").read_text()).get("content_sha256")]
    assert not missing


# 3. the layout: recorded, and a resume with another one refused -------------------------------------------------


def test_layout_is_recorded_and_a_resume_with_another_layout_is_refused(tiny_sweep, tmp_path):
    config = json.loads((tiny_sweep / "config.json").read_text())
    n = len(jax.devices())
    assert config["layout"] == {"devices": n, "platform": "cpu", "runs_per_device": -(-2 // n),
                                "padding": -(-2 // n) * n - 2, "processes": 1}
    other = tmp_path / "other"
    shutil.copytree(tiny_sweep, other)
    config["layout"] = {**config["layout"], "devices": n + 1}
    (other / "config.json").write_text(json.dumps(config))
    with pytest.raises(ValueError, match=rf"ran on {n + 1} cpu device.*resume with --devices {n + 1} --block vmap"):
        sweep.run_sweep(sweep.SweepArgs(out=other, resume=True, **SMALL))
    # --block map is part of the layout: a vmapped sweep does not resume as a mapped one
    with pytest.raises(ValueError, match=r"block vmap\), this process has .* block map\).*--block vmap"):
        sweep.run_sweep(sweep.SweepArgs(out=tiny_sweep, resume=True, block="map", **SMALL))


def test_a_sweep_recorded_before_a_field_existed_resumes_and_a_recorded_difference_is_refused(tiny_sweep, tmp_path):
    """A field added after the sweep started (here: --policy, fidelity.carry_critic_state) takes its default, the
    behaviour the sweep ran with: resume accepts it. A recorded field that differs is still refused."""
    config = json.loads((tiny_sweep / "config.json").read_text())
    old = tmp_path / "old"
    shutil.copytree(tiny_sweep, old)
    del config["sweep"]["policy"], config["sweep"]["fidelity"]["carry_critic_state"]
    (old / "config.json").write_text(json.dumps(config))
    before = (old / "metrics.jsonl").read_text()
    sweep.run_sweep(sweep.SweepArgs(out=old, resume=True, **SMALL))
    assert (old / "metrics.jsonl").read_text() == before  # finished: nothing re-run, nothing lost
    config["sweep"]["fidelity"]["actor_q"] = "mean"  # recorded, and not what this command asks for
    (old / "config.json").write_text(json.dumps(config))
    with pytest.raises(ValueError, match=r"configuration differs.*fidelity"):
        sweep.run_sweep(sweep.SweepArgs(out=old, resume=True, **SMALL))


@pytest.mark.slow
def test_same_command_twice_is_bit_identical(tmp_path):
    outs = [tmp_path / "a", tmp_path / "b"]
    for out in outs:
        p = subprocess.run([sys.executable, "-m", "proto_brax.sweep", *CLI, "--devices", "2", "--out", str(out)],
                           capture_output=True, text=True, timeout=600)
        assert p.returncode == 0, p.stdout + p.stderr
    a, b = ((o / "metrics.jsonl").read_text().splitlines() for o in outs)
    strip = lambda rows: [{k: v for k, v in json.loads(r).items() if k != "grid_updates_per_s"} for r in rows]  # noqa: E731
    assert strip(a) == strip(b) and len(a) == 6  # 2 runs × (π₀ + 2 chunks)


# 4. a truncated cached dataset -----------------------------------------------------------------------------------


def test_truncated_cached_dataset_names_the_make_command(tmp_path, monkeypatch):
    monkeypatch.setenv(datasets.ENV_VAR, str(tmp_path))
    path = datasets.dataset_path("point-random", 2000)
    ds.save_npz(path, _random_data(n=2000), {"env": "point", "kind": "random", "name": "point-random"})
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    fix = r"python -m proto_brax.datasets make point-random --size 2000 --force"
    with pytest.raises(ds.CorruptDatasetError, match=fix):
        load_dataset("point-random", 2000)
    with pytest.raises(ds.CorruptDatasetError, match=fix):
        datasets.load_dataset("point-random", 2000)
    with pytest.raises(ds.CorruptDatasetError, match=fix):
        datasets_cli.cmd_info(datasets_cli.Info(name="point-random", size=2000))


# 5. non-finite values caught only after the output directory was written ----------------------------------------


def test_non_finite_dataset_is_refused_on_load_before_anything_is_written(tmp_path):
    data = _random_data()
    rewards = np.array(data.rewards)
    rewards[[3, 17, 40]] = np.nan
    file = tmp_path / "nan.npz"
    _save_npz_unchecked(file, data.replace(rewards=rewards), {"env": "point"})
    out = tmp_path / "o"
    with pytest.raises(ValueError, match=r"non-finite values \(NaN or ±inf\): 3 in rewards"):
        sweep.run_sweep(sweep.SweepArgs(out=out, **{**SMALL, "dataset": str(file)}))
    assert not out.exists()
    with pytest.raises(ValueError, match="nothing was written"):  # and save_npz does not write such data
        ds.save_npz(tmp_path / "x.npz", data.replace(rewards=rewards), {})
    assert not (tmp_path / "x.npz").exists()


def test_non_finite_values_in_a_d4rl_file_are_refused_naming_the_field(tmp_path):
    import h5py

    data = _random_data(n=50)
    obs = np.array(data.observations)
    obs[5, 1] = np.inf
    with h5py.File(tmp_path / "d.hdf5", "w") as f:
        for k in ("observations", "actions", "rewards", "terminals"):
            f[k] = obs if k == "observations" else np.asarray(getattr(data, k))
    with pytest.raises(ds.NonFiniteDatasetError, match="1 in observations"):
        ds.load_d4rl_hdf5(tmp_path / "d.hdf5")


# 6. a torn last line in metrics.jsonl -----------------------------------------------------------------------------


def test_resume_drops_a_torn_last_metrics_line(tmp_path):
    path = tmp_path / "metrics.jsonl"
    rows = [{"chunk": c, "run": r, "eval_return": 1.0} for c in (-1, 0) for r in (0, 1)]
    path.write_text("".join(json.dumps(r) + "\n" for r in rows) + '{"chunk": 1, "run": 0, "eval_ret')
    truncate_metrics(path, 1)
    assert [json.loads(x) for x in path.read_text().splitlines()] == rows


def test_one_chunk_of_rows_is_one_write(tmp_path, monkeypatch):
    calls = []
    real = os.write
    monkeypatch.setattr(os, "write", lambda fd, b: calls.append(len(b)) or real(fd, b))
    rows = [{"chunk": 0, "run": i, "eval_return": float(i), "pad": "x" * 700} for i in range(64)]  # > 40 kB
    append_rows(tmp_path / "m.jsonl", rows)
    assert len(calls) == 1 and calls[0] > 40_000
    assert len((tmp_path / "m.jsonl").read_text().splitlines()) == 64


# 7. distributed: flags, and process 1 never checks --out ----------------------------------------------------------


def test_help_names_the_coordinator_flags_not_unread_variables():
    p = subprocess.run([sys.executable, "-m", "proto_brax.sweep", "--help"], capture_output=True, text=True,
                       timeout=300)
    assert "--coordinator" in p.stdout and "--num-processes" in p.stdout and "--process-id" in p.stdout
    assert "JAX_NUM_PROCESSES" not in p.stdout and "JAX_PROCESS_ID" not in p.stdout
    with pytest.raises(ValueError, match="--coordinator needs --num-processes"):
        start_distributed(sweep.SweepArgs(coordinator="127.0.0.1:1234"))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_two_process_sweep_matches_one_process(tmp_path):
    one = tmp_path / "one"
    p = subprocess.run([sys.executable, "-m", "proto_brax.sweep", *CLI, "--devices", "2", "--out", str(one)],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stdout + p.stderr
    two = tmp_path / "two"  # process 0 creates it while process 1 runs: process 1 must not look at it
    port = _free_port()
    procs = [subprocess.Popen([sys.executable, "-m", "proto_brax.sweep", *CLI, "--devices", "1", "--coordinator",
                               f"127.0.0.1:{port}", "--num-processes", "2", "--process-id", str(i), "--out",
                               str(two)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
             for i in (0, 1)]
    outs = [q.communicate(timeout=600)[0] for q in procs]
    assert all(q.returncode == 0 for q in procs), "\n".join(o[-2000:] for o in outs)
    strip = lambda d: [{k: v for k, v in json.loads(r).items() if k != "grid_updates_per_s"}  # noqa: E731
                       for r in (d / "metrics.jsonl").read_text().splitlines()]
    assert strip(one) == strip(two)
    assert json.loads((two / "config.json").read_text())["layout"]["processes"] == 2


# 8. silent no-ops -------------------------------------------------------------------------------------------------


def test_learning_starts_beyond_the_run_is_an_error(tmp_path):
    with pytest.raises(ValueError, match=r"--learning-starts 100000 > --steps 200: no update would run"):
        sweep.run_sweep(sweep.SweepArgs(out=tmp_path / "o", **{**SMALL, "learning_starts": 100_000, "steps": 200,
                                                                 "eval_every": 100}))
    assert not (tmp_path / "o").exists()


def test_negative_devices_is_an_error(tmp_path):
    with pytest.raises(ValueError, match="--devices -1"):  # (env 'hoper' fails later, before compiling, if missed)
        sweep.run_sweep(sweep.SweepArgs(out=tmp_path / "o", devices=-1, **{**SMALL, "env": "hoper"}))


# 9. strict JSON ---------------------------------------------------------------------------------------------------


def test_outputs_are_strict_json_and_readers_take_null(tiny_sweep):
    from proto_brax.analysis.report import load_sweep

    rows = [_strict(x) for x in (tiny_sweep / "metrics.jsonl").read_text().splitlines()]
    assert all(r["grid_updates_per_s"] is None for r in rows if r["chunk"] == -1)  # π₀ rows: was bare NaN
    _strict((tiny_sweep / "summary.json").read_text())
    _strict((tiny_sweep / "config.json").read_text())
    s = load_sweep(tiny_sweep)  # (report.py, and benchmarks/results_md.py through it)
    assert np.isnan(s.runs[0].rows[0]["grid_updates_per_s"]) and s.runs[0].rows[0]["initial"]


# minor ------------------------------------------------------------------------------------------------------------


def test_resuming_a_finished_sweep_says_so(tiny_sweep, capsys):
    sweep.run_sweep(sweep.SweepArgs(out=tiny_sweep, resume=True, **SMALL))
    out = capsys.readouterr().out
    assert "nan s" not in out and "no chunk left to run" in out


def test_stale_save_temporaries_are_removed(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    root = tmp_path / "state"
    for name in (f".step_00000001.tmp-{dead.pid}", f".step_00000001.old-{dead.pid}"):  # a save killed midway
        (root / name / "state").mkdir(parents=True)
    checkpoints.save_step(root, 3, {"x": np.arange(3.0)}, {"chunks_done": 3})
    assert sorted(p.name for p in root.iterdir()) == ["step_00000003"]


def test_input_errors_are_one_line_without_traceback(tmp_path):
    cmd = [sys.executable, "-m", "proto_brax.sweep", "--env", "hoper", "--out", str(tmp_path / "o")]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    assert p.stderr.startswith("error: ") and "Unknown env" in p.stderr
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env={**os.environ, "PROTO_BRAX_DEBUG": "1"})
    assert p.returncode == 1 and "Traceback" in p.stderr


# pretrain and datasets make ---------------------------------------------------------------------------------------


def test_pretrain_overwrite_refuses_a_directory_that_is_not_a_bundle(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    data = tmp_path / "d.npz"
    ds.save_npz(data, _random_data(), {"env": "point"})
    with pytest.raises(FileExistsError, match="not a pretrained bundle .*notes.txt"):
        pretrain.pretrain(pretrain.PretrainArgs(dataset=str(data), out=tmp_path, overwrite=True, steps=100,
                                                log_every=100, hidden=(8,), batch_size=8))
    assert (tmp_path / "notes.txt").read_text() == "mine"
    with pytest.raises(checkpoints.CheckpointError, match="not a checkpoint"):  # and save() never replaces it
        checkpoints.save(tmp_path, {"x": np.zeros(2)}, {})
    assert (tmp_path / "notes.txt").read_text() == "mine"


def test_datasets_make_force_replaces_only_a_dataset_file(tmp_path):
    path = datasets.dataset_path("point-random", 2000, 0, tmp_path)
    path.mkdir(parents=True)
    (path / "keep.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="not a dataset file"):
        datasets_cli.cmd_make(datasets_cli.Make(name="point-random", size=2000, cache_dir=tmp_path, force=True))
    assert (path / "keep.txt").read_text() == "mine"


# 10. two processes writing one sweep ------------------------------------------------------------------------------

# Another process that holds DIR/.lock as files.lock_dir takes it, until it is killed.
HOLDER = ("import fcntl, os, sys, time\n"
          "f = open(os.path.join(sys.argv[1], '.lock'), 'a+')\n"
          "fcntl.flock(f, fcntl.LOCK_EX)\n"
          "f.seek(0); f.truncate(); f.write(f'pid {os.getpid()} on testhost'); f.flush()\n"
          "print('held', flush=True)\n"
          "time.sleep(600)\n")


def _hold(directory: Path) -> subprocess.Popen:
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(directory)], stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "held"
    return holder


def test_a_second_process_on_the_same_sweep_is_refused_and_a_killed_ones_resume_takes_over(tiny_sweep, tmp_path):
    """Before the lock, a second --resume (or --overwrite) of a sweep that was still running appended its own chunks
    to the first one's metrics and checkpoints. Now it stops with a one-line error naming the holder, before it
    writes or deletes anything; once the holder dies (even by SIGKILL: the kernel drops an flock) the same command
    takes the directory over."""
    out = tmp_path / "sweep"
    shutil.copytree(tiny_sweep, out)
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file() and p.name != ".lock"}
    holder = _hold(out)
    try:
        for flag in ("resume", "overwrite"):
            with pytest.raises(FileExistsError, match=rf"{out} is being written by pid {holder.pid} on testhost: "
                                                      "wait for it to end, or choose another --out"):
                sweep.run_sweep(sweep.SweepArgs(out=out, **{flag: True}, **SMALL))
            assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file() and p.name != ".lock"} == before
    finally:
        holder.kill()
        holder.wait()
    sweep.run_sweep(sweep.SweepArgs(out=out, resume=True, **SMALL))  # the holder is gone: resumes (nothing left)
    assert (out / "metrics.jsonl").read_bytes() == before["metrics.jsonl"]
    holder = _hold(out)  # and this process let go of it at the end of its run
    holder.kill()
    holder.wait()


def test_a_second_pretraining_on_the_same_resume_state_is_refused(tmp_path, monkeypatch):
    monkeypatch.setenv("PROTO_BRAX_RUNS", str(tmp_path / "runs"))
    data = tmp_path / "d.npz"
    point = _random_data(obs=4)  # the point task's sizes
    ds.save_npz(data, point, {"env": "point"})
    args = pretrain.PretrainArgs(dataset=str(data), out=tmp_path / "bundle", resume=True, steps=100, log_every=100,
                                 hidden=(8,), batch_size=8, eval_episodes=1)
    from proto_brax.experiment.pretrain import partial_dir

    partial = partial_dir(args, ds.content_hash(point))
    partial.mkdir(parents=True)
    holder = _hold(partial)
    try:
        with pytest.raises(FileExistsError, match=f"being written by pid {holder.pid} on testhost: wait for it to "
                                                  "end, or run without --resume"):
            pretrain.pretrain(args)
        assert not (tmp_path / "bundle").exists()
    finally:
        holder.kill()
        holder.wait()
    pretrain.pretrain(args)  # the holder is gone
    assert (tmp_path / "bundle" / "metadata.json").exists() and not partial.exists()
