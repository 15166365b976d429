"""Minari export (proto_brax.data.minari_io, minari's own writer) and import (load_minari, minari's own reader):
bit-for-bit round trips, episode ends, refusal to overwrite, bad ids."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

minari = pytest.importorskip("minari")  # the `test` extra

from proto_brax import envs  # noqa: E402
from proto_brax.cli import datasets as datasets_cli  # noqa: E402
from proto_brax.data import cache as datasets  # noqa: E402
from proto_brax.data import minari_io  # noqa: E402
from proto_brax.data.dataset import (  # noqa: E402
    CorruptDatasetError,
    Transition,
    content_hash,
    load_minari,
    save_npz,
)

SIZE = 2000


@pytest.fixture(scope="module")
def point_medium():
    """A small generated point-medium dataset (terminals and timeouts both occur) and its metadata."""
    data, meta = datasets.make_dataset("point-medium", size=SIZE, num_envs=20, progress=False)
    assert data.terminals.sum() > 0 and data.timeouts.sum() > 0
    return data, meta


def _rows(minari_ds, field: str) -> np.ndarray:
    return np.concatenate([np.asarray(getattr(ep, field)) for ep in minari_ds.iterate_episodes()])


def test_round_trip_through_minaris_reader_and_ours(point_medium, tmp_path, monkeypatch):
    data, meta = point_medium
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    path = minari_io.export_minari(data, meta, "proto_brax/point/medium-v0", source="point-medium")
    assert path == tmp_path / "proto_brax" / "point" / "medium-v0"

    # minari's own reader
    ds = minari.load_dataset("proto_brax/point/medium-v0")
    bounds = minari_io.episode_bounds(data)
    assert ds.total_episodes == len(bounds) and ds.total_steps == SIZE
    for ep, (start, stop) in zip(ds.iterate_episodes(), bounds):
        assert len(ep) == stop - start and ep.observations.shape == (stop - start + 1, 4)
        np.testing.assert_array_equal(ep.observations[:-1], data.observations[start:stop])
        np.testing.assert_array_equal(ep.observations[-1], data.next_observations[stop - 1])  # the final successor
        assert bool(ep.terminations[-1] or ep.truncations[-1])  # generated episodes always end on a flag
        np.testing.assert_array_equal(ep.infos["dataset_row"], [*range(start, stop), -1])
    np.testing.assert_array_equal(_rows(ds, "rewards"), data.rewards)
    np.testing.assert_array_equal(_rows(ds, "actions"), data.actions)
    np.testing.assert_array_equal(_rows(ds, "terminations"), data.terminals > 0)
    np.testing.assert_array_equal(_rows(ds, "truncations"), data.timeouts > 0)
    spec = envs.get_spec("point")
    raw = ds.storage.metadata
    assert ds.env_spec is None and raw["proto_brax"]["env"] == "point"
    assert (raw["ref_min_score"], raw["ref_max_score"]) == (spec.ref_random, spec.ref_expert)
    np.testing.assert_allclose(minari.get_normalized_score(ds, np.array([spec.ref_random, spec.ref_expert])), [0, 1])
    assert raw["proto_brax"]["content_hash"] == content_hash(data)
    assert raw["proto_brax"]["generation"] == json.loads(json.dumps(meta))

    # back through the suite's loaders: the very rows (same content hash), by id, by directory, and as --dataset
    expected = content_hash(data)
    back, bmeta = load_minari("proto_brax/point/medium-v0")
    assert content_hash(back) == bmeta["content_hash"] == expected
    assert bmeta["env"] == "point" and bmeta["proto_brax"]["generation"]["kind"] == "medium"
    assert (bmeta["ref_min_score"], bmeta["ref_max_score"]) == (spec.ref_random, spec.ref_expert)
    assert content_hash(datasets.load_dataset(str(path))[0]) == expected
    from proto_brax.experiment.plan import load_dataset  # what `python -m proto_brax.sweep --dataset ID` reads

    assert content_hash(load_dataset("proto_brax/point/medium-v0")[0]) == expected


def _ep(obs, steps, *, start=0.0):
    """One stored trajectory of ``steps`` rows: observations (obs, obs + 1, …) as float32 [steps + 1, 2]."""
    return (np.arange(steps + 1, dtype=np.float32)[:, None] + start + np.float32(obs) * np.ones((1, 2), np.float32))


def _hand_dataset() -> tuple[Transition, list[tuple[int, int]]]:
    """Trajectories ending on: a terminal; a timeout; both flags; no flag but a discontinuity; a terminal the next row
    continues (AntMaze's goal inside a run); a -0.0 successor followed by a +0.0 observation (bitwise different);
    and the end of the data, unfinished. Returns the dataset and its expected episode ranges."""
    eps = [(_ep(0, 3), (1, 0)), (_ep(10, 4), (0, 1)), (_ep(20, 2), (1, 1)), (_ep(30, 2), (0, 0))]
    run = _ep(40, 4)  # rows 0-1 end on a terminal, rows 2-3 continue from the same observation
    obs, nxt, term, tout = [], [], [], []
    for o, (t, u) in eps:
        obs.append(o[:-1]), nxt.append(o[1:])
        term.append(np.r_[np.zeros(len(o) - 2), t]), tout.append(np.r_[np.zeros(len(o) - 2), u])
    obs.append(run[:-1]), nxt.append(run[1:])
    term.append(np.array([0, 1, 0, 0])), tout.append(np.zeros(4))
    signed = np.array([[5.0, 0.0], [6.0, 0.0]], np.float32)  # row: (5, 0) -> (6, -0.0); next row starts at (6, +0.0)
    obs.append(signed), nxt.append(np.array([[6.0, -0.0], [7.0, 0.0]], np.float32))
    term.append(np.zeros(2)), tout.append(np.zeros(2))
    obs_, nxt_ = np.concatenate(obs), np.concatenate(nxt)
    n = len(obs_)
    rng = np.random.default_rng(0)
    data = Transition(observations=obs_, actions=rng.uniform(-1, 1, (n, 1)).astype(np.float32),
                      rewards=rng.normal(size=n).astype(np.float32), next_observations=nxt_,
                      terminals=np.concatenate(term).astype(np.float32),
                      timeouts=np.concatenate(tout).astype(np.float32))
    # 3 + 4 + 2 + 2 rows, then the run split at its terminal (2 + 2), then the signed-zero pair split (1 + 1)
    return data, [(0, 3), (3, 7), (7, 9), (9, 11), (11, 13), (13, 15), (15, 16), (16, 17)]


def test_episodes_end_on_terminals_timeouts_and_cuts_and_round_trip_bitwise(tmp_path, monkeypatch):
    data, expected_bounds = _hand_dataset()
    assert minari_io.episode_bounds(data) == expected_bounds
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    minari_io.export_minari(data, {"note": "hand-made"}, "toy/hand-v1", env="point")
    ds = minari.load_dataset("toy/hand-v1")
    last = [(bool(ep.terminations[-1]), bool(ep.truncations[-1])) for ep in ds.iterate_episodes()]
    # terminal, timeout, both, cut (no flag), run's terminal, run's rest (no flag), signed zero (no flag), last row
    assert last == [(True, False), (False, True), (True, True), (False, False), (True, False), (False, False),
                    (False, False), (False, False)]
    timeout_ep = next(ep for i, ep in enumerate(ds.iterate_episodes()) if i == 1)
    np.testing.assert_array_equal(timeout_ep.observations[-1], data.next_observations[6])  # the timeout's successor
    back, meta = load_minari("toy/hand-v1")
    assert content_hash(back) == content_hash(data)
    assert np.signbit(np.asarray(back.next_observations)[15, 1])  # -0.0 survives
    assert meta["proto_brax"]["generation"] == {"note": "hand-made"}


def test_refuses_to_overwrite_and_replaces_only_its_own_exports(point_medium, tmp_path):
    data, meta = point_medium
    root = tmp_path / "minari"
    path = minari_io.export_minari(data, meta, "proto_brax/point/medium-v0", root=root)
    with pytest.raises(FileExistsError, match="pass --force"):
        minari_io.export_minari(data, meta, "proto_brax/point/medium-v0", root=root)
    # --force replaces our own export (another dataset: its rows read back)
    other, _ = _hand_dataset()
    minari_io.export_minari(other, {}, "proto_brax/point/medium-v0", root=root, force=True)
    assert content_hash(load_minari(path)[0]) == content_hash(other)
    assert sorted(p.name for p in path.parent.iterdir()) == ["medium-v0", "namespace_metadata.json"]  # old copy gone

    # a user's file inside our export, or a dataset someone else wrote: refused even with --force, left untouched
    (path / "data" / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="even with --force"):
        minari_io.export_minari(data, meta, "proto_brax/point/medium-v0", root=root, force=True)
    assert (path / "data" / "notes.txt").read_text() == "mine"
    theirs = minari_io.export_minari(data, meta, "user/walk-v0", root=root)
    metadata_file = theirs / "data" / "metadata.json"
    raw = json.loads(metadata_file.read_text())
    del raw["proto_brax"]
    metadata_file.write_text(json.dumps(raw))
    with pytest.raises(FileExistsError, match="not written by"):
        minari_io.export_minari(data, meta, "user/walk-v0", root=root, force=True)
    assert json.loads(metadata_file.read_text()) == raw


def test_a_modified_export_is_refused_naming_the_export_command(point_medium, tmp_path, monkeypatch):
    data, meta = point_medium
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    path = minari_io.export_minari(data, meta, "proto_brax/point/medium-v0", command="EXPORT-AGAIN")
    with h5py.File(path / "data" / "main_data.hdf5", "a") as f:
        f["episode_0/rewards"][0] += 1.0
    with pytest.raises(CorruptDatasetError, match="EXPORT-AGAIN"):
        load_minari("proto_brax/point/medium-v0")
    with pytest.raises(CorruptDatasetError):  # --dataset ID says so too (not "not available locally")
        datasets.load_dataset("proto_brax/point/medium-v0")


@pytest.mark.parametrize("bad", ["hopper medium", "proto_brax/hopper/medium", "../escape-v0", "a//b-v0", "a/b-v0", ""])
def test_a_bad_id_is_one_line_naming_the_fix(bad):
    with pytest.raises(ValueError, match="pass another --id") as e:
        minari_io.check_id(bad)
    assert "\n" not in str(e.value)


def test_cli_export_a_cached_dataset(point_medium, tmp_path, capsys, monkeypatch):
    data, meta = point_medium
    monkeypatch.setenv("XLA_FLAGS", "")  # main() pins the generation numerics in os.environ; restored afterwards
    cache, out = tmp_path / "cache", tmp_path / "minari"
    save_npz(datasets.dataset_path("point-medium", SIZE, 0, cache), data, meta)
    args = ["export", "point-medium", "--minari", "--size", str(SIZE), "--cache-dir", str(cache), "--out", str(out)]
    datasets_cli.main(args)
    path = out / "proto_brax" / "point" / f"medium-n{SIZE}-seed0-v0"
    assert f"read back bit-for-bit (content hash {content_hash(data)})" in capsys.readouterr().out
    assert content_hash(datasets.load_dataset(str(path))[0]) == content_hash(data)
    assert json.loads((path / "data" / "metadata.json").read_text())["proto_brax"]["export_command"].endswith(
        "--force")

    with pytest.raises(SystemExit) as e:  # again: refused, one line naming --force
        datasets_cli.main(args)
    assert e.value.code == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("error: Minari dataset") and "--force" in err[0]
    datasets_cli.main([*args, "--force"])
    assert "read back bit-for-bit" in capsys.readouterr().out

    for extra, fix in ((["--id", "not an id"], "pass another --id"), ([], None)):
        argv = [a for a in args if a != "--minari"] if fix is None else [*args, *extra]
        with pytest.raises(SystemExit):
            datasets_cli.main(argv)
        assert (fix or "pass --minari") in capsys.readouterr().err.splitlines()[0]
