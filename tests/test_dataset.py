"""Tests of proto_brax.data.dataset: the .npz format, the D4RL-HDF5 and Minari readers, checks and statistics.

All host-side numpy: nothing here compiles JAX code.
"""

from __future__ import annotations

import os
import zipfile

import gymnasium as gym
import h5py
import numpy as np
import pytest

from proto_brax.data.dataset import (
    FIELDS,
    CorruptDatasetError,
    Transition,
    content_hash,
    dataset_size,
    episode_return_stats,
    episode_returns,
    load_d4rl_hdf5,
    load_minari,
    load_npz,
    return_range_scale,
    save_npz,
    transform_rewards,
    validate_for_env,
    with_returns_to_go,
)

HINT = "python -m proto_brax.datasets make hopper-medium"


def _random_dataset(n: int = 50, obs: int = 5, act: int = 3, seed: int = 0) -> Transition:
    rng = np.random.default_rng(seed)
    terminals = np.zeros(n, np.float32)
    terminals[n // 3] = 1.0
    timeouts = np.zeros(n, np.float32)
    timeouts[2 * n // 3] = 1.0
    return Transition(
        observations=rng.standard_normal((n, obs)).astype(np.float32),
        actions=rng.uniform(-1, 1, (n, act)).astype(np.float32),
        rewards=rng.standard_normal(n).astype(np.float32),
        next_observations=rng.standard_normal((n, obs)).astype(np.float32),
        terminals=terminals,
        timeouts=timeouts,
    )


def _assert_bit_exact(a: Transition, b: Transition) -> None:
    for name in FIELDS:
        x, y = np.asarray(getattr(a, name)), np.asarray(getattr(b, name))
        assert x.dtype == y.dtype == np.float32, name
        assert x.shape == y.shape, name
        assert x.tobytes() == y.tobytes(), name


# ------------------------------------------------------------------------------------------------------------------
# .npz format
# ------------------------------------------------------------------------------------------------------------------


def test_npz_round_trip_is_bit_exact_with_metadata(tmp_path):
    ds = _random_dataset()
    meta = {"env": "hopper", "quality": "medium", "seed": 3, "scores": [1.5, -2.0], "nested": {"a": None}}
    path = tmp_path / "hopper-medium.npz"
    save_npz(path, ds, meta)
    assert os.listdir(tmp_path) == ["hopper-medium.npz"]  # no suffix added, no temp file left

    loaded, loaded_meta = load_npz(path)
    _assert_bit_exact(ds, loaded)
    assert loaded_meta == {**meta, "format_version": 1, "content_hash": content_hash(ds)}
    assert meta == {"env": "hopper", "quality": "medium", "seed": 3, "scores": [1.5, -2.0], "nested": {"a": None}}
    assert dataset_size(loaded) == 50
    # the stored hash is also accepted as the expected one
    load_npz(path, expected_hash=content_hash(ds))


def test_npz_canonicalises_bool_flags_and_column_rewards(tmp_path):
    ds = _random_dataset(n=6)
    ds_bool = ds.replace(
        rewards=np.asarray(ds.rewards)[:, None],
        terminals=np.asarray(ds.terminals) > 0,
        timeouts=np.asarray(ds.timeouts) > 0,
    )
    assert content_hash(ds_bool) == content_hash(ds)
    save_npz(tmp_path / "d.npz", ds_bool, {})
    loaded, _ = load_npz(tmp_path / "d.npz")
    _assert_bit_exact(ds, loaded)


def test_content_hash_is_deterministic_and_sensitive():
    ds = _random_dataset()
    h = content_hash(ds)
    assert h == content_hash(_random_dataset()) and len(h) == 64
    for name in FIELDS:
        arr = np.array(getattr(ds, name), copy=True)
        flat = arr.reshape(-1)
        flat[7] = 1.0 - flat[7] if name in ("terminals", "timeouts") else np.nextafter(flat[7], np.float32(np.inf))
        assert content_hash(ds.replace(**{name: arr})) != h, name
    # swapping two same-shaped fields changes the hash (names are part of it)
    swapped = ds.replace(observations=ds.next_observations, next_observations=ds.observations)
    assert content_hash(swapped) != h


def _member_data_offset(path, member: str) -> int:
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo(member)
    with open(path, "rb") as f:
        f.seek(info.header_offset + 26)
        name_len, extra_len = np.frombuffer(f.read(4), "<u2")
    return info.header_offset + 30 + int(name_len) + int(extra_len)


@pytest.mark.parametrize("where", ["array-data", "metadata", "start", "truncated-half", "truncated-tail", "empty"])
def test_corrupted_file_raises_with_rebuild_hint(tmp_path, where):
    path = tmp_path / "hopper-medium.npz"
    save_npz(path, _random_dataset(), {"env": "hopper"})
    data = bytearray(path.read_bytes())
    if where == "array-data":
        off = _member_data_offset(path, "observations.npy") + 200
        data[off : off + 8] = b"\x00\x01\x02\x03\x04\x05\x06\x07"
    elif where == "metadata":
        off = _member_data_offset(path, "metadata.npy") + 140
        data[off : off + 4] = b"ZZZZ"
    elif where == "start":
        data[:16] = b"\xff" * 16
    elif where == "truncated-half":
        data = data[: len(data) // 2]
    elif where == "truncated-tail":
        data = data[:-10]
    else:
        data = bytearray()
    path.write_bytes(bytes(data))

    with pytest.raises(CorruptDatasetError) as e:
        load_npz(path, rebuild_hint=HINT)
    assert isinstance(e.value, ValueError)
    assert str(path) in str(e.value) and HINT in str(e.value)


def test_tampered_arrays_with_valid_zip_fail_the_hash_check(tmp_path):
    path = tmp_path / "d.npz"
    ds = _random_dataset()
    save_npz(path, ds, {})
    with np.load(path) as npz:
        entries = {k: npz[k] for k in npz.files}
    entries["rewards"] = entries["rewards"].copy()
    entries["rewards"][0] += 1.0
    with open(path, "wb") as f:
        np.savez(f, **entries)
    with pytest.raises(CorruptDatasetError, match="content hash") as e:
        load_npz(path, rebuild_hint=HINT)
    assert HINT in str(e.value)


def test_expected_hash_mismatch_raises(tmp_path):
    path = tmp_path / "d.npz"
    save_npz(path, _random_dataset(), {})
    with pytest.raises(CorruptDatasetError, match="expected") as e:
        load_npz(path, expected_hash="0" * 64)
    assert "rebuild" in str(e.value)


def test_missing_file_raises_file_not_found_with_hint(tmp_path):
    with pytest.raises(FileNotFoundError, match="proto_brax.datasets make"):
        load_npz(tmp_path / "nope.npz", rebuild_hint=HINT)


def _exploding_savez(file, *args, **kwds):
    file.write(b"PK\x03\x04 partial zip")
    raise RuntimeError("disk on fire")


def test_interrupted_write_leaves_no_file(tmp_path, monkeypatch):
    monkeypatch.setattr(np, "savez", _exploding_savez)
    path = tmp_path / "d.npz"
    with pytest.raises(RuntimeError, match="disk on fire"):
        save_npz(path, _random_dataset(), {"a": 1})
    assert not path.exists()
    assert os.listdir(tmp_path) == []  # the temp file is gone too


def test_interrupted_overwrite_keeps_the_previous_file(tmp_path, monkeypatch):
    path = tmp_path / "d.npz"
    old = _random_dataset(seed=1)
    save_npz(path, old, {"v": "old"})
    monkeypatch.setattr(np, "savez", _exploding_savez)
    with pytest.raises(RuntimeError):
        save_npz(path, _random_dataset(seed=2), {"v": "new"})
    monkeypatch.undo()
    loaded, meta = load_npz(path)
    _assert_bit_exact(old, loaded)
    assert meta["v"] == "old" and os.listdir(tmp_path) == ["d.npz"]


def test_unserialisable_metadata_writes_nothing(tmp_path):
    with pytest.raises(TypeError):
        save_npz(tmp_path / "d.npz", _random_dataset(), {"bad": object()})
    assert os.listdir(tmp_path) == []


# ------------------------------------------------------------------------------------------------------------------
# D4RL HDF5
# ------------------------------------------------------------------------------------------------------------------

# 7 steps: episode A = rows 0-2 (time limit at row 2), episode B = rows 3-4 (terminal at row 4),
# episode C = rows 5-6 (unfinished when the file ends).
_OBS = np.array([[i, 10.0 + i] for i in range(7)], np.float32)
_ACT = np.array([[0.1 * i] for i in range(7)], np.float32)
_REW = np.arange(1, 8, dtype=np.float32)
_TERM = np.array([0, 0, 0, 0, 1, 0, 0], bool)
_TOUT = np.array([0, 0, 1, 0, 0, 0, 0], bool)


def _write_d4rl(path, next_observations=None, timeouts=True, metadata=False):
    with h5py.File(path, "w") as f:
        f["observations"] = _OBS
        f["actions"] = _ACT
        f["rewards"] = _REW
        f["terminals"] = _TERM
        if timeouts:
            f["timeouts"] = _TOUT
        if next_observations is not None:
            f["next_observations"] = next_observations
        if metadata:
            f.attrs["env_name"] = "toy-medium-v2"
            f["metadata/algorithm"] = "SAC"
            f["metadata/iteration"] = np.int64(42)
            f["metadata/policy/fc0/weight"] = np.zeros((256, 11), np.float32)  # too big: skipped
            f["metadata"].attrs["quality"] = b"medium"


def test_d4rl_hdf5_without_next_observations_follows_qlearning_dataset(tmp_path):
    path = tmp_path / "toy.hdf5"
    _write_d4rl(path, metadata=True)
    ds, meta = load_d4rl_hdf5(path)

    # By hand: rows 2 (timeout: its successor is not stored) and 6 (last row) are dropped; kept rows 0,1,3,4,5.
    rows = [0, 1, 3, 4, 5]
    np.testing.assert_array_equal(ds.observations, [[0, 10], [1, 11], [3, 13], [4, 14], [5, 15]])
    np.testing.assert_array_equal(ds.next_observations, [[1, 11], [2, 12], [4, 14], [5, 15], [6, 16]])
    np.testing.assert_array_equal(ds.actions, _ACT[rows])
    np.testing.assert_array_equal(ds.rewards, [1, 2, 4, 5, 6])
    np.testing.assert_array_equal(ds.terminals, [0, 0, 0, 1, 0])
    # the last kept step of A (before the dropped timeout row) and of the unfinished C are marked as cut
    np.testing.assert_array_equal(ds.timeouts, [0, 1, 0, 0, 1])
    for name in FIELDS:
        assert np.asarray(getattr(ds, name)).dtype == np.float32
    np.testing.assert_array_equal(episode_returns(ds), [1 + 2, 4 + 5, 6])

    assert meta["source"] == "d4rl-hdf5" and meta["path"] == str(path.resolve())
    assert meta["rebuilt_next_observations"] is True
    assert meta["env_name"] == "toy-medium-v2" and meta["algorithm"] == "SAC" and meta["iteration"] == 42
    assert meta["quality"] == "medium"
    assert not any("weight" in k for k in meta)


def test_d4rl_hdf5_with_next_observations_keeps_every_row(tmp_path):
    path = tmp_path / "toy.hdf5"
    next_obs = _OBS + 100.0
    _write_d4rl(path, next_observations=next_obs)
    ds, meta = load_d4rl_hdf5(path)
    np.testing.assert_array_equal(ds.observations, _OBS)
    np.testing.assert_array_equal(ds.next_observations, next_obs)
    np.testing.assert_array_equal(ds.actions, _ACT)
    np.testing.assert_array_equal(ds.rewards, _REW)
    np.testing.assert_array_equal(ds.terminals, [0, 0, 0, 0, 1, 0, 0])
    np.testing.assert_array_equal(ds.timeouts, [0, 0, 1, 0, 0, 0, 0])
    assert meta["rebuilt_next_observations"] is False and meta["source"] == "d4rl-hdf5"
    np.testing.assert_array_equal(episode_returns(ds), [1 + 2 + 3, 4 + 5, 6 + 7])


def test_d4rl_hdf5_without_timeouts_only_drops_the_last_row(tmp_path):
    path = tmp_path / "toy.hdf5"
    _write_d4rl(path, timeouts=False)
    ds, _ = load_d4rl_hdf5(path)
    np.testing.assert_array_equal(ds.observations, _OBS[:6])
    np.testing.assert_array_equal(ds.next_observations, _OBS[1:])
    np.testing.assert_array_equal(ds.terminals, [0, 0, 0, 0, 1, 0])
    np.testing.assert_array_equal(ds.timeouts, [0, 0, 0, 0, 0, 1])


def test_d4rl_hdf5_missing_dataset_is_a_clear_error(tmp_path):
    path = tmp_path / "bad.hdf5"
    with h5py.File(path, "w") as f:
        f["observations"] = _OBS
    with pytest.raises(ValueError, match="actions"):
        load_d4rl_hdf5(path)


# ------------------------------------------------------------------------------------------------------------------
# Minari (recorded with minari's own DataCollector)
# ------------------------------------------------------------------------------------------------------------------

try:
    import minari
except ImportError:  # minari is in the `test` extra; the other tests do not need it
    minari = None
needs_minari = pytest.mark.skipif(minari is None, reason="minari is not installed (pip install -e '.[test]')")


class _Walk(gym.Env):
    """1-D walk: obs (x, t); reward x; terminates once x >= 2.5. Optionally goal-conditioned dict observations."""

    def __init__(self, goal_conditioned: bool = False):
        box = gym.spaces.Box(-100.0, 100.0, (2,), np.float32)
        if goal_conditioned:
            goal = gym.spaces.Box(-100.0, 100.0, (1,), np.float32)
            box = gym.spaces.Dict({"observation": box, "achieved_goal": goal, "desired_goal": goal})
        self.observation_space = box
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.goal_conditioned = goal_conditioned

    def _obs(self):
        obs = np.array([self.x, self.t], np.float32)
        if not self.goal_conditioned:
            return obs
        return {
            "observation": obs,
            "achieved_goal": np.array([self.x], np.float32),
            "desired_goal": np.array([2.5], np.float32),
        }

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x, self.t = 0.0, 0
        return self._obs(), {}

    def step(self, action):
        self.x += float(action[0])
        self.t += 1
        return self._obs(), self.x, self.x >= 2.5, False, {}


def _record(dataset_id: str, goal_conditioned: bool = False) -> None:
    """Three episodes: terminated after 3 steps, time-limited after 4, unfinished after 2 (flushed as truncated)."""
    env = gym.wrappers.TimeLimit(_Walk(goal_conditioned), max_episode_steps=4)
    collector = minari.DataCollector(env)
    for seed, action, steps in ((0, 1.0, 3), (1, 0.5, 4), (2, 0.25, 2)):
        collector.reset(seed=seed)
        for _ in range(steps):
            collector.step(np.array([action], np.float32))
    collector.create_dataset(
        dataset_id=dataset_id,
        algorithm_name="scripted",
        author="proto_brax tests",
        author_email="tests@example.invalid",
        code_permalink="https://example.invalid/proto_brax",
        description="tiny walk",
    )
    collector.close()


# Expected transitions, by hand (x after each step; obs = (x, t)).
_EXP_OBS = [[0, 0], [1, 1], [2, 2], [0, 0], [0.5, 1], [1, 2], [1.5, 3], [0, 0], [0.25, 1]]
_EXP_NEXT = [[1, 1], [2, 2], [3, 3], [0.5, 1], [1, 2], [1.5, 3], [2, 4], [0.25, 1], [0.5, 2]]
_EXP_REW = [1, 2, 3, 0.5, 1, 1.5, 2, 0.25, 0.5]
_EXP_TERM = [0, 0, 1, 0, 0, 0, 0, 0, 0]
_EXP_TOUT = [0, 0, 0, 0, 0, 0, 1, 0, 1]


@needs_minari
@pytest.mark.filterwarnings("ignore::UserWarning")
def test_minari_by_id(tmp_path, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    _record("toy/walk-v0")
    ds, meta = load_minari("toy/walk-v0")

    assert dataset_size(ds) == 9
    np.testing.assert_allclose(ds.observations, _EXP_OBS)
    np.testing.assert_allclose(ds.next_observations, _EXP_NEXT)
    np.testing.assert_allclose(ds.actions, [[1.0]] * 3 + [[0.5]] * 4 + [[0.25]] * 2)
    np.testing.assert_allclose(ds.rewards, _EXP_REW)
    np.testing.assert_array_equal(ds.terminals, _EXP_TERM)
    np.testing.assert_array_equal(ds.timeouts, _EXP_TOUT)
    for name in FIELDS:
        assert np.asarray(getattr(ds, name)).dtype == np.float32
    np.testing.assert_allclose(episode_returns(ds), [6.0, 5.0, 0.75])
    assert meta["source"] == "minari" and meta["dataset_id"] == "toy/walk-v0"
    assert meta["total_episodes"] == 3 and meta["total_steps"] == 9
    assert meta["algorithm_name"] == "scripted"
    assert meta["content_hash"] == content_hash(ds) and "proto_brax" not in meta  # not one of our exports
    validate_for_env(ds, 2, 1, "toy/walk-v0")


@needs_minari
@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("env_var_before", [None, "elsewhere"])
def test_minari_by_path_does_not_leak_env_var(tmp_path, monkeypatch, env_var_before):
    root = tmp_path / "root"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    _record("walk-v0")
    if env_var_before is None:
        monkeypatch.delenv("MINARI_DATASETS_PATH")
    else:
        monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / env_var_before))

    ds, meta = load_minari(root / "walk-v0")
    assert dataset_size(ds) == 9 and meta["dataset_id"] == "walk-v0"
    np.testing.assert_array_equal(ds.terminals, _EXP_TERM)
    ds2, _ = load_minari(str(root / "walk-v0" / "data"))  # the data/ directory, as a string
    assert content_hash(ds2) == content_hash(ds)

    expected = None if env_var_before is None else str(tmp_path / env_var_before)
    assert os.environ.get("MINARI_DATASETS_PATH") == expected


@needs_minari
@pytest.mark.filterwarnings("ignore::UserWarning")
def test_minari_goal_conditioned_dict_observations_are_flattened(tmp_path, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    _record("toy/goal-v0", goal_conditioned=True)
    ds, meta = load_minari("toy/goal-v0")
    goal = [[2.5]] * 9
    np.testing.assert_allclose(ds.observations, np.concatenate([_EXP_OBS, goal], axis=1))  # (x, t, goal)
    np.testing.assert_allclose(ds.next_observations, np.concatenate([_EXP_NEXT, goal], axis=1))
    np.testing.assert_array_equal(ds.terminals, _EXP_TERM)
    np.testing.assert_array_equal(ds.timeouts, _EXP_TOUT)
    assert meta["observation_layout"] == "concat(observation, desired_goal)"


@needs_minari
def test_minari_missing_dataset_raises(tmp_path, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    with pytest.raises(FileNotFoundError):
        load_minari("toy/absent-v0")


@needs_minari
@pytest.mark.filterwarnings("ignore::UserWarning")
def test_sweep_dataset_argument_reads_minari_ids_and_directories(tmp_path, monkeypatch):
    """`--dataset D4RL/pen/human-v2` (the paper-adroit preset) goes through datasets.load_dataset: a Minari id or a
    Minari directory loads; an id that is not cached names where to put it (nothing is downloaded)."""
    from proto_brax.data import cache as datasets

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    _record("toy/walk-v0")
    by_id, _ = datasets.load_dataset("toy/walk-v0")
    by_dir, _ = datasets.load_dataset(str(tmp_path / "toy" / "walk-v0"))
    assert dataset_size(by_id) == 9 and content_hash(by_dir) == content_hash(by_id)
    with pytest.raises(FileNotFoundError, match=f"copy it to {tmp_path}/D4RL/pen/human-v2"):
        datasets.load_dataset("D4RL/pen/human-v2")


# ------------------------------------------------------------------------------------------------------------------
# validate_for_env, episode_returns
# ------------------------------------------------------------------------------------------------------------------


def test_validate_for_env_accepts_a_matching_dataset():
    validate_for_env(_random_dataset(obs=5, act=3), 5, 3, "toy", env_name="toy-env")


def test_validate_for_env_observation_size_mismatch_names_both_sizes():
    with pytest.raises(ValueError) as e:
        validate_for_env(_random_dataset(obs=11, act=3), 17, 3, "hopper-medium", env_name="walker2d")
    msg = str(e.value)
    assert "11" in msg and "17" in msg and "hopper-medium" in msg and "walker2d" in msg


def test_validate_for_env_action_size_mismatch_names_both_sizes():
    with pytest.raises(ValueError) as e:
        validate_for_env(_random_dataset(obs=5, act=3), 5, 6, "hopper-medium", env_name="halfcheetah")
    msg = str(e.value)
    assert "action size 6" in msg and "actions of size 3" in msg and "hopper-medium" in msg and "halfcheetah" in msg


def test_validate_for_env_rejects_out_of_range_actions_and_ragged_arrays():
    ds = _random_dataset(obs=5, act=3)
    actions = np.array(ds.actions, copy=True)
    actions[4, 1] = 1.5
    with pytest.raises(ValueError, match=r"outside \[-1, 1\]"):
        validate_for_env(ds.replace(actions=actions), 5, 3, "toy")
    with pytest.raises(ValueError, match="leading lengths"):
        validate_for_env(ds.replace(rewards=np.asarray(ds.rewards)[:-1]), 5, 3, "toy")
    rewards = np.array(ds.rewards, copy=True)
    rewards[0] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        validate_for_env(ds.replace(rewards=rewards), 5, 3, "toy")


def test_episode_returns_by_hand():
    z = np.zeros((7, 1), np.float32)
    ds = Transition(
        observations=z,
        actions=z,
        rewards=np.array([1, 2, 3, 4, 5, 6, 7], np.float32),
        next_observations=z,
        terminals=np.array([0, 1, 0, 0, 0, 1, 0], np.float32),
        timeouts=np.array([0, 0, 0, 1, 0, 0, 0], np.float32),
    )
    # episodes: [1, 2] | [3, 4] | [5, 6] | [7] (unfinished at the end)
    np.testing.assert_array_equal(episode_returns(ds), [3, 7, 11, 7])
    stats = episode_return_stats(ds)
    assert stats == {"num_transitions": 7, "num_episodes": 4, "mean": 7.0, "min": 3.0, "max": 11.0}

    # a dataset ending exactly at an episode end has no extra empty episode
    last = ds.replace(timeouts=np.array([0, 0, 0, 1, 0, 0, 1], np.float32))
    np.testing.assert_array_equal(episode_returns(last), [3, 7, 11, 7])

    e1, e0 = np.zeros((0, 1), np.float32), np.zeros(0, np.float32)
    empty = Transition(observations=e1, actions=e1, rewards=e0, next_observations=e1, terminals=e0, timeouts=e0)
    assert episode_returns(empty).shape == (0,)
    assert episode_return_stats(empty)["num_episodes"] == 0


def test_reward_transform_by_hand():
    """The reference codes' locomotion reward scale 1000 / (max − min episode return), and r' = scale · r + shift."""
    z = np.zeros((7, 1), np.float32)
    ds = Transition(observations=z, actions=z, rewards=np.array([1, 2, 3, 4, 5, 6, 7], np.float32),
                    next_observations=z, terminals=np.array([0, 1, 0, 0, 0, 1, 0], np.float32),
                    timeouts=np.array([0, 0, 0, 1, 0, 0, 0], np.float32))
    assert return_range_scale(ds) == pytest.approx(1000.0 / (11 - 3))  # episode returns 3, 7, 11, 7
    out = transform_rewards(ds, 0.5, -1.0)
    np.testing.assert_array_equal(out.rewards, [-0.5, 0, 0.5, 1, 1.5, 2, 2.5])
    assert out.rewards.dtype == np.float32 and out.terminals is ds.terminals
    assert transform_rewards(ds, 1.0, 0.0) is ds
    with pytest.raises(ValueError, match="before with_returns_to_go"):
        transform_rewards(with_returns_to_go(ds, 0.99), 2.0, 0.0)
    one = ds.replace(terminals=np.zeros(7, np.float32), timeouts=np.zeros(7, np.float32))
    with pytest.raises(ValueError, match="--reward-scale"):
        return_range_scale(one)
