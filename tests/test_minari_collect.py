"""Minari datasets recorded on Gymnasium's own v5 envs with minari's DataCollector (data.minari_collect): the rows
are Gymnasium's dynamics under our behaviour policy, read back by the suite's reader with the recorded hash,
reproducible from the seed, and never written over."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from proto_brax import envs
from proto_brax.data import generate as g
from proto_brax.data import minari_collect as mc
from proto_brax.data.dataset import CorruptDatasetError, load_minari
from proto_brax.envs.gym_v5 import NativeGymV5, gymnasium_env

minari = pytest.importorskip("minari")


def _episodes(data):
    ends = np.flatnonzero((data.terminals > 0) | (data.timeouts > 0))
    return np.split(np.arange(len(data.rewards)), ends[:-1] + 1)


def test_random_collection_is_gymnasiums_hopper_step_for_step(tmp_path):
    path = mc.collect("hopper-v5", "local/hopper-v5/random-v0", 400, "random", seed=3, root=tmp_path)
    data, meta = load_minari(path)
    spec = envs.get_spec("hopper-v5")
    assert len(data.rewards) == 400 and meta["env"] == "hopper-v5" and meta["env_id"] == "Hopper-v5"
    assert (meta["ref_min_score"], meta["ref_max_score"]) == (spec.ref_random, spec.ref_expert)
    assert meta["proto_brax"]["generation"]["policy"] == "random" and meta["proto_brax"]["source"] == "collect"
    episodes = _episodes(data)
    assert len(episodes) > 3  # a random hopper falls within ~20-50 steps: terminations split the rows
    assert data.timeouts[-1] == 1 and data.terminals[:-1][data.timeouts[:-1] > 0].sum() == 0
    # Replay every episode on a fresh native env reset with the collector's seeds: same rows, same flags.
    rng, env = np.random.default_rng(3), gymnasium_env("hopper")
    for rows in episodes:
        obs, _ = env.reset(seed=int(rng.integers(2**31 - 1)))
        np.testing.assert_array_equal(data.observations[rows[0]], np.float32(obs))
        for i in rows:
            obs, reward, terminated, _, _ = env.step(data.actions[i])  # float32, as the collector passed it
            np.testing.assert_array_equal(data.next_observations[i], np.float32(obs))
            assert data.rewards[i] == np.float32(reward) and data.terminals[i] == float(terminated)
    assert np.all(np.abs(data.actions) <= 1.0)


def test_collect_reads_its_rows_back_once_and_the_summary_checks_them(tmp_path, monkeypatch):
    """``datasets collect`` read a new dataset three times (hash, re-check, summary); now collect reads it once (the
    hash) and the summary's read is the first check against that hash."""
    from proto_brax.data import dataset as ds

    calls = []

    def counted(*a, **k):
        calls.append(a)
        return load_minari(*a, **k)

    monkeypatch.setattr(ds, "load_minari", counted)
    path = mc.collect("hopper-v5", "local/hopper-v5/random-v0", 60, "random", seed=1, root=tmp_path)
    assert len(calls) == 1
    s = mc.summary(path)
    assert len(calls) == 2 and s["transitions"] == 60 and s["content_hash"] == load_minari(path)[1]["content_hash"]


def test_same_seed_same_rows_and_nothing_is_overwritten(tmp_path):
    a = mc.collect("hopper-v5", "local/hopper-v5/random-v0", 120, "random", seed=1, root=tmp_path / "a")
    b = mc.collect("hopper-v5", "local/hopper-v5/random-v0", 120, "random", seed=1, root=tmp_path / "b")
    c = mc.collect("hopper-v5", "local/hopper-v5/random-v0", 120, "random", seed=2, root=tmp_path / "c")
    ha, hb, hc = (load_minari(p)[1]["content_hash"] for p in (a, b, c))
    assert ha == hb != hc
    before = sorted(p.stat().st_mtime_ns for p in a.rglob("*") if p.is_file())
    with pytest.raises(FileExistsError, match="never replaces"):
        mc.collect("hopper-v5", "local/hopper-v5/random-v0", 120, "random", seed=1, root=tmp_path / "a")
    assert sorted(p.stat().st_mtime_ns for p in a.rglob("*") if p.is_file()) == before
    for bad, match in ((dict(env="hopper"), "Gymnasium's own v5"), (dict(dataset_id="no version"), "Minari dataset id"),
                       (dict(steps=0), "--steps")):
        kw = dict(env="hopper-v5", dataset_id="local/x-v0", steps=10, policy="random", root=tmp_path / "d") | bad
        with pytest.raises(ValueError, match=match):
            mc.collect(**kw)
    assert not (tmp_path / "d").exists()


