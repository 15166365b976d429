"""Independent NumPy re-implementations of the networks and losses, for equality tests (float64)."""

from __future__ import annotations

import numpy as np


def _np(tree):
    import jax

    return jax.tree.map(lambda x: np.asarray(x, np.float64), tree)


def mlp(p: dict, x: np.ndarray, layer_norm: bool) -> np.ndarray:
    """flax MLP: Dense_i (+ LayerNorm_i) + relu for hidden layers, then the last Dense."""
    dense = sorted((k for k in p if k.startswith("Dense_")), key=lambda k: int(k.split("_")[1]))
    for i, name in enumerate(dense):
        x = x @ p[name]["kernel"] + p[name]["bias"]
        if i < len(dense) - 1:
            if layer_norm:
                ln = p[f"LayerNorm_{i}"]
                mu = x.mean(-1, keepdims=True)
                var = x.var(-1, keepdims=True)
                x = (x - mu) / np.sqrt(var + 1e-6) * ln["scale"] + ln["bias"]
            x = np.maximum(x, 0.0)
    return x


def gaussian_actor(params, obs, log_std_min=-5.0, log_std_max=2.0):
    out = mlp(_np(params)["params"]["MLP_0"], obs, False)
    mean, raw = np.split(out, 2, axis=-1)
    log_std = log_std_min + 0.5 * (log_std_max - log_std_min) * (np.tanh(raw) + 1.0)
    return mean, log_std


def gaussian_mean_tanh_actor(params, obs, log_std_min=-5.0, log_std_max=2.0):
    """The official PROTO code's policy: N(tanh(m(s)), exp(clip(log_stds))) with a state-independent log-std."""
    p = _np(params)["params"]
    mean = np.tanh(mlp(p["MLP_0"], obs, False))
    return mean, np.broadcast_to(np.clip(p["log_stds"], log_std_min, log_std_max), mean.shape)


def det_actor(params, obs):
    """PROTO-TD3's actor: tanh of the Gaussian actor's mean (same parameters)."""
    return np.tanh(gaussian_actor(params, obs)[0])


def critics(params, obs, act, layer_norm=True):
    p = _np(params)["params"]["VmapCritic_0"]["MLP_0"]
    num = next(iter(p.values()))["kernel"].shape[0]
    x = np.concatenate([obs, act], -1)
    return np.stack([mlp({k: {kk: vv[i] for kk, vv in v.items()} for k, v in p.items()}, x, layer_norm)[..., 0]
                     for i in range(num)])


def normal_logpdf(u, mean, log_std):
    return np.sum(-0.5 * ((u - mean) / np.exp(log_std)) ** 2 - log_std - 0.5 * np.log(2 * np.pi), -1)


def tanh_gaussian_logp(u, mean, log_std):
    # log π(tanh u) = log N(u) − Σ log(1 − tanh(u)²): the textbook form (fine in float64 for moderate u)
    return normal_logpdf(u, mean, log_std) - np.sum(np.log(1.0 - np.tanh(u) ** 2), -1)


def sac_critic_loss(actor, critic, critic_target, pibar, log_alpha_sac, batch, eps, alpha, gamma, backup, clip,
                    member=None, gaussian=False):
    """PROTO-SAC's critic loss (Eq. 3); ``member``: without clipping, the one target critic used (official code);
    ``gaussian``: the official code's policy (an unsquashed Gaussian sample and its Gaussian log-density)."""
    s, a, r, s2, d = (np.asarray(getattr(batch, f), np.float64) for f in
                      ("observations", "actions", "rewards", "next_observations", "terminals"))
    actor_fn, logp_fn, squash = _policy(gaussian)
    mean, log_std = actor_fn(actor, s2)
    u = mean + np.exp(log_std) * eps
    logp = logp_fn(u, mean, log_std)
    q_next = critics(critic_target, s2, squash(u))
    q_next = q_next.min(0) if clip else (q_next.mean(0) if member is None else q_next[member])
    v = q_next - np.exp(log_alpha_sac) * logp if backup else q_next  # no backup: no entropy term either
    if backup:
        mb, lb = actor_fn(pibar, s2)
        v = v - alpha * (logp - logp_fn(u, mb, lb))
    y = r + gamma * (1 - d) * v
    q = critics(critic, s, a)
    return np.mean((q - y[None]) ** 2)


