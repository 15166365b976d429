"""Engine-level fidelity switches (proto_brax.config.Fidelity): the online buffer's preload, behaviour-policy
evaluation, and that the defaults leave every run exactly as before. Loss-level switches are in test_losses.py."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference as ref
from helpers import perturb
from test_engine import SCRATCH, TINY, point_dataset

from proto_brax.agents import sac
from proto_brax.agents.insample import weighted_log_likelihood
from proto_brax.agents.learner import Pretrained, init_learner
from proto_brax.agents.registry import agent
from proto_brax.data.replay import replay_sample
from proto_brax.fidelity import Fidelity
from proto_brax.networks import NetworkConfig, make_networks
from proto_brax.train import online

CFG = dataclasses.replace(TINY, steps=400, eval_every=200, sampling="symmetric", learning_starts=1)


def test_online_preload_copies_distinct_dataset_rows_into_the_buffer():
    data = point_dataset()
    cfg = dataclasses.replace(CFG, fidelity=Fidelity(online_preload=300))
    assert cfg.capacity == 400 + 300  # room for every online step besides the preload
    state = jax.jit(online.make_finetune(cfg).init)(sac.SACHParams.create(), jax.random.PRNGKey(0), None, data)
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
        online.make_finetune(cfg).init(sac.SACHParams.create(), jax.random.PRNGKey(0), None, None)
    with pytest.raises(ValueError, match="online_preload must be >= 0"):
        dataclasses.replace(CFG, fidelity=Fidelity(online_preload=-1))


@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_behaviour_evaluation_acts_like_training(algo):
    """eval_mode='behaviour' (official AntMaze evaluation): the same key gives the same returns, and the returns
    differ from the deterministic evaluation of the same learner."""
    cfg = dataclasses.replace(CFG, algo=algo, eval_episodes=6)
    hp_cls = agent(algo).hparams
    hp = hp_cls.create(**{k: v for k, v in {**SCRATCH, "expl_noise": 0.5}.items() if k in hp_cls.names()})
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
    data, hp = point_dataset(), sac.SACHParams.create()
    base = dataclasses.replace(CFG, steps=200, eval_every=200)
    runs = {}
    official = dataclasses.replace(Fidelity.official(), carry_critic_state=False)  # (no bundle here: random π₀, Q₀)
    for name, fid in (("default", Fidelity()), ("official", official)):
        ft = online.make_finetune(dataclasses.replace(base, fidelity=fid))
        _, m = jax.jit(ft.finetune)(hp, jax.random.PRNGKey(5), None, data)
        runs[name] = np.asarray(m["critic_loss"])
    assert np.all(np.isfinite(runs["official"]))
    assert not np.array_equal(runs["default"], runs["official"])


# ------------------------------------------------------------------------ the official code's policy (FIDELITY row 6)

GNET = NetworkConfig(hidden=(8, 8), policy="gaussian")
OBS = 4  # the point task's observation size


def _gaussian_learner(seed=0):
    nets = make_networks(GNET, 2)
    hp = sac.SACHParams.create(alpha_sac_init=0.2, gamma=0.9)
    lrn = init_learner(jax.random.PRNGKey(seed), nets, agent("sac"), hp, OBS, 2, None)
    # Distinct networks (and a log-std away from its init of 0) so that a swapped argument cannot pass.
    lrn = lrn.replace(actor=perturb(lrn.actor, jax.random.PRNGKey(seed + 1)),
                      critic_target=perturb(lrn.critic, jax.random.PRNGKey(seed + 2)),
                      pibar=perturb(lrn.actor, jax.random.PRNGKey(seed + 3)))
    return nets, hp, lrn


def test_gaussian_policy_parameters_are_state_independent_and_shared_with_td3():
    nets, _, lrn = _gaussian_learner()
    assert lrn.actor["params"]["log_stds"].shape == (2,)
    obs = jax.random.normal(jax.random.PRNGKey(9), (4, OBS))
    mean, log_std = nets.actor.apply(lrn.actor, obs)
    m_ref, l_ref = ref.gaussian_mean_tanh_actor(lrn.actor, np.asarray(obs, np.float64))
    np.testing.assert_allclose(mean, m_ref, atol=1e-6)
    np.testing.assert_allclose(log_std, l_ref, atol=1e-6)
    assert np.all(np.asarray(log_std) == np.asarray(log_std)[0])  # the same std in every state
    det = make_networks(GNET, 2, deterministic=True)
    np.testing.assert_allclose(det.actor.apply(lrn.actor, obs), mean, atol=1e-7)  # TD3 on the same parameters
    big = {"params": {**lrn.actor["params"], "log_stds": jnp.array([7.0, -9.0])}}
    np.testing.assert_array_equal(nets.actor.apply(big, obs)[1][0], [2.0, -5.0])  # hard clip, as the official code


@pytest.mark.parametrize("backup", [True, False])
def test_gaussian_policy_proto_sac_losses_match_numpy(backup):
    """PROTO-SAC with the official policy: the critic sees the unsquashed sample a = tanh(m) + σε, log π and the KL
    are Gaussian densities of a (no Jacobian)."""
    nets, hp, lrn = _gaussian_learner()
    cfg = dataclasses.replace(CFG, net=GNET, value_reg_backup=backup)
    batch = jax.tree.map(lambda x: x[:6], point_dataset())
    key, alpha = jax.random.PRNGKey(7), 1.7
    eps = np.asarray(jax.random.normal(key, (6, 2)), np.float64)
    loss, _ = sac.critic_loss(lrn.critic, lrn, batch, key, alpha, hp, nets, cfg)
    expected = ref.sac_critic_loss(lrn.actor, lrn.critic, lrn.critic_target, lrn.pibar, float(lrn.log_alpha_sac),
                                   batch, eps, alpha, 0.9, backup, True, gaussian=True)
    np.testing.assert_allclose(float(loss), expected, rtol=2e-5)
    a_loss, _ = sac.actor_loss(lrn.actor, lrn.critic, lrn, batch.observations, key, alpha, nets, cfg)
    a_expected = ref.sac_actor_loss(lrn.actor, lrn.critic, lrn.pibar, float(lrn.log_alpha_sac), batch.observations,
                                    eps, alpha, True, gaussian=True)
    np.testing.assert_allclose(float(a_loss), a_expected, rtol=2e-5)


def test_gaussian_policy_acts_clipped_and_fits_clipped_dataset_actions():
    nets, hp, lrn = _gaussian_learner()
    lrn = lrn.replace(actor={"params": {**lrn.actor["params"], "log_stds": jnp.array([1.0, 1.0])}})  # std e
    obs = jax.random.normal(jax.random.PRNGKey(2), (200, OBS))
    a = np.asarray(sac.act(nets, lrn, obs, jax.random.PRNGKey(3), hp, deterministic=False))
    assert a.min() == -1.0 and a.max() == 1.0  # samples leave the box; the env gets them clipped
    mean = ref.gaussian_mean_tanh_actor(lrn.actor, np.asarray(obs, np.float64))[0]
    np.testing.assert_allclose(sac.act(nets, lrn, obs, None, hp, deterministic=True), mean, atol=1e-6)
    batch = jax.tree.map(lambda x: x[:6], point_dataset()).replace(
        actions=jnp.array([[1.0, -1.0], [0.3, 0.2], [-0.99, 0.5], [0.0, 0.0], [1.0, 1.0], [-0.2, -1.0]]))
    w = jnp.linspace(0.5, 2.0, 6)
    loss, _ = weighted_log_likelihood(lrn.actor, nets, batch, w)
    m, ls = ref.gaussian_mean_tanh_actor(lrn.actor, np.asarray(batch.observations, np.float64))
    acts = np.clip(np.asarray(batch.actions, np.float64), -1 + 1e-5, 1 - 1e-5)
    np.testing.assert_allclose(float(loss), -np.mean(np.asarray(w) * ref.normal_logpdf(acts, m, ls)), rtol=2e-5)


# ------------------------------------------------------------- the critic's state across the switch (FIDELITY row 5)


def test_carry_critic_state_takes_the_bundles_adam_and_target():
    nets, hp, lrn = _gaussian_learner()
    hp = hp.replace(lr_critic=jnp.float32(1e-4))
    moved = jax.tree.map(lambda x: x + 0.5, lrn.critic_opt)  # moments, count and learning rate of "pretraining"
    pre = Pretrained(actor=lrn.actor, critic=lrn.critic, critic_target=lrn.critic_target, critic_opt=moved)
    algo = agent("sac")
    carried = init_learner(jax.random.PRNGKey(0), nets, algo, hp, OBS, 2, pre, carry_critic_state=True)
    fresh = init_learner(jax.random.PRNGKey(0), nets, algo, hp, OBS, 2, pre)
    for a, b in zip(jax.tree.leaves(carried.critic_target), jax.tree.leaves(lrn.critic_target)):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(jax.tree.leaves(fresh.critic_target)[0], jax.tree.leaves(lrn.critic_target)[0])
    np.testing.assert_array_equal(carried.critic_opt.inner_state[0].count, moved.inner_state[0].count)
    np.testing.assert_array_equal(jax.tree.leaves(carried.critic_opt.inner_state[0].mu)[0],
                                  jax.tree.leaves(moved.inner_state[0].mu)[0])
    assert float(carried.critic_opt.hyperparams["learning_rate"]) == np.float32(1e-4)  # the finetuning rate
    assert int(fresh.critic_opt.inner_state[0].count) == 0
    with pytest.raises(ValueError, match="carry_critic_state needs a bundle"):
        init_learner(jax.random.PRNGKey(0), nets, algo, hp, OBS, 2, Pretrained(actor=lrn.actor),
                     carry_critic_state=True)


@pytest.mark.slow  # ~1 min of pretraining and finetuning compiles
def test_proto_official_pretrains_and_finetunes_end_to_end(tmp_path):
    """--algo proto-official: an EQL bundle with the official policy and extraction (weight scale 1, z clip 7), then
    finetuning with every official switch, the critic's Adam state carried over."""
    from proto_brax import sweep
    from proto_brax.data.dataset import save_npz

    data = tmp_path / "pt.npz"
    save_npz(data, jax.device_get(point_dataset()), {"env": "point"})
    args = sweep.parse_args(["--preset", "smoke", "--algo", "proto-official", "--seeds", "0", "--tau", "0.005",
                             "--dataset", str(data), "--pretrain", "eql", "--pretrain-steps", "200",
                             "--no-report", "--out", str(tmp_path / "o")])
    assert args.policy == "gaussian" and args.fidelity.carry_critic_state and args.learning_starts == 1
    sweep.run_sweep(args)
    points = json.loads((tmp_path / "o" / "summary.json").read_text())["points"]
    assert points and all(np.isfinite(p["final_normalized_score"]["mean"]) for p in points)
    cfg = json.loads((tmp_path / "o" / "config.json").read_text())
    meta = cfg["checkpoint_metadata"]
    assert meta["net"]["policy"] == "gaussian"
    assert meta["hparams"]["eql_weight_scale"] == 1.0 and meta["hparams"]["eql_z_clip"] == 7.0
    assert cfg["finetune"]["fidelity"]["carry_critic_state"] is True


def test_pretrain_all_makes_a_methods_variant_bundle_with_its_settings():
    """benchmarks/pretrain_all.py --methods proto-official queues eql-official bundles with the method's policy and
    pretraining hyper-parameters (the one place they are written is the method)."""
    from test_results_md import load_module

    pa = load_module("pretrain_all")
    args = pa.Args(algos=(), methods=("proto-official",), envs=("point",), kinds=("medium", "random"))
    (algo, name, extra), = pa.bundle_jobs(args)
    assert (algo, name) == ("eql", "eql-official")
    assert extra == ["--policy", "gaussian", "--hp", "eql_weight_scale", "1", "eql_z_clip", "7"]
    assert [d for d, _, _ in pa.pending(args)] == ["point-medium", "point-random"]  # (no point bundles committed)