def test_a_modified_collection_fails_its_hash(tmp_path):
    import h5py

    path = mc.collect("hopper-v5", "local/hopper-v5/random-v0", 50, "random", root=tmp_path)
    with h5py.File(path / "data" / "main_data.hdf5", "r+") as f:
        f["episode_0/rewards"][0] += 1.0
    with pytest.raises(CorruptDatasetError, match="content hash"):
        load_minari(path)


def test_snapshot_policy_samples_the_snapshots_tanh_gaussian(tmp_path):
    """A behaviour snapshot (a tiny native SAC run) drives the collection: each action is the snapshot actor's
    tanh-Gaussian sample under the key folded with the step, as in :func:`generate.stochastic_policy`."""
    from proto_brax.data import native_behavior as nb

    nb.train(nb.Args(env="hopper-v5", steps=100, snapshot_every=100, eval_episodes=1, learning_starts=50,
                     buffer_capacity=200, batch_size=16, hidden=(8, 8), out=tmp_path / "behavior",
                     resume_dir=tmp_path / "resume"))
    with pytest.raises(ValueError, match="no snapshot of hopper-v5 at that step; the steps are 100"):
        mc.collect("hopper-v5", "local/h-v0", 30, "200", root=tmp_path / "m", behavior_root=tmp_path / "behavior")
    path = mc.collect("hopper-v5", "local/hopper-v5/expert-v0", 30, "expert", seed=5, root=tmp_path / "m",
                      behavior_root=tmp_path / "behavior")
    data, meta = load_minari(path)
    gen = meta["proto_brax"]["generation"]
    assert gen["snapshot_step"] == 100 and gen["sampling"].startswith("stochastic")
    snap = g.list_snapshots("hopper-v5", tmp_path / "behavior")[-1]
    nets, params = g.load_snapshot_actor(snap, NativeGymV5("hopper-v5"))
    key = jax.random.PRNGKey(5)
    expected = np.stack([np.asarray(g.stochastic_policy(nets)(params, data.observations[t][None],
                                                              jax.random.fold_in(key, t))[0]) for t in range(30)])
    np.testing.assert_allclose(data.actions, expected, rtol=1e-6, atol=1e-6)
    assert np.std(data.actions) > 0.05  # samples, not one repeated action


def test_v5_datasets_are_recorded_on_gymnasiums_own_env(tmp_path):
    """``make hopper-v5-random`` (and every v5 kind) rolls out on Gymnasium's Hopper-v5 (generate.native_rollouts):
    env-major rows that replay step for step on a fresh native env reset with the recorded key, the time limit and
    the cut at the end of each env's rows as timeouts, and the same rows from the same seed."""
    from proto_brax.data.cache import make_dataset

    data, meta = make_dataset("hopper-v5-random", size=240, seed=2, num_envs=4, progress=False)
    assert meta["backend"] == "native" and meta["size"] == 240 and len(data.rewards) == 240
    again, _ = make_dataset("hopper-v5-random", size=240, seed=2, num_envs=4, progress=False)
    np.testing.assert_array_equal(again.observations, data.observations)
    per_env = 60
    for j in range(4):
        rows = slice(j * per_env, (j + 1) * per_env)
        assert data.terminals[rows][-1] + data.timeouts[rows][-1] == 1  # no episode runs into the next env's rows
    # env 0's episodes, replayed: reset keys fold (0, env, episode) into the part's key (fold_in(dataset key, 0))
    key = jax.random.fold_in(g.dataset_key(2, "random"), 0)
    sim, k = NativeGymV5("hopper-v5"), 0
    obs = sim.reset(jax.random.fold_in(jax.random.fold_in(jax.random.fold_in(key, 0), 0), 0))
    for i in range(per_env):
        np.testing.assert_array_equal(data.observations[i], obs)
        obs, reward, terminal, _ = sim.step(data.actions[i])
        np.testing.assert_array_equal(data.next_observations[i], obs)
        assert data.rewards[i] == np.float32(reward) and data.terminals[i] == float(terminal)
        if terminal:
            k += 1
            obs = sim.reset(jax.random.fold_in(jax.random.fold_in(jax.random.fold_in(key, 0), 0), k))
    assert k >= 1  # a random hopper falls within 60 steps: the replay crossed a reset
