"""Offline losses (EQL, SQL, IQL, BC, FQE) against NumPy; FQE against a closed-form value; pretraining learns."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference as ref
from helpers import random_batch

from proto_brax import envs
from proto_brax.agents import eql, iql, sql
from proto_brax.agents.bc import bc_loss
from proto_brax.agents.fqe import fqe_loss, fqe_update
from proto_brax.agents.insample import OfflineHParams, init_offline_state, q_to_v_loss, weighted_log_likelihood
from proto_brax.data.dataset import Transition
from proto_brax.networks import NetworkConfig, make_networks
from proto_brax.train.offline import PretrainConfig, make_pretrain, run_pretrain

OBS, ACT, B = 3, 2, 6
NETS = make_networks(NetworkConfig(hidden=(8, 8)), ACT)
HP = OfflineHParams.create(alpha=1.5, expectile=0.8, temperature=2.0, gamma=0.9)


def _batch(seed=0):
    return random_batch(OBS, ACT, seed)


QV = (np.array([1.0, -2.0, 0.5, 3.0, 9.0, -0.1]), np.array([0.5, -1.0, 0.5, -1.0, 0.0, 0.3]))


@pytest.mark.parametrize("z_clip,scale", [(5.0, 10.0), (7.0, 1.0)])  # IVR's code; the official PROTO code's
def test_eql_value_loss_and_weight(z_clip, scale):
    q, v = QV  # (9 − 0)/1.5 = 6 lies between the two clips
    hp = HP.replace(eql_z_clip=jnp.float32(z_clip), eql_weight_scale=jnp.float32(scale))
    z = np.minimum((q - v) / 1.5, z_clip)
    m = max(z.max(), -1.0)
    expected = np.mean(np.exp(z - m) - z * np.exp(-m) - np.exp(-m))
    np.testing.assert_allclose(eql.value_loss(jnp.asarray(q), jnp.asarray(v), hp), expected, rtol=1e-5)
    np.testing.assert_allclose(eql.weight(jnp.asarray(q), jnp.asarray(v), hp),
                               np.minimum(np.exp(scale * (q - v) / 1.5), 100.0), rtol=1e-5)


def test_eql_value_loss_gradient_vanishes_at_q():
    """exp(z) − z − 1 is minimized at z = 0: V = Q is a stationary point when nothing is clipped."""
    q = jnp.array([0.3, -0.2, 0.1])
    g = jax.grad(lambda v: eql.value_loss(q, v, HP))(q)
    np.testing.assert_allclose(g, 0.0, atol=1e-7)


def test_sql_value_loss_and_weight():
    q, v = QV
    u = (q - v) / (2 * 1.5) + 1.0  # IVR: sp_term = (q − v) / (2α) + 1
    expected = np.mean(np.where(u > 0, u**2, 0.0) + v / 1.5)
    np.testing.assert_allclose(sql.value_loss(jnp.asarray(q), jnp.asarray(v), HP), expected, rtol=1e-5)
    np.testing.assert_allclose(sql.weight(jnp.asarray(q), jnp.asarray(v), HP), np.clip(q - v, 0, 100), rtol=1e-6)


def test_iql_expectile_loss_and_weight():
    q, v = QV
    u = q - v
    expected = np.mean(np.where(u < 0, 0.2, 0.8) * u**2)
    np.testing.assert_allclose(iql.value_loss(jnp.asarray(q), jnp.asarray(v), HP), expected, rtol=1e-5)
    np.testing.assert_allclose(iql.weight(jnp.asarray(q), jnp.asarray(v), HP),
                               np.minimum(np.exp(2.0 * u), 100.0), rtol=1e-5)


def test_weighted_log_likelihood_and_bc_match_numpy():
    st = init_offline_state(jax.random.PRNGKey(0), NETS, OBS, ACT, HP)
    batch = _batch()
    w = jnp.linspace(0.0, 3.0, B)
    mean, log_std = ref.gaussian_actor(st.actor, np.asarray(batch.observations, np.float64))
    u = np.arctanh(np.asarray(batch.actions, np.float64))
    logp = ref.tanh_gaussian_logp(u, mean, log_std)
    np.testing.assert_allclose(weighted_log_likelihood(st.actor, NETS, batch, w)[0], -np.mean(np.asarray(w) * logp),
                               rtol=1e-4)
    np.testing.assert_allclose(bc_loss(st.actor, NETS, batch)[0], -np.mean(logp), rtol=1e-4)


def test_q_to_v_and_fqe_losses_match_numpy():
    st = init_offline_state(jax.random.PRNGKey(1), NETS, OBS, ACT, HP)
    batch = _batch(2)
    s, a, r, s2, d = (np.asarray(x, np.float64) for x in (batch.observations, batch.actions, batch.rewards,
                                                           batch.next_observations, batch.terminals))
    vp = jax.tree.map(lambda x: np.asarray(x, np.float64), st.value)["params"]["MLP_0"]
    v2 = ref.mlp(vp, s2, True)[..., 0]
    y = r + 0.9 * (1 - d) * v2
    expected = np.mean((ref.critics(st.critic, s, a) - y[None]) ** 2)
    np.testing.assert_allclose(q_to_v_loss(st.critic, NETS, st.value, batch, HP.gamma)[0], expected, rtol=1e-4)

    key = jax.random.PRNGKey(3)
    mean, log_std = ref.gaussian_actor(st.actor, s2)
    a2 = np.tanh(mean + np.exp(log_std) * np.asarray(jax.random.normal(key, (B, ACT)), np.float64))
    y = r + 0.9 * (1 - d) * ref.critics(st.critic_target, s2, a2).min(0)
    expected = np.mean((ref.critics(st.critic, s, a) - y[None]) ** 2)
    got = fqe_loss(st.critic, st.critic_target, st.actor, NETS, batch, key, HP.gamma)[0]
    np.testing.assert_allclose(got, expected, rtol=1e-4)


def test_fqe_recovers_closed_form_value():
    """Reward r = a₀, policy a′ ≈ tanh(μ) fixed (std e⁻⁵), γ = 0.5: Q^π(s, a) = a₀ + γ tanh(μ₀) / (1 − γ)."""
    nets = make_networks(NetworkConfig(hidden=(32, 32), critic_layer_norm=False), ACT)
    hp = OfflineHParams.create(gamma=0.5, lr_critic=1e-3, target_tau=0.05)
    st = init_offline_state(jax.random.PRNGKey(0), nets, OBS, ACT, hp, with_value=False)
    mu = np.array([0.4, -0.7])
    last = st.actor["params"]["MLP_0"]["Dense_2"]
    last = {"kernel": jnp.zeros_like(last["kernel"]), "bias": jnp.concatenate([jnp.asarray(mu), -1e3 * jnp.ones(2)])}
    actor = {"params": {"MLP_0": {**st.actor["params"]["MLP_0"], "Dense_2": last}}}
    st = st.replace(actor=actor)
    n = 4096
    k = jax.random.split(jax.random.PRNGKey(1), 3)
    data = Transition(
        observations=jax.random.normal(k[0], (n, OBS)), actions=jax.random.uniform(k[1], (n, ACT), minval=-1, maxval=1),
        rewards=jnp.zeros(n), next_observations=jax.random.normal(k[2], (n, OBS)), terminals=jnp.zeros(n),
        timeouts=jnp.zeros(n),
    )
    data = data.replace(rewards=data.actions[:, 0])

    @jax.jit
    def train(st):
        def body(st, key):
            idx = jax.random.randint(key, (256,), 0, n)
            return fqe_update(st, jax.tree.map(lambda x: x[idx], data), key, nets, hp)[0], None

        return jax.lax.scan(body, st, jax.random.split(jax.random.PRNGKey(2), 3000))[0]

    st = train(st)
    truth = np.asarray(data.actions[:512, 0]) + 0.5 * np.tanh(mu[0]) / 0.5
    q = np.asarray(nets.critic.apply(st.critic, data.observations[:512], data.actions[:512]))
    assert np.abs(q - truth[None]).mean() < 0.05, np.abs(q - truth[None]).mean()


@functools.lru_cache(maxsize=None)
def _point_data():
    from test_engine import point_dataset

    return point_dataset()


@pytest.mark.parametrize("algo", ["eql", "iql", "bc", "sql"])
def test_pretraining_learns_point(algo):
    """Each method lowers its loss and extracts a policy far above random on noisy-expert point data."""
    cfg = PretrainConfig(algo=algo, env="point", net=NetworkConfig(hidden=(32, 32)), steps=3000, log_every=1000,
                         batch_size=64, eval_episodes=10)
    pre = make_pretrain(cfg)
    hp = OfflineHParams.create(lr_actor=1e-3, lr_critic=1e-3, lr_value=1e-3, alpha=0.5)
    state, m, returns = run_pretrain(pre, hp, [0, 1], _point_data())
    assert m["critic_loss"].shape == (3, 2)
    own = "bc_loss" if algo == "bc" else "critic_loss"  # FQE tracks a moving policy: BC's loss is BC's objective
    assert np.all(m[own][-1] < m[own][0])
    score = np.asarray(envs.normalized_score("point", returns.mean(-1)))
    assert np.all(score >= 70.0), score


def test_bad_pretrain_config():
    with pytest.raises(ValueError, match="Unknown pretraining algo"):
        PretrainConfig(algo="td3")
    with pytest.raises(ValueError, match="multiple of log_every"):
        PretrainConfig(steps=1000, log_every=300)
    with pytest.raises(ValueError, match="Unknown offline hyper-parameter"):
        OfflineHParams.create(alpah=1.0)


def test_an_interrupted_pretraining_resumes_to_the_uninterrupted_result(tmp_path):
    """A kill after chunk 2 of 3 (here: the callback raises), then a rerun with the same resume directory: the final
    state, the per-chunk metrics and the evaluation equal an uninterrupted run's, bit for bit."""
    cfg = PretrainConfig(algo="eql", env="point", net=NetworkConfig(hidden=(16, 16)), steps=300, log_every=100,
                         batch_size=32, eval_episodes=2)
    pre, hp, data = make_pretrain(cfg), OfflineHParams.create(), _point_data()
    straight, m_straight, r_straight = run_pretrain(pre, hp, [0, 1], data)

    def kill_after_two(c, m):
        if c == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_pretrain(pre, hp, [0, 1], data, callback=kill_after_two, resume=tmp_path)
    ran = []
    resumed, m_resumed, r_resumed = run_pretrain(pre, hp, [0, 1], data, callback=lambda c, m: ran.append(c),
                                                 resume=tmp_path)
    assert ran == [2]  # only the chunk after the last saved one
    for a, b in zip(jax.tree.leaves(straight), jax.tree.leaves(resumed)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    for k in m_straight:
        np.testing.assert_array_equal(np.asarray(m_straight[k]), np.asarray(m_resumed[k]))
    np.testing.assert_array_equal(np.asarray(r_straight), np.asarray(r_resumed))


def test_a_pretraining_resumes_only_from_its_own_configuration(tmp_path, monkeypatch):
    from proto_brax.experiment.pretrain import PretrainArgs, partial_dir

    monkeypatch.setenv("PROTO_BRAX_RUNS", str(tmp_path))
    base = PretrainArgs(dataset="hopper-medium", algo="eql", out=tmp_path / "a")
    here = partial_dir(base, "hash1")
    assert here.parent == tmp_path / "pretrain" and here.name.startswith("hopper-medium-eql-")
    assert partial_dir(PretrainArgs(dataset="hopper-medium", algo="eql", out=tmp_path / "b", overwrite=True),
                       "hash1") == here  # where the bundle goes does not change its numbers
    for other in (PretrainArgs(dataset="hopper-medium", algo="eql", seeds=(1,)),
                  PretrainArgs(dataset="hopper-medium", algo="eql", hp={"alpha": 0.5}),
                  PretrainArgs(dataset="hopper-medium", algo="eql", steps=200_000)):
        assert partial_dir(other, "hash1") != here
    assert partial_dir(base, "hash2") != here  # other data under the same name