def _policy(gaussian: bool):
    """(actor, log-density of the sampled u, u -> critic's action) of the tanh-Gaussian or the official Gaussian."""
    if gaussian:
        return gaussian_mean_tanh_actor, normal_logpdf, lambda u: u
    return gaussian_actor, tanh_gaussian_logp, np.tanh


def sac_actor_loss(actor, critic, pibar, log_alpha_sac, obs, eps, alpha, clip, mean_q=False, gaussian=False):
    """PROTO-SAC's actor loss (Eq. 4); ``mean_q``: the ensemble mean always (official code)."""
    s = np.asarray(obs, np.float64)
    actor_fn, logp_fn, squash = _policy(gaussian)
    mean, log_std = actor_fn(actor, s)
    u = mean + np.exp(log_std) * eps
    logp = logp_fn(u, mean, log_std)
    mb, lb = actor_fn(pibar, s)
    kl = logp - logp_fn(u, mb, lb)
    q = critics(critic, s, squash(u))
    q = q.min(0) if clip and not mean_q else q.mean(0)
    return np.mean(np.exp(log_alpha_sac) * logp + alpha * kl - q)


def td3_critic_loss(actor, actor_target, critic, critic_target, pibar, batch, noise, alpha, gamma, noise_clip, backup,
                    official=False, penalty_mean=False):
    """y = r + γ (1 − d) [min Q̄(s′, clip(π_targ(s′) + clip(ε))) − α ‖π(s′) − π̄(s′)‖²] (PROTO-TD3, paper appendix).

    ``official``: the official code's y = r + γ (1 − d) [min Q̄(s′, π_targ(s′)) − α mean((π(s′) + clip(ε) − π̄(s′))²)],
    the mean over the whole batch and the action dimensions."""
    s, a, r, s2, d = (np.asarray(getattr(batch, f), np.float64) for f in
                      ("observations", "actions", "rewards", "next_observations", "terminals"))
    eps = np.clip(noise, -noise_clip, noise_clip)
    a2 = det_actor(actor_target, s2) if official else np.clip(det_actor(actor_target, s2) + eps, -1, 1)
    v = critics(critic_target, s2, a2).min(0)
    if backup and official:
        v = v - alpha * np.mean((det_actor(actor, s2) + eps - det_actor(pibar, s2)) ** 2)
    elif backup:
        sq = (det_actor(actor, s2) - det_actor(pibar, s2)) ** 2
        v = v - alpha * (sq.mean(-1) if penalty_mean else sq.sum(-1))
    y = r + gamma * (1 - d) * v
    return np.mean((critics(critic, s, a) - y[None]) ** 2)


def td3_actor_loss(actor, critic, pibar, obs, alpha, beta, member=0, penalty_mean=False):
    s = np.asarray(obs, np.float64)
    a = det_actor(actor, s)
    q = critics(critic, s, a)[member]
    lam = beta / np.mean(np.abs(q))
    sq = (a - det_actor(pibar, s)) ** 2
    return np.mean(-lam * q + alpha * (sq.mean(-1) if penalty_mean else sq.sum(-1)))


def temperature_loss(log_alpha_sac, logp, target_entropy, form):
    scale = np.exp(log_alpha_sac) if form == "alpha" else log_alpha_sac
    return scale * np.mean(-np.asarray(logp, np.float64) - target_entropy)


def value_net(params, obs, layer_norm=True):
    return mlp(_np(params)["params"]["MLP_0"], np.asarray(obs, np.float64), layer_norm)[..., 0]


def logp_of_action(actor, obs, action, eps=1e-6):
    """log π(a|s) of a given squashed action, clipped away from ±1 in float32 as the library does (the clip bound
    itself is rounded to float32 there)."""
    mean, log_std = gaussian_actor(actor, np.asarray(obs, np.float64))
    bound = np.float32(1 - eps)
    u = np.arctanh(np.clip(np.asarray(action, np.float32), -bound, bound).astype(np.float64))
    return tanh_gaussian_logp(u, mean, log_std)


