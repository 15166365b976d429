"""Vectorized evaluation: many episodes side by side, each to termination or the time limit, inside jit."""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
from jax import lax


def run_episodes(
    env, horizon: int, policy: Callable[[jax.Array, jax.Array], jax.Array], key: jax.Array, episodes: int,
    one_at_a_time: bool = False,
) -> jax.Array:
    """Returns of ``episodes`` episodes; ``policy(obs [n, obs], key) -> actions [n, act]``."""
    return run_episode_stats(env, horizon, policy, key, episodes, one_at_a_time).returns


class EpisodeStats(NamedTuple):
    """Per evaluation episode: return, length (steps up to and including the one that ended it, ``horizon`` if none
    did: on a goal task that terminates at the goal, the steps to the goal) and success steps (steps whose
    ``state.metrics["success"]`` was set, 0 where the env has no such metric: D4RL's ``goal_achieved`` count)."""

    returns: jax.Array
    lengths: jax.Array
    success_steps: jax.Array


def run_episodes_with_lengths(
    env, horizon: int, policy: Callable[[jax.Array, jax.Array], jax.Array], key: jax.Array, episodes: int
) -> tuple[jax.Array, jax.Array]:
    """(returns [episodes], lengths [episodes] int32) of ``run_episode_stats``."""
    return run_episode_stats(env, horizon, policy, key, episodes)[:2]


def run_episode_stats(
    env, horizon: int, policy: Callable[[jax.Array, jax.Array], jax.Array], key: jax.Array, episodes: int,
    one_at_a_time: bool = False,
) -> EpisodeStats:
    """``EpisodeStats`` ([episodes] each; lengths and success steps int32) of ``episodes`` episodes side by side, or
    with ``one_at_a_time`` one after another (``lax.map``; each episode its own batch of one, with the same reset
    and step keys, so a deterministic policy's episodes are the side-by-side ones up to the rounding of batched
    physics; a stochastic policy draws other noise). One at a time is faster where a batched step costs more than
    its episodes' single steps: the MJX hands (``EnvSpec.eval_one_at_a_time``)."""
    k_reset, k_run = jax.random.split(key)
    reset_keys = jax.random.split(k_reset, episodes)
    keys = jax.random.split(k_run, horizon)  # step i's key, however many steps run
    if one_at_a_time:
        # The env steps unbatched (the policy sees a batch of one): a batch-of-one vmap of the physics is slower.
        return lax.map(lambda k: _episodes(env, horizon, lambda o, kk: policy(o[None], kk)[0], k, keys, ()),
                       reset_keys)
    return _episodes(env, horizon, policy, reset_keys, keys, (episodes,))


def _episodes(env, horizon: int, policy, reset_keys: jax.Array, keys: jax.Array, batch: tuple) -> EpisodeStats:
    """Episodes started from ``reset_keys`` side by side (``batch`` ``(n,)``) or one (``()``: the env and the
    statistics unbatched), step i acting with ``keys[i]``."""
    vmap = (lambda f: f) if batch == () else jax.vmap
    s = vmap(env.reset)(reset_keys)

    def success(state) -> jax.Array:  # decided at trace time: Brax's locomotion envs have no success metric
        return state.metrics["success"] > 0 if "success" in state.metrics else jnp.zeros(batch, bool)

    def body(carry):
        i, s, ret, alive, length, wins = carry
        s = vmap(env.step)(s, policy(s.obs, keys[i]))
        ret = ret + jnp.where(alive, s.reward, 0.0)  # where, not multiply: a finished episode may hold NaNs
        length = length + alive.astype(jnp.int32)
        wins = wins + jnp.logical_and(alive, success(s)).astype(jnp.int32)
        return i + 1, s, ret, jnp.logical_and(alive, s.done == 0), length, wins

    # The loop ends when every episode has ended (or at the horizon). A step after that changes no statistic, so the
    # result equals a full-horizon scan's, while policies that fall early cost only their episodes' steps (under a
    # grid's vmap: the steps of the grid's longest episode).
    zeros = jnp.zeros(batch, jnp.int32)
    init = (jnp.zeros((), jnp.int32), s, jnp.zeros(batch), jnp.ones(batch, bool), zeros, zeros)
    _, _, ret, _, length, wins = lax.while_loop(lambda c: (c[0] < horizon) & jnp.any(c[3]), body, init)
    return EpisodeStats(ret, length, wins)
