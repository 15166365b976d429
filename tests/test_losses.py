"""PROTO losses against an independent NumPy computation on fixed tiny parameters (paper Eq. 3–4, TD3 appendix)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference as ref
from helpers import perturb

from proto_brax.agents import proto, sac, td3
from proto_brax.agents.common import polyak, temperature_loss
from proto_brax.agents.learner import init_learner
from proto_brax.agents.registry import agent
from proto_brax.agents.td3 import TD3HParams
from proto_brax.config import FinetuneConfig
from proto_brax.data.dataset import Transition
from proto_brax.fidelity import Fidelity
from proto_brax.networks import NetworkConfig, make_networks, tanh_gaussian_log_prob

OBS, ACT, B = 3, 2, 5
NET = NetworkConfig(hidden=(8, 8), critic_layer_norm=True)


def _setup(algo: str, **cfg_kw):
    cfg = FinetuneConfig(env="point", algo=algo, net=NET, **cfg_kw)
    nets = make_networks(NET, ACT, deterministic=algo == "td3")
    hp_cls = agent(cfg.algo).hparams  # (TD3 has no temperature)
    hp = hp_cls.create(**{k: v for k, v in dict(alpha_sac_init=0.2, gamma=0.9).items() if k in hp_cls.names()})
    lrn = init_learner(jax.random.PRNGKey(0), nets, agent(cfg.algo), hp, OBS, ACT, None)
    # Make every network distinct so that a swapped argument cannot pass.
    lrn = lrn.replace(
        critic_target=perturb(lrn.critic, jax.random.PRNGKey(1)),
        pibar=perturb(lrn.actor, jax.random.PRNGKey(2)),
        actor_target=None if lrn.actor_target is None else perturb(lrn.actor, jax.random.PRNGKey(3)),
    )
    k = jax.random.split(jax.random.PRNGKey(4), 5)
    batch = Transition(
        observations=jax.random.normal(k[0], (B, OBS)),
        actions=jax.random.uniform(k[1], (B, ACT), minval=-0.9, maxval=0.9),
        rewards=jax.random.normal(k[2], (B,)),
        next_observations=jax.random.normal(k[3], (B, OBS)),
        terminals=jnp.array([0.0, 1.0, 0.0, 0.0, 1.0]),
        timeouts=jnp.zeros(B),
    )
    return cfg, nets, hp, lrn, batch


@pytest.mark.parametrize("backup", [True, False])
@pytest.mark.parametrize("clip", [True, False])
def test_sac_critic_loss_matches_numpy(backup, clip):
    cfg, nets, hp, lrn, batch = _setup("sac", value_reg_backup=backup, clipped_double_q=clip)
    key, alpha = jax.random.PRNGKey(7), 1.7
    loss, _ = sac.critic_loss(lrn.critic, lrn, batch, key, alpha, hp, nets, cfg)
    eps = np.asarray(jax.random.normal(key, (B, ACT)), np.float64)
    expected = ref.sac_critic_loss(lrn.actor, lrn.critic, lrn.critic_target, lrn.pibar, float(lrn.log_alpha_sac),
                                   batch, eps, alpha, 0.9, backup, clip)
    np.testing.assert_allclose(float(loss), expected, rtol=2e-5)


@pytest.mark.parametrize("clip", [True, False])
def test_sac_actor_loss_matches_numpy(clip):
    cfg, nets, hp, lrn, batch = _setup("sac", clipped_double_q=clip)
    key, alpha = jax.random.PRNGKey(8), 0.6
    loss, _ = sac.actor_loss(lrn.actor, lrn.critic, lrn, batch.observations, key, alpha, nets, cfg)
    eps = np.asarray(jax.random.normal(key, (B, ACT)), np.float64)
    expected = ref.sac_actor_loss(lrn.actor, lrn.critic, lrn.pibar, float(lrn.log_alpha_sac), batch.observations,
                                  eps, alpha, clip)
    np.testing.assert_allclose(float(loss), expected, rtol=2e-5)


def test_sac_critic_loss_random_target_member_matches_numpy():
    """Fidelity.unclipped_target='random': one target critic, drawn with fold_in(key, 1), replaces the mean."""
    cfg, nets, hp, lrn, batch = _setup("sac", clipped_double_q=False,
                                       fidelity=Fidelity(unclipped_target="random"))
    losses = set()
    for seed in range(6):
        key = jax.random.PRNGKey(20 + seed)
        loss, _ = sac.critic_loss(lrn.critic, lrn, batch, key, 1.1, hp, nets, cfg)
        member = int(jax.random.randint(jax.random.fold_in(key, 1), (), 0, 2))
        eps = np.asarray(jax.random.normal(key, (B, ACT)), np.float64)
        expected = ref.sac_critic_loss(lrn.actor, lrn.critic, lrn.critic_target, lrn.pibar, float(lrn.log_alpha_sac),
                                       batch, eps, 1.1, 0.9, True, False, member=member)
        np.testing.assert_allclose(float(loss), expected, rtol=2e-5)
        losses.add(member)
    assert losses == {0, 1}  # both members are drawn


@pytest.mark.parametrize("clip", [True, False])
def test_sac_actor_loss_mean_q_matches_numpy(clip):
    """Fidelity.actor_q='mean': the actor maximizes the ensemble mean even with clipped double-Q (official code)."""
    cfg, nets, hp, lrn, batch = _setup("sac", clipped_double_q=clip, fidelity=Fidelity(actor_q="mean"))
    key, alpha = jax.random.PRNGKey(8), 0.6
    loss, _ = sac.actor_loss(lrn.actor, lrn.critic, lrn, batch.observations, key, alpha, nets, cfg)
    eps = np.asarray(jax.random.normal(key, (B, ACT)), np.float64)
    expected = ref.sac_actor_loss(lrn.actor, lrn.critic, lrn.pibar, float(lrn.log_alpha_sac), batch.observations,
                                  eps, alpha, clip, mean_q=True)
    np.testing.assert_allclose(float(loss), expected, rtol=2e-5)
    if clip:  # differs from the default on distinct critics
        default = ref.sac_actor_loss(lrn.actor, lrn.critic, lrn.pibar, float(lrn.log_alpha_sac), batch.observations,
                                     eps, alpha, clip)
        assert abs(expected - default) > 1e-4


@pytest.mark.parametrize("form", ["log_alpha", "alpha"])
def test_temperature_loss_forms_match_numpy(form):
    log_alpha, logp = jnp.float32(np.log(0.2)), jnp.array([0.3, -1.2, 0.8, 2.0])
    value, grad = jax.value_and_grad(temperature_loss)(log_alpha, logp, -1.0, form)
    np.testing.assert_allclose(float(value), ref.temperature_loss(np.log(0.2), logp, -1.0, form), rtol=1e-6)
    # d/d log α: (H − H̄) for log α, α (H − H̄) for α: the official form moves log α α-times slower.
    h_gap = float(np.mean(-np.asarray(logp)) + 1.0)
    np.testing.assert_allclose(float(grad), h_gap * (0.2 if form == "alpha" else 1.0), rtol=1e-5)


def test_sac_alpha_zero_is_plain_sac():
    """α = 0: the PROTO terms vanish exactly, whatever π̄ is, and equal SAC without the regularizer."""
    cfg, nets, hp, lrn, batch = _setup("sac", value_reg_backup=True)
    cfg_plain = dataclasses.replace(cfg, regularizer=False)
    key = jax.random.PRNGKey(9)
    other_pibar = lrn.replace(pibar=perturb(lrn.pibar, jax.random.PRNGKey(5), 1.0))
    with_term = sac.critic_loss(lrn.critic, lrn, batch, key, 0.0, hp, nets, cfg)[0]
    assert float(with_term) == float(sac.critic_loss(lrn.critic, other_pibar, batch, key, 0.0, hp, nets, cfg)[0])
    plain = sac.critic_loss(lrn.critic, lrn, batch, key, 0.0, hp, nets, cfg_plain)[0]
    assert float(with_term) == float(plain)
    a_loss = sac.actor_loss(lrn.actor, lrn.critic, lrn, batch.observations, key, 0.0, nets, cfg)[0]
    a_loss2 = sac.actor_loss(lrn.actor, lrn.critic, other_pibar, batch.observations, key, 0.0, nets, cfg)[0]
    assert float(a_loss) == float(a_loss2)


@pytest.mark.parametrize("backup", [True, False])
def test_td3_critic_loss_matches_numpy(backup):
    cfg, nets, hp, lrn, batch = _setup("td3", value_reg_backup=backup)
    key, alpha = jax.random.PRNGKey(10), 1.3
    loss, _ = td3.critic_loss(lrn.critic, lrn, batch, key, alpha, hp, nets, cfg)
    noise = 0.2 * np.asarray(jax.random.normal(key, (B, ACT)), np.float64)
    expected = ref.td3_critic_loss(lrn.actor, lrn.actor_target, lrn.critic, lrn.critic_target, lrn.pibar, batch, noise,
                                   alpha, 0.9, 0.5, backup)
    np.testing.assert_allclose(float(loss), expected, rtol=2e-5)


def test_td3_backup_penalizes_the_current_actor():
    """Zero smoothing noise, three distinct actors (π, π_targ, π̄): the target is the paper's Q̄(s′, π_targ(s′)) −
    α‖π(s′) − π̄(s′)‖². The old backup penalized ‖a′ − π̄(s′)‖² of the target action; it differs here."""
    cfg, nets, _, lrn, batch = _setup("td3")
    hp = TD3HParams.create(gamma=0.9, policy_noise=0.0)
    assert lrn.actor_target is not None
    key, alpha = jax.random.PRNGKey(11), 1.3
    _, info = td3.critic_loss(lrn.critic, lrn, batch, key, alpha, hp, nets, cfg)
    s2 = np.asarray(batch.next_observations, np.float64)
    a_targ = np.clip(ref.det_actor(lrn.actor_target, s2), -1, 1)
    pen = np.sum((ref.det_actor(lrn.actor, s2) - ref.det_actor(lrn.pibar, s2)) ** 2, -1)
    y = (np.asarray(batch.rewards) + 0.9 * (1 - np.asarray(batch.terminals))
         * (ref.critics(lrn.critic_target, s2, a_targ).min(0) - alpha * pen))
    np.testing.assert_allclose(float(info["target_mean"]), y.mean(), rtol=2e-5)
    old_pen = np.sum((a_targ - ref.det_actor(lrn.pibar, s2)) ** 2, -1)
    assert abs(np.mean(0.9 * (1 - np.asarray(batch.terminals)) * alpha * (pen - old_pen))) > 1e-3


@pytest.mark.parametrize("penalty_mean", [False, True])
def test_td3_critic_loss_official_and_mean_penalty_match_numpy(penalty_mean):
    """Fidelity.td3_backup='official' (Q̄ at π_targ(s′) unsmoothed, batch-mean penalty on the noisy current action),
    and the paper's backup with the per-dimension mean penalty."""
    fid = Fidelity(td3_backup="official") if penalty_mean else Fidelity(td3_penalty="mean")
    cfg, nets, hp, lrn, batch = _setup("td3", fidelity=fid)
    key, alpha = jax.random.PRNGKey(12), 1.3
    loss, _ = td3.critic_loss(lrn.critic, lrn, batch, key, alpha, hp, nets, cfg)
    noise = 0.2 * np.asarray(jax.random.normal(key, (B, ACT)), np.float64)
    expected = ref.td3_critic_loss(lrn.actor, lrn.actor_target, lrn.critic, lrn.critic_target, lrn.pibar, batch, noise,
                                   alpha, 0.9, 0.5, True, official=penalty_mean, penalty_mean=not penalty_mean)
    np.testing.assert_allclose(float(loss), expected, rtol=2e-5)


