"""RLPD (agents/rlpd.py): its losses against NumPy (float64) on distinct networks, its per-env-step schedule (UTD
critic steps, then one actor and temperature step), its random target subset, and learning the point task from a
random init with poor offline data."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference as ref
from helpers import perturb, random_batch

from proto_brax import envs, sweep
from proto_brax.agents import rlpd
from proto_brax.agents.learner import init_learner
from proto_brax.agents.registry import METHODS, agent
from proto_brax.agents.sac import SACHParams
from proto_brax.config import FinetuneConfig
from proto_brax.networks import NetworkConfig, make_networks
from proto_brax.train.online import make_finetune

OBS, ACT, B, E = 4, 2, 6, 4
NET = NetworkConfig(hidden=(8, 8), critic_layer_norm=True, num_qs=E)
NETS = make_networks(NET, ACT)
HP = SACHParams.create(gamma=0.9, alpha_sac_init=0.3)


def _learner(seed=1):
    lrn = init_learner(jax.random.PRNGKey(seed), NETS, agent("rlpd"), HP, OBS, ACT, None)
    # Every network distinct: the target ensemble is not the online one, and its members differ from each other.
    # (a mild actor perturbation: a saturated tanh with σ near e⁻⁵ leaves float32 log-probs 3e-4 off float64)
    return lrn.replace(actor=perturb(lrn.actor, jax.random.PRNGKey(10), 0.1), critic=perturb(lrn.critic,
                       jax.random.PRNGKey(11)), critic_target=perturb(lrn.critic, jax.random.PRNGKey(12)))


def test_target_subset_is_two_distinct_critics_covering_the_ensemble():
    subsets = np.stack([np.asarray(rlpd.target_subset(jax.random.PRNGKey(i), 10)) for i in range(200)])
    assert subsets.shape == (200, 2) and np.all(subsets[:, 0] != subsets[:, 1])
    assert set(subsets.ravel()) == set(range(10))
    assert rlpd.target_subset(jax.random.PRNGKey(0), 1).shape == (1,)  # fewer critics than M: all of them


def test_critic_loss_matches_numpy():
    """y = r + γ(1 − d)[min over the drawn subset of Q̄_j(s′, a′) − α_sac log π(a′|s′)]; loss over all E critics."""
    lrn, batch, key = _learner(), random_batch(OBS, ACT, 0), jax.random.PRNGKey(3)
    loss, _ = rlpd.critic_loss(lrn.critic, lrn, batch, key, HP, NETS)
    k_act, k_subset = jax.random.split(key)
    idx = np.asarray(rlpd.target_subset(k_subset, E))
    eps = np.asarray(jax.random.normal(k_act, (B, ACT)), np.float64)
    s, a, r, s2, d = (np.asarray(getattr(batch, f), np.float64) for f in
                      ("observations", "actions", "rewards", "next_observations", "terminals"))
    mean, log_std = ref.gaussian_actor(lrn.actor, s2)
    u = mean + np.exp(log_std) * eps
    q_next = ref.critics(lrn.critic_target, s2, np.tanh(u))[idx].min(0)
    y = r + 0.9 * (1 - d) * (q_next - 0.3 * ref.tanh_gaussian_logp(u, mean, log_std))
    expected = np.mean((ref.critics(lrn.critic, s, a) - y[None]) ** 2)
    np.testing.assert_allclose(float(loss), expected, rtol=2e-5)
    # the min over the drawn pair, not over the whole ensemble nor one member
    whole = np.mean((ref.critics(lrn.critic, s, a) - (r + 0.9 * (1 - d) * (
        ref.critics(lrn.critic_target, s2, np.tanh(u)).min(0) - 0.3 * ref.tanh_gaussian_logp(u, mean, log_std)))
        [None]) ** 2)
    assert abs(whole - expected) > 1e-4 * abs(expected)


def test_actor_loss_uses_the_mean_of_all_critics():
    lrn, obs, key = _learner(), random_batch(OBS, ACT, 1).observations, jax.random.PRNGKey(4)
    loss, _ = rlpd.actor_loss(lrn.actor, lrn.critic, lrn, obs, key, NETS)
    eps = np.asarray(jax.random.normal(key, (B, ACT)), np.float64)
    mean, log_std = ref.gaussian_actor(lrn.actor, np.asarray(obs, np.float64))
    u = mean + np.exp(log_std) * eps
    q = ref.critics(lrn.critic, np.asarray(obs, np.float64), np.tanh(u)).mean(0)
    expected = np.mean(0.3 * ref.tanh_gaussian_logp(u, mean, log_std) - q)
    np.testing.assert_allclose(float(loss), expected, rtol=2e-5)


def test_utd_critic_steps_then_one_actor_and_temperature_step():
    """UTD 3: the critic and its target move at every update; the actor and α_sac only at the third, with the
    temperature loss α_sac·(H − H̄) (gradient in log α_sac: α_sac·(H − H̄))."""
    cfg = FinetuneConfig(env="point", net=NET, algo="rlpd", updates_per_step=3)
    lrn = _learner()
    update = jax.jit(lambda lrn, b, k, step: rlpd.update(lrn, b, k, jnp.zeros(()), HP, NETS, cfg, step))
    for step in range(3):
        new, m = update(lrn, random_batch(OBS, ACT, step), jax.random.PRNGKey(step), jnp.asarray(step))
        changed = lambda a, b: any(not np.array_equal(x, y) for x, y in  # noqa: E731
                                   zip(jax.tree.leaves(a), jax.tree.leaves(b)))
        assert changed(new.critic, lrn.critic) and changed(new.critic_target, lrn.critic_target)
        last = step == 2
        assert changed(new.actor, lrn.actor) == last and float(m["actor_updates"]) == float(last)
        assert (float(new.log_alpha_sac) != float(lrn.log_alpha_sac)) == last
        if last:  # Adam's first step moves log α_sac by −lr · sign(gradient); gradient = α_sac (H − H̄) > 0 here
            entropy, target = float(m["entropy"]), -0.5 * ACT
            assert np.sign(float(new.log_alpha_sac) - float(lrn.log_alpha_sac)) == -np.sign(entropy - target)
            np.testing.assert_allclose(abs(float(new.log_alpha_sac) - float(lrn.log_alpha_sac)), 3e-4, rtol=1e-3)
        lrn = new


def test_method_defaults_are_rlpds():
    args = sweep.parse_args(["--algo", "rlpd", "--env", "point"])
    assert (args.num_qs, args.updates_per_step, args.critic_layer_norm, args.sampling, args.checkpoint) == (
        10, 20, True, "symmetric", "none")
    assert METHODS["rlpd"].hp == {"alpha_sac_init": 1.0} and not METHODS["rlpd"].regularizer


@pytest.mark.parametrize("utd", [1, 2])
def test_rlpd_learns_point_from_random_init_with_poor_data(utd):
    """From a random init (normalized score near 0) to ≥ 80 in 1600 steps, with near-random offline data."""
    from test_methods import POINT, poor_data

    cfg = dataclasses.replace(POINT, algo="rlpd", sampling="symmetric", regularizer=False, updates_per_step=utd,
                              net=dataclasses.replace(POINT.net, num_qs=4))
    ft = make_finetune(cfg)
    hp = SACHParams.create(lr_actor=1e-3, lr_critic=1e-3, alpha_sac_init=1.0)
    _, m = jax.jit(ft.finetune)(hp, jax.random.PRNGKey(0), None, poor_data())
    score = np.asarray(envs.normalized_score("point", m["eval_return"]))
    assert np.all(np.isfinite(m["critic_loss"])) and score[-1] >= 80.0, score
