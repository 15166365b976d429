"""Pretrained bundles: bit-exact save/restore, finetune from restored == from memory, clear errors; the CLIs."""

from __future__ import annotations

import dataclasses
import json
import shutil

import jax
import numpy as np
import pytest
from test_engine import SCRATCH, TINY, finetune_fn, point_dataset

from proto_brax import checkpoints, pretrain, sweep
from proto_brax.agents.learner import Pretrained
from proto_brax.agents.sac import SACHParams
from proto_brax.cli import checkpoints as checkpoints_cli
from proto_brax.data.dataset import save_npz
from proto_brax.networks import NetworkConfig

ARGS = dict(algo="eql", seeds=(0, 1), steps=400, log_every=200, batch_size=32, hidden=(32, 32), eval_episodes=2,
            hp={"lr_actor": 1e-3, "alpha": 0.5})


@pytest.fixture(scope="module")
def bundle(tmp_path_factory):
    root = tmp_path_factory.mktemp("bundle")
    data_file = root / "point-noisy.npz"
    save_npz(data_file, jax.device_get(point_dataset()), {"env": "point", "kind": "noisy-expert"})
    with pytest.MonkeyPatch.context() as mp:  # the resume state of an unfinished run goes under $PROTO_BRAX_RUNS
        mp.setenv("PROTO_BRAX_RUNS", str(root / "runs"))
        meta = pretrain.pretrain(pretrain.PretrainArgs(dataset=str(data_file), out=root / "eql", **ARGS))
    return root, data_file, meta


def test_bundle_round_trip_is_bit_exact(bundle):
    root, _, meta = bundle
    state, meta2 = checkpoints.load_bundle(root / "eql")
    assert meta2["algo"] == "eql" and meta2["seeds"] == [0, 1] and meta2["env"] == "point"
    assert {"returns_per_seed", "normalized_score_mean"} <= set(meta2["offline_eval"])
    assert (meta2["reward_scale"], meta2["reward_shift"]) == (1.0, 0.0)  # point's rule: raw rewards
    assert state.actor_opt is not None and state.value is not None
    # its chunks were saved for a resume while it ran, and removed once the bundle was saved
    assert meta2["resumed_after_chunk"] == 0 and list((root / "runs" / "pretrain").iterdir()) == []
    # save again from the restored state and restore: identical leaves (params and optimizer state)
    checkpoints.save_bundle(root / "copy", state, {k: v for k, v in meta2.items() if k != "format_version"})
    again, _ = checkpoints.load_bundle(root / "copy")
    jax.tree.map(np.testing.assert_array_equal, state, again)
    counts = jax.tree.leaves(state.actor_opt)
    assert any(np.asarray(c).dtype == np.int32 and np.all(np.asarray(c) == 400) for c in counts)  # Adam step count


def test_finetune_from_restored_bundle_equals_in_memory(bundle):
    root, data_file, _ = bundle
    state, _ = checkpoints.load_bundle(root / "eql")
    cfg = dataclasses.replace(TINY, sampling="symmetric", steps=400, eval_every=200)
    ft, single = finetune_fn(cfg)
    hp = jax.tree.map(lambda x: x, SACHParams.create(**SCRATCH))
    restored = Pretrained(actor=jax.tree.map(lambda x: x[1], state.actor), critic=jax.tree.map(lambda x: x[1],
                                                                                                 state.critic))
    in_memory = jax.tree.map(lambda x: np.array(x), restored)  # an independent host copy
    a = single(hp, jax.random.PRNGKey(0), restored, point_dataset())[1]
    b = single(hp, jax.random.PRNGKey(0), Pretrained(**{k: jax.tree.map(jax.numpy.asarray, v) for k, v in
                                                         vars(in_memory).items()}), point_dataset())[1]
    jax.tree.map(np.testing.assert_array_equal, a, b)