@pytest.mark.parametrize("alpha", [0.0, 2.5])
@pytest.mark.parametrize("member,penalty", [(0, "sum"), (1, "mean")])
def test_td3_actor_loss_matches_numpy(alpha, member, penalty):
    cfg, nets, hp, lrn, batch = _setup("td3", fidelity=Fidelity(td3_actor_critic=member, td3_penalty=penalty))
    loss, _ = td3.actor_loss(lrn.actor, lrn.critic, lrn, batch.observations, alpha, hp, nets, cfg)
    expected = ref.td3_actor_loss(lrn.actor, lrn.critic, lrn.pibar, batch.observations, alpha, 4.0, member=member,
                                  penalty_mean=penalty == "mean")
    np.testing.assert_allclose(float(loss), expected, rtol=2e-5)


def test_td3_exploration_noise_clip():
    """td3_expl_noise_clip bounds the exploration noise (official 0.5); None leaves it unclipped."""
    cfg, nets, _, lrn, _ = _setup("td3")
    obs = jax.random.normal(jax.random.PRNGKey(13), (400, OBS))
    key, hp = jax.random.PRNGKey(14), TD3HParams.create(expl_noise=3.0)
    a = np.asarray(nets.actor.apply(lrn.actor, obs), np.float64)
    eps = 3.0 * np.asarray(jax.random.normal(key, a.shape), np.float64)
    for clip in (0.5, None):
        got = td3.act(nets, lrn, obs, key, hp, deterministic=False, noise_clip=clip)
        bounded = eps if clip is None else np.clip(eps, -clip, clip)
        np.testing.assert_allclose(np.asarray(got), np.clip(a + bounded, -1, 1), atol=1e-6)
    assert np.abs(np.clip(eps, -0.5, 0.5) - eps).max() > 1  # the clip binds on these draws


