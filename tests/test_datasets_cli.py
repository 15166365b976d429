"""Dataset generation from committed behaviour snapshots: determinism, kinds, cache, errors (on the point task)."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from proto_brax import envs
from proto_brax.cli import datasets as datasets_cli
from proto_brax.data import cache as datasets
from proto_brax.data import generate as g
from proto_brax.data.dataset import CorruptDatasetError, content_hash, episode_returns, load_npz
from proto_brax.experiment.plan import load_dataset

SMALL = dict(size=2000, num_envs=20, progress=False)


@pytest.fixture(scope="module")
def medium():
    return datasets.make_dataset("point-medium", seed=0, **SMALL)


def test_same_name_size_seed_gives_identical_arrays(medium):
    again = datasets.make_dataset("point-medium", seed=0, **SMALL)
    assert content_hash(medium[0]) == content_hash(again[0])
    other = datasets.make_dataset("point-medium", seed=1, **SMALL)
    assert content_hash(medium[0]) != content_hash(other[0])


def test_medium_uses_the_snapshot_closest_to_a_third_of_the_normalized_range(medium):
    from proto_brax import envs

    spec = envs.get_spec("point")
    snaps = g.list_snapshots("point")
    expert, med = g.pick_expert_medium(snaps, datasets.reference_returns(spec))
    assert expert.step == max(s.step for s in snaps)
    target = spec.ref_random + (spec.ref_expert - spec.ref_random) / 3
    assert abs(med.eval_return - target) == min(abs(s.eval_return - target) for s in snaps[:-1])
    data, meta = medium
    assert meta["medium_snapshot"]["step"] == med.step and meta["behavior"][0]["step"] == med.step
    assert data.observations.shape == (2000, 4) and data.actions.shape == (2000, 2)
    assert np.all(np.abs(data.actions) <= 1.0)


def datasets_fields():
    from proto_brax.data.dataset import FIELDS

    return FIELDS


def test_synthetic_snapshot_choice():
    mk = lambda step, r: g.Snapshot(step, Path("."), r, {})  # noqa: E731
    snaps = [mk(0, 5.0), mk(1, 31.0), mk(2, 40.0), mk(3, 100.0), mk(4, 90.0)]
    expert, med = g.pick_expert_medium(snaps)
    assert expert.step == 4 and med.step == 1  # 90 / 3 = 30 -> 31
    # with reference returns (random 0, expert 120: the final snapshot's 90 underestimates it) the target is 40
    expert, med = g.pick_expert_medium(snaps, (0.0, 120.0))
    assert expert.step == 4 and med.step == 2
    expert, med = g.pick_expert_medium(snaps, (-60.0, 120.0))  # -60 + 180 / 3 = 0 -> the 5.0 snapshot
    assert med.step == 0
    # measured behaviour (stochastic-policy) returns take precedence over the evaluations, once all are measured
    beh = lambda step, r, b: g.Snapshot(step, Path("."), r, {"behavior_return": {"mean": b}})  # noqa: E731
    snaps = [beh(0, 5.0, 1.0), beh(1, 31.0, 20.0), beh(2, 40.0, 25.0), beh(3, 60.0, 41.0), beh(4, 90.0, 80.0)]
    assert g.pick_expert_medium(snaps, (0.0, 120.0))[1].step == 3  # target 40: behaviour 41, not eval 40
    snaps[2] = mk(2, 40.0)  # one unmeasured snapshot: evaluations for all
    assert g.pick_expert_medium(snaps, (0.0, 120.0))[1].step == 2


def test_measure_records_behavior_returns_and_picks_medium_by_them(tmp_path, capsys):
    import shutil

    root = tmp_path / "behavior"
    shutil.copytree(Path(__file__).resolve().parents[1] / "checkpoints" / "behavior" / "point", root / "point")
    out = datasets_cli.cmd_measure(datasets_cli.Measure("point", episodes=8, behavior_root=root))
    snaps = g.list_snapshots("point", root)
    assert [r["step"] for r in out] == [s.step for s in snaps]
    assert all(s.metadata["behavior_return"]["episodes"] == 8 for s in snaps)
    assert out[-1]["mean"] > out[0]["mean"] + 10  # the final snapshot's samples score far above the first one's
    _, med = g.pick_expert_medium(snaps, (0.34, 49.0))
    target = 0.34 + (49.0 - 0.34) / 3
    assert abs(med.metadata["behavior_return"]["mean"] - target) == min(
        abs(s.metadata["behavior_return"]["mean"] - target) for s in snaps[:-1])
    assert f"medium is now the snapshot at step {med.step}" in capsys.readouterr().out


def test_a_cached_dataset_from_other_snapshots_is_stale(tmp_path, medium, capsys):
    from proto_brax.data.dataset import save_npz

    data, meta = medium
    assert datasets.stale_reason(meta) is None
    old = {**meta, "medium_snapshot": {**meta["medium_snapshot"], "step": meta["medium_snapshot"]["step"] + 1}}
    save_npz(datasets.dataset_path("point-medium", 2000, 0, tmp_path), data, old)
    with pytest.raises(CorruptDatasetError, match=r"stale: .*medium snapshot at step .*make point-medium --size 2000 "
                                                  r"--force"):
        datasets.load_dataset("point-medium", 2000, 0, tmp_path)
    save_npz(datasets.dataset_path("point-medium", None, 0, tmp_path), data, old)  # the default size, for `list`
    datasets_cli.cmd_list(datasets_cli.List(cache_dir=tmp_path))
    assert "stale (it was generated from the medium snapshot" in capsys.readouterr().out


def test_kinds_are_ordered_and_sized():
    mr, meta = datasets.make_dataset("point-medium-replay", **SMALL)
    steps = [b["step"] for b in meta["behavior"]]
    assert steps[0] == 0 and steps == sorted(steps) and steps[-1] == meta["medium_snapshot"]["step"]
    assert sum(b["transitions"] for b in meta["behavior"]) == 2000 == mr.rewards.shape[0]
    me, meta = datasets.make_dataset("point-medium-expert", **SMALL)
    assert me.rewards.shape[0] == 4000 and [b["step"] for b in meta["behavior"]] == [
        meta["medium_snapshot"]["step"], meta["expert_snapshot"]["step"]]
    rnd, _ = datasets.make_dataset("point-random", **SMALL)
    ex, _ = datasets.make_dataset("point-expert", **SMALL)
    assert episode_returns(ex).mean() > episode_returns(rnd).mean() + 20  # the expert is clearly better
    md, _ = datasets.make_dataset("point-medium", **SMALL)
    for f in datasets_fields():  # medium-expert is exactly medium followed by expert (D4RL)
        np.testing.assert_array_equal(getattr(me, f), np.concatenate([getattr(md, f), getattr(ex, f)]))


def test_cloned_is_half_expert_half_a_bc_policy_trained_on_its_first_episodes():
    """D4RL's Adroit cloned recipe on point: the first half is the expert dataset at half the size (its first episodes
    are the BC demonstrations), the second half the BC policy's own rollouts; deterministic; staleness follows the
    expert snapshot."""
    kw = dict(size=2000, num_envs=20, progress=False, demos=5, bc_steps=500)
    cl, meta = datasets.make_cloned("point-cloned", **kw)
    ex, _ = datasets.make_dataset("point-expert", size=1000, num_envs=20, progress=False)
    for f in datasets_fields():
        np.testing.assert_array_equal(getattr(cl, f)[:1000], getattr(ex, f))
    bc = meta["behavior"][-1]
    demo = datasets.first_episodes(ex, 5)
    assert bc["demos"] == 5 and bc["demo_transitions"] == len(demo.rewards) == 250  # point episodes: 50 steps
    assert meta["kind"] == "cloned" and meta["size"] == 2000 == cl.rewards.shape[0] and bc["transitions"] == 1000
    assert meta["parts"]["expert"] == content_hash(ex) and "human demonstrations" in meta["note"]
    # the BC half is not a copy of the expert half, and the BC policy (500 steps) still reaches the origin
    assert not np.allclose(cl.actions[1000:], ex.actions)
    assert episode_returns(jax.tree.map(lambda x: x[1000:], cl)).mean() > 30
    again, _ = datasets.make_cloned("point-cloned", **kw)
    assert content_hash(again) == content_hash(cl)
    assert datasets.stale_reason(meta) is None
    assert "expert snapshot" in datasets.stale_reason({**meta, "expert_snapshot": {"step": 1}})
    with pytest.raises(ValueError, match="fewer than the 99"):
        datasets.first_episodes(ex, 99)
    assert "pen-cloned" in g.dataset_names() and g.default_size("pen") == 500_000


def test_noisy_policy_adds_gaussian_noise_clipped_to_the_box():
    base = lambda params, obs, key: jnp.full((obs.shape[0], 2), params)  # noqa: E731  (a constant action)
    noisy = g.noisy_policy(base, 0.2)
    a = np.asarray(noisy(0.0, jnp.zeros((20_000, 3)), jax.random.PRNGKey(0)))
    assert abs(a.mean()) < 0.01 and abs(a.std() - 0.2) < 0.01  # N(0, 0.2²) around the action
    edge = np.asarray(noisy(0.95, jnp.zeros((20_000, 3)), jax.random.PRNGKey(1)))
    assert edge.max() == 1.0 and np.mean(edge == 1.0) == pytest.approx(0.4013, abs=0.02)  # P(N > 0.05 / 0.2)


def test_human_is_25_noisy_expert_episodes():
    """Issue 36's human-sized data: D4RL's 25 demonstrations, one env each for one episode length (point: 50 steps),
    from the expert snapshot with N(0, 0.2²) action noise; deterministic."""
    data, meta = datasets.make_dataset("point-human", progress=False)
    assert meta["kind"] == "human" and meta["num_envs"] == 25 and meta["size"] == 25 * 50 == data.rewards.shape[0]
    (info,) = meta["behavior"]
    assert info["action_noise"] == 0.2 and info["step"] == meta["expert_snapshot"]["step"]
    assert "stands in" in meta["note"] and "pen-human" in g.dataset_names()
    assert g.default_size("pen", "human") == 25 * 100 and g.default_size("door", "human") == 25 * 200
    assert datasets.dataset_path("point-human").name == "point-human.npz"
    again, _ = datasets.make_dataset("point-human", progress=False)
    assert content_hash(again) == content_hash(data)
    assert datasets.stale_reason(meta) is None
    assert "expert snapshot" in datasets.stale_reason({**meta, "expert_snapshot": {"step": 1}})


def test_episodes_are_contiguous_and_bounded(medium):
    data, _ = medium
    ends = np.flatnonzero((data.terminals + data.timeouts) > 0)
    # every env's block of 100 transitions ends an episode; no successor crosses an episode end
    assert set(range(99, 2000, 100)) <= set(ends.tolist())
    inner = np.setdiff1d(np.arange(1999), ends)
    np.testing.assert_allclose(data.next_observations[inner], data.observations[inner + 1], atol=1e-6)


def test_generation_pins_one_xla_thread_whatever_the_caller_set():
    flags = datasets.generation_xla_flags("--xla_cpu_multi_thread_eigen=true --xla_foo=1 "
                                          "intra_op_parallelism_threads=8")
    assert flags == "--xla_foo=1 --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
    mjx = datasets.generation_xla_flags("", mjx=True)
    assert mjx.endswith("intra_op_parallelism_threads=1 --xla_cpu_enable_concurrency_optimized_scheduler=false")
    assert datasets.generation_xla_flags(flags) == flags  # idempotent


def test_host_cpu_names_the_model_and_the_widest_vector_isa(monkeypatch):
    import platform

    monkeypatch.setattr(platform, "machine", lambda: "x86_64")
    zen4 = "processor\t: 0\nmodel name\t: AMD EPYC\nflags\t\t: fpu sse4_2 avx avx2 fma avx512f avx512bw\n\n" \
           "processor\t: 1\nmodel name\t: other\nflags\t\t: fpu\n"  # the first core's block is read
    assert envs.host_cpu(zen4) == "AMD EPYC, x86_64 avx512f"
    assert envs.host_cpu("model name\t: AMD EPYC\nflags\t\t: sse4_2 avx fma avx2\n") == "AMD EPYC, x86_64 avx2"
    monkeypatch.setattr(platform, "machine", lambda: "aarch64")
    monkeypatch.setattr(platform, "processor", lambda: "")
    assert envs.host_cpu("processor\t: 0\nFeatures\t: fp asimd sve\n") == "aarch64 sve"
    assert envs.host_cpu("") == "aarch64"


def test_cli_make_info_list_and_corruption(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=true")
    args = ["--size", "2000", "--num-envs", "20", "--cache-dir", str(tmp_path)]
    datasets_cli.main(["make", "point-random", *args])
    path = datasets.dataset_path("point-random", 2000, 0, tmp_path)
    assert path.exists() and not list(tmp_path.glob(".*tmp"))
    _, meta = load_npz(path)
    assert meta["xla_flags"] == "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"  # as generated
    assert meta["cpu"] == envs.host_cpu()  # and on which CPU
    datasets_cli.main(["info", "point-random", "--size", "2000", "--cache-dir", str(tmp_path)])
    out = capsys.readouterr().out
    assert "episodes" in out and "return mean" in out
    datasets_cli.main(["list", "--cache-dir", str(tmp_path)])
    assert "hopper-medium-replay" in capsys.readouterr().out
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    path.write_bytes(bytes(raw))
    with pytest.raises(CorruptDatasetError, match="make point-random --size 2000 --force"):
        datasets.load_dataset("point-random", 2000, 0, tmp_path)


def test_unknown_and_missing_datasets_name_the_fix(tmp_path):
    with pytest.raises(ValueError, match="valid names are .*hopper-medium"):
        datasets.make_dataset("hopper-mediun")
    with pytest.raises(FileNotFoundError, match="python -m proto_brax.datasets make point-expert"):
        datasets.load_dataset("point-expert", None, 0, tmp_path)
    with pytest.raises(FileNotFoundError, match="proto_brax.data.behavior --env hopper"):
        g.list_snapshots("hopper", tmp_path)


def test_gymnasium_v5_datasets_are_registered_with_the_locomotion_kinds(tmp_path):
    """hopper-v5-medium etc. (issue 34): the Brax kinds on the MJX ports; without a behaviour policy, make names the
    command that trains one (before any rollout)."""
    names = set(g.dataset_names())
    for env in ("hopper-v5", "walker2d-v5", "halfcheetah-v5", "ant-v5"):
        assert {f"{env}-{kind}" for kind in g.KINDS} <= names
    assert g.parse_name("halfcheetah-v5-medium-replay") == ("halfcheetah-v5", "medium-replay")
    assert g.parse_name("hopper-medium") == ("hopper", "medium")  # the Brax names parse as before
    with pytest.raises(FileNotFoundError, match="proto_brax.data.behavior --env hopper-v5"):
        datasets.make_dataset("hopper-v5-medium", 1000, num_envs=10, behavior_root=tmp_path, progress=False)


def test_sweep_rebuilds_a_missing_or_stale_dataset(tmp_path, monkeypatch, capsys, medium):
    from proto_brax.data.dataset import save_npz

    monkeypatch.setenv(datasets.ENV_VAR, str(tmp_path))
    data, meta = medium
    old = {**meta, "medium_snapshot": {**meta["medium_snapshot"], "step": meta["medium_snapshot"]["step"] + 1}}
    save_npz(datasets.dataset_path("point-medium", 2000), data, old)
    rebuilt, new_meta = load_dataset("point-medium", 2000)
    assert "is stale (it was generated from the medium snapshot" in capsys.readouterr().out
    assert datasets.stale_reason(new_meta) is None and datasets.stale_reason(datasets.cached_metadata(
        datasets.dataset_path("point-medium", 2000))) is None
    assert rebuilt.rewards.shape == (2000,)


def test_staleness_follows_the_snapshots_a_kind_is_made_from(medium):
    _, meta = medium
    moved = {**meta, "medium_snapshot": {**meta["medium_snapshot"], "step": -1}}
    assert datasets.stale_reason({**moved, "kind": "expert"}) is None  # expert data do not depend on medium
    for kind in ("medium", "medium-replay", "medium-expert"):
        assert "medium snapshot at step -1" in datasets.stale_reason({**moved, "kind": kind})
    moved = {**meta, "expert_snapshot": {**meta["expert_snapshot"], "step": -1}}
    assert datasets.stale_reason({**moved, "kind": "medium"}) is None
    assert "expert snapshot" in datasets.stale_reason({**moved, "kind": "expert"})


def test_checkpoint_index_names_expert_and_medium_of_each_env():
    from proto_brax import envs
    from proto_brax.cli.checkpoints import index_markdown

    text = index_markdown(Path(__file__).resolve().parents[1] / "checkpoints")
    for env in ("hopper", "walker2d", "halfcheetah", "ant"):
        snaps = g.list_snapshots(env)
        _, med = g.pick_expert_medium(snaps, datasets.reference_returns(envs.get_spec(env)))
        assert f"| {env} | {len(snaps)} | {snaps[-1].step} | " in text and f" | {med.step} | " in text
    assert "| point | 6 | 3000 | 48.0 / not measured | 500 |" in text


def test_antmaze_data_go_stale_when_the_controller_moves_on():
    last = g.list_snapshots("point")[-1].step  # any env's snapshots stand in for ant-goal's
    meta = {"kind": "diverse", "controller": {"env": "point", "step": last}}
    assert datasets.stale_reason(meta) is None
    why = datasets.stale_reason({**meta, "controller": {"env": "point", "step": last - 500}})
    assert f"controller at step {last - 500}, the last snapshot is step {last}" in why