def awac_critic_loss(actor, critic, critic_target, batch, eps, gamma):
    s, a, r, s2, d = (np.asarray(getattr(batch, f), np.float64) for f in
                      ("observations", "actions", "rewards", "next_observations", "terminals"))
    mean, log_std = gaussian_actor(actor, s2)
    y = r + gamma * (1 - d) * critics(critic_target, s2, np.tanh(mean + np.exp(log_std) * eps)).min(0)
    return np.mean((critics(critic, s, a) - y[None]) ** 2)


def awac_actor_loss(actor, critic, batch, eps, lam, w_max):
    """−E[log π(a|s) · min(exp((Q(s, a) − Q(s, a_π)) / λ), w_max)], a_π = tanh(mean + std · eps)."""
    s, a = (np.asarray(getattr(batch, f), np.float64) for f in ("observations", "actions"))
    mean, log_std = gaussian_actor(actor, s)
    v = critics(critic, s, np.tanh(mean + np.exp(log_std) * eps)).min(0)
    w = np.minimum(np.exp((critics(critic, s, a).min(0) - v) / lam), w_max)
    return -np.mean(w * logp_of_action(actor, s, a))


def pex_actor_loss(actor, critic_target, value, obs, chosen, beta, w_max):
    """−E[min(exp(β (Q̄(s, a*) − V(s))), w_max) log π(a*|s)] for the composite policy's chosen actions a*."""
    s = np.asarray(obs, np.float64)
    w = np.minimum(np.exp(beta * (critics(critic_target, s, np.asarray(chosen, np.float64)).min(0)
                                  - value_net(value, s))), w_max)
    return -np.mean(w * logp_of_action(actor, s, chosen))


def cql_penalty(critic, actor, batch, a_unif, eps_cur, eps_next, calibrated):
    """Mean over members of E_s[logsumexp over 3N proposals − Q(s, a_data)] (CQL(H) with importance sampling;
    Cal-QL: policy-proposal Q's bounded below by the batch's Monte-Carlo returns). eps_*: [N, B, A] normals."""
    s, a, s2 = (np.asarray(getattr(batch, f), np.float64) for f in ("observations", "actions", "next_observations"))
    parts = []
    q_u = np.stack([critics(critic, s, np.asarray(x, np.float64)) for x in a_unif])  # [N, m, B]
    parts.append(q_u - a.shape[-1] * np.log(0.5))
    for obs, eps in ((s, eps_cur), (s2, eps_next)):
        mean, log_std = gaussian_actor(actor, obs)
        qs = []
        for e in np.asarray(eps, np.float64):
            u = mean + np.exp(log_std) * e
            q = critics(critic, s, np.tanh(u))
            if calibrated:
                q = np.maximum(q, np.asarray(batch.mc_returns, np.float64)[None])
            qs.append(q - tanh_gaussian_logp(u, mean, log_std)[None])
        parts.append(np.stack(qs))
    x = np.concatenate(parts)  # [3N, m, B]
    mx = x.max(0)
    lse = mx + np.log(np.exp(x - mx).sum(0))
    return np.mean(lse - critics(critic, s, a))


def density(params, obs, act):
    x = np.concatenate([np.asarray(obs, np.float64), np.asarray(act, np.float64)], -1)
    return np.maximum(mlp(_np(params)["params"], x, False)[..., 0], 0.0)


def off2on_density_loss(params, off, on):
    w_off, w_on = density(params, off.observations, off.actions), density(params, on.observations, on.actions)
    return np.mean(-np.log(2 / (w_off + 1) + 1e-10)) - np.mean(np.log(2 * w_on / (w_on + 1) + 1e-10))


def mixture(actors_list, obs):
    """Moment-matched Gaussian of several tanh-Gaussian actors' pre-tanh Gaussians (log-std clipped to [-5, 2])."""
    stats = [gaussian_actor(a, np.asarray(obs, np.float64)) for a in actors_list]
    means = np.stack([m for m, _ in stats])
    var = np.mean(means**2 + np.exp(2 * np.stack([s for _, s in stats])), 0) - means.mean(0) ** 2
    return means.mean(0), np.clip(0.5 * np.log(var), -5.0, 2.0)