def test_mismatched_checkpoint_is_rejected_with_the_reason(bundle):
    root, _, _ = bundle
    meta = checkpoints.read_metadata(root / "eql")
    cfg = dataclasses.replace(TINY, net=NetworkConfig(hidden=(64, 64)))
    with pytest.raises(checkpoints.CheckpointError, match=r"hidden sizes \(32, 32\)"):
        checkpoints.validate_bundle(meta, cfg.env, 4, 2, cfg.net)
    with pytest.raises(checkpoints.CheckpointError, match="Not a pretrained bundle"):
        checkpoints.validate_bundle({**meta, "kind": None}, cfg.env, 4, 2, cfg.net)
    with pytest.raises(checkpoints.CheckpointError, match="env 'point' \\(finetune: 'hopper'\\)"):
        checkpoints.validate_bundle(meta, "hopper", 11, 3, NetworkConfig(hidden=(32, 32)))


def test_corrupt_or_missing_checkpoint_gives_clear_error(bundle, tmp_path):
    root, _, _ = bundle
    with pytest.raises(checkpoints.CheckpointError, match="No checkpoint at"):
        checkpoints.load_bundle(tmp_path / "nothing")
    bad = tmp_path / "bad"
    shutil.copytree(root / "eql", bad)
    (bad / "metadata.json").write_text("{not json")
    with pytest.raises(checkpoints.CheckpointError, match="Corrupt metadata"):
        checkpoints.load_bundle(bad)
    shutil.rmtree(bad)
    shutil.copytree(root / "eql", bad)
    meta = json.loads((bad / "metadata.json").read_text())
    meta["net"]["hidden"] = [16, 16]  # arrays no longer match what the metadata promises
    (bad / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(checkpoints.CheckpointError, match="corrupt or was saved with a different"):
        checkpoints.load_bundle(bad)


def test_sweep_finetune_only_from_bundle(bundle, tmp_path, capsys):
    root, data_file, meta = bundle
    args = sweep.SweepArgs(env="point", checkpoint=str(root / "eql"), dataset=str(data_file), tau=(0.005,), eta=(0.9,),
                           seeds=(0, 1, 2), steps=400, eval_every=200, eval_episodes=2, hidden=(32, 32),
                           batch_size=32, learning_starts=64, out=tmp_path / "sw", hp=dict(SCRATCH, alpha0=1.0))
    summary = sweep.run_sweep(args)
    cfg = json.loads((tmp_path / "sw" / "config.json").read_text())
    assert cfg["checkpoint_metadata"]["algo"] == "eql"
    assert summary[0]["final_eval_return"]["n"] == 3
    rows = [json.loads(x) for x in (tmp_path / "sw" / "metrics.jsonl").read_text().splitlines()]
    assert all(np.isfinite(r["eval_return"]) for r in rows)
    # the buffer holds the very rows the bundle was pretrained on, and config.json says so
    assert cfg["dataset_vs_bundle"] == {"dataset": "point-noisy", "bundle_content_hash": meta["dataset_content_hash"],
                                        "content_hash": meta["dataset_content_hash"], "same_content": True}
    same = tmp_path / "point-copy.npz"  # the bundle's rows under another name (e.g. a Minari export): accepted
    shutil.copy(data_file, same)
    sweep.run_sweep(dataclasses.replace(args, dataset=str(same), out=tmp_path / "same"))
    other = tmp_path / "point-other.npz"  # other rows under another name: refused before anything is written
    data = jax.device_get(point_dataset())
    save_npz(other, data.replace(rewards=data.rewards + 1.0), {"env": "point", "kind": "noisy-expert"})
    with pytest.raises(checkpoints.CheckpointError, match="pretrained on dataset 'point-noisy', the finetune reads "
                                                          "'point-other': pass --dataset point-noisy"):
        sweep.run_sweep(dataclasses.replace(args, dataset=str(other), out=tmp_path / "other"))
    assert not (tmp_path / "other").exists()
    bad = sweep.SweepArgs(env="point", checkpoint=str(root / "eql"), hidden=(64, 64), out=tmp_path / "bad")
    with pytest.raises(checkpoints.CheckpointError, match="hidden sizes"):
        sweep.run_sweep(bad)
    assert not (tmp_path / "bad").exists()


def test_regenerated_dataset_is_recorded_not_refused(bundle):
    _, _, meta = bundle
    rec = checkpoints.bundle_dataset_record(meta, {"content_hash": "f" * 64})
    assert rec["same_content"] is False and rec["content_hash"] == "f" * 64
    assert "regenerated" in checkpoints.regenerated_note(rec) and "ffffffffffff…" in checkpoints.regenerated_note(rec)
    same = checkpoints.bundle_dataset_record(meta, {"content_hash": meta["dataset_content_hash"]})
    assert same["same_content"] is True and checkpoints.regenerated_note(same) is None
    assert checkpoints.bundle_dataset_record({**meta, "dataset_content_hash": None}, {})["same_content"] is None
    checkpoints.validate_bundle_dataset(meta, "/elsewhere/point-noisy.npz")  # a file's stem is its name


def test_bundle_accepts_its_own_rows_under_another_name(bundle):
    """A Minari export (or a copy) of the bundle's dataset holds the same rows under another name: accepted by
    content hash; another name with other rows is still refused."""
    _, _, meta = bundle
    same = meta["dataset_content_hash"]
    assert same
    checkpoints.validate_bundle_dataset(meta, "proto_brax/point/noisy-v0", same)
    with pytest.raises(checkpoints.CheckpointError, match="pretrained on dataset"):
        checkpoints.validate_bundle_dataset(meta, "proto_brax/point/noisy-v0", "0" * 64)
    with pytest.raises(checkpoints.CheckpointError, match="pretrained on dataset"):
        checkpoints.validate_bundle_dataset(meta, "proto_brax/point/noisy-v0")


def test_checkpoints_cli_lists_bundles(bundle, capsys):
    root, _, _ = bundle
    checkpoints_cli.main(["list", str(root)])
    out = capsys.readouterr().out
    assert "eql" in out and "point-noisy" in out
    checkpoints_cli.main(["show", str(root / "eql")])
    assert '"algo": "eql"' in capsys.readouterr().out
    checkpoints_cli.main(["index", str(root)])
    index = (root / "INDEX.md").read_text()
    assert "| `eql` | eql | point-noisy | [0, 1] | 400 |" in index


def test_evaluate_reproduces_the_recorded_offline_evaluation_and_draws_new_ones(bundle, capsys):
    root, _, meta = bundle
    returns, _ = checkpoints_cli.evaluate_bundle(root / "eql", repeats=3)
    assert returns.shape == (2, 3, ARGS["eval_episodes"])  # [bundle seeds, repetitions, episodes]
    # Repetition 0 is pretraining's own evaluation (its keys, its episode count), per seed of the bundle.
    np.testing.assert_allclose(returns[:, 0].mean(-1), meta["offline_eval"]["returns_per_seed"], rtol=1e-4)
    assert not np.allclose(returns[:, 1], returns[:, 0])  # the other repetitions start from other states
    assert not np.allclose(returns[0], returns[1])  # each seed's own actor
    checkpoints_cli.main(["evaluate", str(root / "eql"), "4", "2"])
    out = capsys.readouterr().out
    assert out.count("recorded:") == 2 and "16 episodes on point" in out
    checkpoints_cli.main(["evaluate", str(root / "eql")])  # the recorded evaluation's size, once per seed
    assert f"{2 * ARGS['eval_episodes']} episodes on point" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="positive integers"):
        checkpoints_cli.main(["evaluate", str(root / "eql"), "0"])
    with pytest.raises(SystemExit, match="^error: .*metadata"):
        checkpoints_cli.main(["evaluate", str(root / "missing")])


