"""Engine-level fidelity switches (proto_brax.config.Fidelity): the online buffer's preload, behaviour-policy
evaluation, and that the defaults leave every run exactly as before. Loss-level switches are in test_losses.py."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest
from test_engine import SCRATCH, TINY, point_dataset

from proto_brax.config import HParams
from proto_brax.data.replay import replay_sample
from proto_brax.fidelity import Fidelity
from proto_brax.train import online

CFG = dataclasses.replace(TINY, steps=400, eval_every=200, sampling="symmetric", learning_starts=1)


def test_online_preload_copies_distinct_dataset_rows_into_the_buffer():
    data = point_dataset()
    cfg = dataclasses.replace(CFG, fidelity=Fidelity(online_preload=300))
    assert cfg.capacity == 400 + 300  # room for every online step besides the preload
    state = jax.jit(online.make_finetune(cfg).init)(HParams.create(), jax.random.PRNGKey(0), None, data)
    assert int(state.buffer.size) == 300 and int(state.buffer.position) == 300
    rows = np.asarray(state.buffer.data.observations[:300])
    acts = np.asarray(state.buffer.data.actions[:300])
    data_obs, data_act = np.asarray(data.observations), np.asarray(data.actions)
    # Each preloaded row is a dataset row (observation and action together), drawn without replacement.
    idx = [int(np.flatnonzero((data_obs == o).all(1) & (data_act == a).all(1))[0]) for o, a in zip(rows, acts)]
    assert len(set(idx)) == 300
    np.testing.assert_array_equal(np.asarray(state.buffer.data.rewards[:300]), np.asarray(data.rewards)[idx])
    assert not np.asarray(state.buffer.data.observations[300:]).any()  # the rest is still empty
    # A symmetric batch's online half now draws from the preloaded rows before any env step.
    batch = replay_sample(jax.random.PRNGKey(1), state.buffer, data, 32, "symmetric", 0.5)
    online_half = np.asarray(batch.observations[16:])
    assert all((data_obs == o).all(1).any() for o in online_half)


def test_online_preload_rejects_runs_without_a_dataset():
    cfg = dataclasses.replace(CFG, sampling="online", fidelity=Fidelity(online_preload=10))
    with pytest.raises(ValueError, match="online_preload"):
        online.make_finetune(cfg).init(HParams.create(), jax.random.PRNGKey(0), None, None)
    with pytest.raises(ValueError, match="online_preload must be >= 0"):
        dataclasses.replace(CFG, fidelity=Fidelity(online_preload=-1))


@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_behaviour_evaluation_acts_like_training(algo):
    """eval_mode='behaviour' (official AntMaze evaluation): the same key gives the same returns, and the returns
    differ from the deterministic evaluation of the same learner."""
    cfg = dataclasses.replace(CFG, algo=algo, eval_episodes=6)
    hp = HParams.create(**SCRATCH, expl_noise=0.5)
    ft_det = online.make_finetune(cfg)
    ft_beh = online.make_finetune(dataclasses.replace(cfg, fidelity=Fidelity(eval_mode="behaviour")))
    learner = ft_det.init(hp, jax.random.PRNGKey(3), None, point_dataset()).learner
    key = jax.random.PRNGKey(4)
    det = np.asarray(jax.jit(ft_det.evaluate)(learner, key, hp)[0])
    beh = np.asarray(jax.jit(ft_beh.evaluate)(learner, key, hp)[0])
    np.testing.assert_array_equal(beh, np.asarray(jax.jit(ft_beh.evaluate)(learner, key, hp)[0]))
    assert np.abs(beh - det).max() > 1e-3


def test_official_fidelity_changes_the_run():
    """Fidelity.official() switches real choices: the same seed gives another critic-loss trajectory."""
    data, hp = point_dataset(), HParams.create()
    base = dataclasses.replace(CFG, steps=200, eval_every=200)
    runs = {}
    for name, fid in (("default", Fidelity()), ("official", Fidelity.official())):
        ft = online.make_finetune(dataclasses.replace(base, fidelity=fid))
        _, m = jax.jit(ft.finetune)(hp, jax.random.PRNGKey(5), None, data)
        runs[name] = np.asarray(m["critic_loss"])
    assert np.all(np.isfinite(runs["official"]))
    assert not np.array_equal(runs["default"], runs["official"])
