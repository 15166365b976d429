"""Vectorized rollouts: run a policy on many envs side by side and collect D4RL-style transitions."""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
from jax import lax

from proto_brax import envs
from proto_brax.data.dataset import Transition

Policy = Callable[[jax.Array, jax.Array], jax.Array]  # (obs [n, obs], key) -> actions [n, act]


def uniform_policy(action_size: int) -> Policy:
    return lambda obs, key: jax.random.uniform(key, (obs.shape[0], action_size), minval=-1.0, maxval=1.0)


def collect(env, episode_length: int, policy: Policy, key: jax.Array, num_envs: int, steps: int):
    """Run ``num_envs`` envs for ``steps`` steps each (auto-reset, time-limit truncation recorded as ``timeouts``).

    Returns (transitions ordered env-major so each env's episodes stay contiguous, finished episode returns with a
    validity mask). Jit it with ``policy``, ``num_envs`` and ``steps`` static.
    """
    k_reset, k_run = jax.random.split(key)
    state = jax.vmap(lambda k: envs.env_reset(env, k))(jax.random.split(k_reset, num_envs))

    def body(state, k):
        k_act, k_env = jax.random.split(k)
        action = policy(state.brax_state.obs, k_act)
        state, tr, done, ret = jax.vmap(lambda s, a, kk: envs.env_step(env, episode_length, s, a, kk))(
            state, action, jax.random.split(k_env, num_envs)
        )
        return state, (tr, done, ret)

    state, (tr, done, ret) = lax.scan(body, state, jax.random.split(k_run, steps))
    # The last transition of every env is cut by the end of collection: mark it as a timeout (no true successor
    # follows it in the array), as D4RL does for its final rows.
    tr = tr.replace(timeouts=tr.timeouts.at[-1].set(jnp.where(tr.terminals[-1] > 0, 0.0, 1.0)))
    flat = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1).reshape((num_envs * steps,) + x.shape[2:]), tr)
    return flat, ret.T.reshape(-1), done.T.reshape(-1) > 0