def test_static_dataclass_fields_are_not_saved_and_come_back_from_the_target(tmp_path):
    """A pytree dataclass's static fields (flax ``pytree_node=False``, MJX's typed-int fields such as the constraint
    counts ``Data._impl.ne``) are not leaves: orbax never stores them. Restoring into such a target failed on them
    ("Unsupported type"), so no MJX sweep could resume."""
    from flax import struct

    @struct.dataclass
    class Node:
        x: jax.Array
        count: int = struct.field(pytree_node=False)

    tree = {"node": Node(x=np.arange(3.0, dtype=np.float32), count=np.int64(5))}
    checkpoints.save(tmp_path / "c", tree, {})
    target = {"node": Node(x=np.zeros(3, np.float32), count=np.int64(5))}
    restored, _ = checkpoints.restore(tmp_path / "c", target)
    np.testing.assert_array_equal(restored["node"].x, [0.0, 1.0, 2.0])
    assert restored["node"].count == 5


def test_interrupted_save_keeps_the_previous_checkpoint(tmp_path, monkeypatch):
    tree = {"w": np.arange(4.0, dtype=np.float32)}
    checkpoints.save(tmp_path / "c", tree, {"n": 1})

    def boom(*a, **k):
        raise KeyboardInterrupt("killed mid-save")

    monkeypatch.setattr(checkpoints, "write_json_atomic", boom)
    with pytest.raises(KeyboardInterrupt):
        checkpoints.save(tmp_path / "c", {"w": np.zeros(4, np.float32)}, {"n": 2})
    monkeypatch.undo()
    restored, meta = checkpoints.restore(tmp_path / "c", tree)
    assert meta["n"] == 1
    np.testing.assert_array_equal(restored["w"], tree["w"])
    for step in (1, 2, 3):
        checkpoints.save_step(tmp_path / "steps", step, tree, {"n": step})
    assert [p.name for p in sorted((tmp_path / "steps").glob("step_*"))] == ["step_00000002", "step_00000003"]
    assert checkpoints.latest_step(tmp_path / "steps").name == "step_00000003"