def test_alpha_schedule_values():
    f = lambda t: float(proto.alpha_schedule(2.0, 0.9, 1e6, 0.0, t))  # noqa: E731
    assert f(0.0) == 2.0
    np.testing.assert_allclose(f(5e5), 2.0 * (1 - 0.45), rtol=1e-6)
    np.testing.assert_allclose(f(1e6), 0.2, rtol=1e-5)
    assert f(1e6 / 0.9 + 1) == 0.0  # reaches 0 at N/η and stays there
    assert f(3e6) == 0.0
    assert float(proto.alpha_schedule(2.0, 0.9, 1e6, 0.5, 1e6)) == 0.5  # floor α_min


def test_polyak_tau_zero_is_bit_exact():
    old = {"w": jnp.array([0.1, -3.0, 7e-8])}
    new = {"w": jnp.array([5.0, 2.0, -1.0])}
    np.testing.assert_array_equal(polyak(new, old, 0.0)["w"], old["w"])
    np.testing.assert_allclose(polyak(new, old, 0.25)["w"], 0.25 * new["w"] + 0.75 * old["w"], rtol=1e-6)


def test_kl_penalty_equals_tanh_gaussian_log_ratio():
    """The Jacobian-free form equals log π(a) − log π̄(a) computed with the full tanh-Gaussian densities."""
    k = jax.random.split(jax.random.PRNGKey(0), 5)
    m, ls, mb, lb = (jax.random.normal(kk, (4, 3)) * 0.5 for kk in k[:4])
    u = m + jnp.exp(ls) * jax.random.normal(k[4], (4, 3))
    a = jnp.tanh(u)
    direct = tanh_gaussian_log_prob(a, m, ls) - tanh_gaussian_log_prob(a, mb, lb)
    np.testing.assert_allclose(proto.kl_penalty(u, m, ls, mb, lb), direct, rtol=1e-3, atol=1e-3)


