"""Adroit on native MuJoCo (envs.adroit_native) and the host-loop SAC that trains its experts
(data.native_behavior): the env is the cross-check's native reference step for step; the trainer writes snapshots in
the behaviour format, evaluates success by D4RL's rule and resumes from its last snapshot."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

from proto_brax.analysis.crosscheck import native_rollout
from proto_brax.data import generate as g
from proto_brax.data import native_behavior as nb
from proto_brax.envs import adroit
from proto_brax.envs.adroit_native import NativeAdroit


@pytest.mark.parametrize("task", ["pen", "door", "hammer"])  # (hammer's reset failed on a NumPy model row)
def test_native_env_is_the_cross_checks_native_reference_step_for_step(task):
    """Same layout (drawn by the MJX env's own sample_layout from the key), same actions: the same observations and
    rewards as ``crosscheck.native_rollout`` on the capsule model, which adroit_check compares with MJX."""
    env = NativeAdroit(task, d4rl_reward=False)  # (native_rollout scores gymnasium-robotics' reward)
    key = jax.random.PRNGKey(3)
    obs0 = env.reset(key)
    field, body = adroit.LAYOUT[task]
    layout = np.asarray(adroit.sample_layout(task, key, env._own))
    np.testing.assert_array_equal(getattr(env.model, field)[env.ids.body[body]], layout)
    actions = np.random.default_rng(0).uniform(-1, 1, (15, env.action_size))
    steps = [env.step(a) for a in actions]
    ref_obs, ref_rew, _ = native_rollout(task, adroit.load_capsule_model(task), layout, actions)
    np.testing.assert_allclose(obs0, ref_obs[0], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(np.stack([s[0] for s in steps]), ref_obs[1:], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose([s[1] for s in steps], ref_rew, rtol=1e-6, atol=1e-6)
    assert obs0.shape == (adroit.get_task(task).obs_size,) and obs0.dtype == np.float32


def test_pen_drop_terminates_only_with_d4rls_rule():
    """A pen that falls (object z < 0.075) ends the episode under D4RL's reward (the registered env's), not under
    gymnasium-robotics'."""
    for d4rl, want in ((True, True), (False, False)):
        env = NativeAdroit("pen", d4rl_reward=d4rl)
        env.reset(jax.random.PRNGKey(0))
        env.data.qpos[-6] += 0.5  # OBJTx slides along −z in pen's XML: the pen's centre from z 0.25 to −0.25
        _, _, terminal, _ = env.step(np.zeros(env.action_size))
        assert terminal == want


def test_host_loop_sac_writes_behaviour_snapshots_and_resumes(tmp_path):
    args = nb.Args(env="pen", steps=300, snapshot_every=150, eval_episodes=2, learning_starts=100,
                   buffer_capacity=1000, batch_size=32, hidden=(16, 16), out=tmp_path / "behavior",
                   resume_dir=tmp_path / "resume")
    log = nb.train(args)
    assert [r["step"] for r in log] == [150, 300]
    assert all(0.0 <= r["eval_success_rate"] <= 1.0 and np.isfinite(r["eval_return_mean"]) for r in log)
    assert np.isfinite(log[0]["critic_loss"]) and np.isfinite(log[1]["critic_loss"])  # updates from step 100
    snaps = g.list_snapshots("pen", tmp_path / "behavior")  # what `datasets make pen-expert` reads
    assert [s.step for s in snaps] == [150, 300] and snaps[-1].eval_return == pytest.approx(log[-1]["eval_return_mean"])
    meta = json.loads((tmp_path / "behavior" / "pen" / "step_0000300" / "metadata.json").read_text())
    assert meta["backend"] == "native" and meta["config"]["trainer"] == "native_behavior"
    resumed = nb.train(nb.Args(**{**vars(args), "steps": 450}))  # continues from the step-300 state
    assert [r["step"] for r in resumed] == [450]
    assert [s.step for s in g.list_snapshots("pen", tmp_path / "behavior")] == [150, 300, 450]


def test_host_loop_sac_trains_on_gymnasiums_own_v5_env(tmp_path):
    """Issue 34's behaviour policies: the same trainer on gymnasium's Hopper-v5 (its sizes are the MJX port's; the same
    key resets to the same state); no success rule, so the rate is None."""
    from proto_brax import envs
    from proto_brax.envs.gym_v5 import NativeGymV5

    native, port = NativeGymV5("hopper-v5"), envs.make_env("hopper-v5")
    assert (native.observation_size, native.action_size) == (port.observation_size, port.action_size)
    np.testing.assert_array_equal(native.reset(jax.random.PRNGKey(4)), NativeGymV5("hopper-v5").reset(
        jax.random.PRNGKey(4)))
    args = nb.Args(env="hopper-v5", steps=200, snapshot_every=100, eval_episodes=1, learning_starts=50,
                   buffer_capacity=500, batch_size=16, hidden=(8, 8), out=tmp_path / "behavior",
                   resume_dir=tmp_path / "resume")
    log = nb.train(args)
    assert [r["step"] for r in log] == [100, 200] and all(r["eval_success_rate"] is None for r in log)
    assert [s.step for s in g.list_snapshots("hopper-v5", tmp_path / "behavior")] == [100, 200]


def test_measure_runs_a_v5_snapshot_on_gymnasiums_own_env(tmp_path, monkeypatch):
    """``datasets measure hopper-v5`` (which picks the medium snapshot) samples each snapshot's tanh-Gaussian on the
    native env its datasets are recorded on, not on the MJX port: the recorded returns are those of an episode loop
    written out here on gymnasium's Hopper-v5 (episode e resets from key e of the seed's split, the policy's key at
    step t is that key folded with t + 1)."""
    from proto_brax.cli import datasets as datasets_cli
    from proto_brax.envs.gym_v5 import NativeGymV5

    nb.train(nb.Args(env="hopper-v5", steps=100, snapshot_every=100, eval_episodes=1, learning_starts=50,
                     buffer_capacity=200, batch_size=16, hidden=(8, 8), out=tmp_path / "behavior",
                     resume_dir=tmp_path / "resume"))
    monkeypatch.setattr(g, "_episode_returns", None)  # the MJX path would fail
    out = datasets_cli.cmd_measure(datasets_cli.Measure("hopper-v5", episodes=3, seed=4,
                                                        behavior_root=tmp_path / "behavior"))
    snap = g.list_snapshots("hopper-v5", tmp_path / "behavior")[-1]
    nets, params = g.load_snapshot_actor(snap, NativeGymV5("hopper-v5"))
    sim, returns = NativeGymV5("hopper-v5"), []
    for k in jax.random.split(jax.random.PRNGKey(4), 3):
        obs, total = sim.reset(k), 0.0
        for t in range(1000):
            a = np.asarray(g.stochastic_policy(nets)(params, obs[None], jax.random.fold_in(k, t + 1)))[0]
            obs, reward, terminal, _ = sim.step(a)
            total += reward
            if terminal:
                break
        returns.append(total)
    assert out[0]["mean"] == pytest.approx(np.mean(returns), rel=1e-6)
    assert snap.metadata["behavior_return"]["std"] == pytest.approx(np.std(returns), rel=1e-6)
    assert np.std(returns) > 0  # three different episodes