def test_checkpoint_predating_an_optional_field_still_restores(tmp_path):
    """A state type that gains an optional (None) field keeps reading its older checkpoints (orbax alone refuses any
    key difference); a checkpoint that lacks a real array is still refused."""
    import jax.numpy as jnp
    import optax
    from flax import struct

    @struct.dataclass
    class Old:
        w: dict
        opt: object
        gone: object = None  # None on disk

    @struct.dataclass
    class New:
        w: dict
        opt: object
        gone: object = None
        added: object = None  # the new optional field

    w = {"a": jnp.arange(3.0)}
    old = Old(w=w, opt=optax.inject_hyperparams(optax.adam)(learning_rate=1e-3).init(w))
    checkpoints.save(tmp_path / "c", old, {"k": 1})
    target = New(w=jax.tree.map(jnp.zeros_like, w), opt=jax.tree.map(jnp.zeros_like, old.opt))
    got, meta = checkpoints.restore(tmp_path / "c", target)
    assert isinstance(got, New) and got.added is None and meta["k"] == 1
    np.testing.assert_array_equal(got.w["a"], w["a"])
    assert type(got.opt) is type(old.opt)
    for a, b in zip(jax.tree.leaves(got.opt), jax.tree.leaves(old.opt)):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(checkpoints.CheckpointError, match="Could not restore"):
        checkpoints.restore(tmp_path / "c", target.replace(added={"b": jnp.zeros(2)}))


def test_zero_size_arrays_round_trip(tmp_path):
    """MJX states hold zero-size arrays (``act`` without activations) that orbax refuses to save: they come back
    with their shapes, next to the real data."""
    tree = {"act": np.zeros((4, 0), np.float32), "q": np.arange(6, dtype=np.float32).reshape(2, 3),
            "empty_int": np.zeros((0,), np.int32), "none": None}
    checkpoints.save(tmp_path / "z", tree, {"k": 1})
    back, meta = checkpoints.restore(tmp_path / "z", tree)
    assert meta["k"] == 1 and back["none"] is None
    for k in ("act", "q", "empty_int"):
        assert back[k].shape == tree[k].shape and back[k].dtype == tree[k].dtype
    np.testing.assert_array_equal(back["q"], tree["q"])