def test_tanh_log_prob_is_stable_for_large_u():
    from proto_brax.networks import sample_tanh_gaussian

    _, _, logp = sample_tanh_gaussian(jax.random.PRNGKey(0), jnp.full((1, 2), 30.0), jnp.full((1, 2), -5.0))
    assert np.all(np.isfinite(np.asarray(logp)))


def test_sac_update_reports_the_numpy_losses_with_pibar_computed_once():
    """``sac.update`` runs π̄ once on [s′; s] and hands each loss its half: the critic and actor losses it reports
    equal the NumPy references (π̄ at s′ in the backup, at s in the penalty; s and s′ distinct, so a swapped half
    fails). The update splits its key (critic, actor) as ``jax.random.split`` does."""
    cfg, nets, hp, lrn, batch = _setup("sac")
    key, alpha = jax.random.PRNGKey(9), 1.3
    _, info = sac.update(lrn, batch, key, alpha, hp, nets, cfg, jnp.int32(0))
    k_critic, k_actor = jax.random.split(key)
    eps_c = np.asarray(jax.random.normal(k_critic, (B, ACT)), np.float64)
    expected = ref.sac_critic_loss(lrn.actor, lrn.critic, lrn.critic_target, lrn.pibar, float(lrn.log_alpha_sac),
                                   batch, eps_c, alpha, 0.9, True, True)
    np.testing.assert_allclose(float(info["critic_loss"]), expected, rtol=2e-5)
    # The actor's loss is taken against the critic after its step: the same step, from the update's own output.
    critic = sac.actor_critic_step(lrn, lambda c: sac.critic_loss(c, lrn, batch, k_critic, alpha, hp, nets, cfg),
                                   lambda a, c: (jnp.zeros(()), {"log_prob": jnp.zeros(B)}), 0.0, 0.0)[0].critic
    eps_a = np.asarray(jax.random.normal(k_actor, (B, ACT)), np.float64)
    a_expected = ref.sac_actor_loss(lrn.actor, critic, lrn.pibar, float(lrn.log_alpha_sac), batch.observations,
                                    eps_a, alpha, True)
    np.testing.assert_allclose(float(info["actor_loss"]), a_expected, rtol=2e-5)
