"""AntMaze datasets made the way D4RL made them: a goal-reaching ant steered by a waypoint planner through the maze.

``antmaze-{umaze,medium,large}-{play,diverse}``. The controller is the suite's ``ant-goal`` policy
(``checkpoints/behavior/ant-goal``, SAC from scratch on ``antmaze.AntGoal``): its observation is the ant seen from
the frame pointing at its target, so the planner (``maze_planner``) steers it by pointing it at the next waypoint.
Actions are sampled from the stochastic policy, as for the locomotion datasets.

* **diverse**: every episode starts in a uniformly drawn free cell and the ant is commanded to uniformly drawn free
  cells, a new one each time it reaches one (D4RL: "random goals and starts").
* **play**: starts and commanded goals come from a hand-picked set of cells per maze (D4RL: "hand-picked
  locations"), always including the evaluation start and goal; umaze's set is just those two (D4RL's antmaze-umaze
  commands the ant to the evaluation goal from the evaluation start).

Starts get ``U(±1 m)`` noise per axis around the cell centre (gymnasium-robotics' reset noise), commanded goals
``U(±0.5 m)`` (less, to keep the ant off the walls, as Minari's regeneration did). Episodes last 1000 steps (a
timeout), or end early with a timeout if the ant turns upside down (it cannot right itself; D4RL's data kept such
stuck stretches). Rewards are D4RL's sparse ``1[‖xy′ − g‖ ≤ 0.5]`` against the *evaluation* goal cell's centre ``g``
(the task the data are scored on), and, as in D4RL's antmaze files, ``terminals`` equal those rewards while the
episode goes on. The ant does not stop at the evaluation goal (``terminate_on_success=False``).
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from proto_brax.data.dataset import Transition
from proto_brax.data.partial import run_segments
from proto_brax.envs.antmaze import (
    GOAL_RADIUS,
    MAZE_SIZE_SCALING,
    MAZES,
    AntMaze,
    cell_to_xy,
    maze_map,
    sparse_reward,
    upside_down,
)
from proto_brax.envs.maze_planner import controller_obs, make_planner

KINDS = ("play", "diverse")
EPISODE_LENGTH = 1000
START_NOISE = 0.25 * MAZE_SIZE_SCALING  # ±1 m: gymnasium-robotics' reset noise
GOAL_NOISE = 0.5  # ±0.5 m around a commanded goal cell's centre
CONTROLLER_ENV = "ant-goal"

# Hand-picked play cells (row, column) of gymnasium-robotics' maps: dead ends and junctions spread over each maze,
# always with D4RL's evaluation start and goal.
PLAY_CELLS = {
    "umaze": [(1, 1), (3, 1)],
    "medium": [(1, 1), (1, 6), (3, 3), (4, 6), (6, 1), (6, 6)],
    "large": [(1, 1), (1, 10), (3, 4), (5, 8), (7, 1), (7, 5), (7, 9)],
}


def task_cells(maze: str, kind: str) -> list[tuple[int, int]]:
    """Start / commanded-goal cells of a dataset kind: the play set, or every free cell (diverse)."""
    if kind not in KINDS:
        raise ValueError(f"Unknown AntMaze dataset kind {kind!r}: choose one of {list(KINDS)}.")
    layout = maze_map(maze)
    if kind == "play":
        cells = PLAY_CELLS[maze]
        spec = MAZES[maze]
        assert spec.reset_cell in cells and spec.goal_cell in cells
        assert all(layout[i][j] != 1 for i, j in cells), f"a {maze} play cell is a wall"
        return cells
    return [(i, j) for i, row in enumerate(layout) for j, v in enumerate(row) if v != 1]


def _draw(key: jax.Array, cells_xy: jax.Array, noise: float, xy_now: jax.Array | None = None) -> jax.Array:
    """A cell centre of ``cells_xy`` plus U(±noise) per axis; with ``xy_now``, not the cell the ant is in."""
    logits = jnp.zeros(cells_xy.shape[0])
    if xy_now is not None:
        logits = jnp.where(jnp.linalg.norm(cells_xy - xy_now, axis=-1) < 0.5 * MAZE_SIZE_SCALING, -jnp.inf, 0.0)
    k_c, k_n = jax.random.split(key)
    return cells_xy[jax.random.categorical(k_c, logits)] + jax.random.uniform(k_n, (2,), minval=-noise, maxval=noise)


def fresh_episode(env: AntMaze, cells_xy: jax.Array, eval_goal: jax.Array, key: jax.Array):
    """(env state at a drawn start cell, commanded goal in another cell, step counter 0)."""
    k_start, k_goal, k_env = jax.random.split(key, 3)
    start = _draw(k_start, cells_xy, START_NOISE)
    return env.reset_at(k_env, start, eval_goal), _draw(k_goal, cells_xy, GOAL_NOISE, start), jnp.zeros((), jnp.int32)


def collect_maze(env: AntMaze, planner, cells_xy: jax.Array, eval_goal: jax.Array, policy, params, key: jax.Array,
                 steps: int, episode_length: int, state):
    """``steps`` more transitions of the ants in ``state`` (``vmap(fresh_episode)`` to start): time-major
    ``Transition`` [steps, num_envs] and the state to continue from. ``policy(params, obs27, key) -> action``."""
    num_envs = state[2].shape[0]

    def one(carry, k):
        s, goal, t = carry
        k_act, k_goal, k_reset = jax.random.split(k, 3)
        action = policy(params, controller_obs(planner, s.obs, goal), k_act)
        nxt = env.step(s, action)
        q = nxt.pipeline_state.q
        reward, _ = sparse_reward(q[:2], eval_goal)
        end = (t + 1 >= episode_length) | upside_down(q) | (nxt.done > 0)
        tr = Transition(observations=s.obs, actions=action, rewards=reward, next_observations=nxt.obs,
                        terminals=reward, timeouts=end.astype(jnp.float32))
        goal = jnp.where(jnp.linalg.norm(q[:2] - goal) <= GOAL_RADIUS, _draw(k_goal, cells_xy, GOAL_NOISE, q[:2]),
                         goal)
        carry = jax.tree.map(lambda a, b: jnp.where(end, a, b), fresh_episode(env, cells_xy, eval_goal, k_reset),
                             (nxt, goal, t + 1))
        return carry, tr

    def body(carry, k):
        return jax.vmap(one)(carry, jax.random.split(k, num_envs))

    state, tr = jax.lax.scan(body, state, jax.random.split(key, steps))
    return tr, state


@functools.partial(jax.jit, static_argnums=(0, 3))
def _init(env, cells_xy, eval_goal, num_envs, key):
    return jax.vmap(lambda k: fresh_episode(env, cells_xy, eval_goal, k))(jax.random.split(key, num_envs))


@functools.partial(jax.jit, static_argnums=(0, 1, 4, 7, 8))
def _segment(env, planner, cells_xy, eval_goal, policy, params, key, steps, episode_length, state):
    return collect_maze(env, planner, cells_xy, eval_goal, policy, params, key, steps, episode_length, state)


@functools.lru_cache(maxsize=None)
def data_env(maze: str) -> tuple[AntMaze, object]:
    """The collection env (no termination at the goal) and the maze's planner, one of each per maze, so that the
    compiled segments (static in both) are reused."""
    env = AntMaze(maze, terminate_on_success=False)
    return env, make_planner(env.layout)


def make_antmaze_dataset(maze: str, kind: str, size: int, seed: int, num_envs: int, controller=None,
                         progress: bool = True, episode_length: int = EPISODE_LENGTH, checkpoint: Path | None = None):
    """(numpy ``OfflineDataset``, metadata) of ``antmaze-MAZE-KIND``; deterministic in (maze, kind, size, seed,
    controller). ``controller`` = (snapshot metadata dict, nets, params); default: the last ``ant-goal`` snapshot.
    ``checkpoint``: a directory where the build saves its progress after every segment and from which an
    interrupted build with the same inputs resumes, bit for bit (``proto_brax.data.partial``)."""
    from tqdm import tqdm

    from proto_brax import __version__, envs
    from proto_brax.data import generate as g
    from proto_brax.data.dataset import episode_return_stats
    from proto_brax.data.generate import flatten_env_major

    if size % num_envs:
        raise ValueError(f"size ({size}) must be a multiple of num_envs ({num_envs}).")
    # steps per compiled segment (a progress-bar tick): the largest of these that divides the steps per env
    segment = next(d for d in (500, 250, 200, 100, 50, 25, 20, 10, 5, 2, 1) if (size // num_envs) % d == 0)
    env, planner = data_env(maze)
    layout = env.layout
    if controller is None:
        snap = g.list_snapshots(CONTROLLER_ENV)[-1]
        nets, params = g.load_snapshot_actor(snap, envs.make_env(CONTROLLER_ENV))
        controller = ({"step": snap.step, "eval_return": snap.eval_return}, nets, params)
    info, nets, params = controller
    cells = task_cells(maze, kind)
    cells_xy = jnp.asarray(np.stack([cell_to_xy(c, layout) for c in cells]), jnp.float32)
    eval_goal = jnp.asarray(cell_to_xy(MAZES[maze].goal_cell, layout), jnp.float32)
    policy = g.stochastic_policy(nets)
    key = jax.random.fold_in(jax.random.PRNGKey(seed), KINDS.index(kind))
    fingerprint = {"name": f"antmaze-{maze}-{kind}", "size": size, "seed": seed, "num_envs": num_envs,
                   "episode_length": episode_length, "version": __version__, "controller": info,
                   "controller_params": g.params_hash(params), "xla_flags": os.environ.get("XLA_FLAGS", "")}
    bar = tqdm(total=size, unit="tr", desc=f"antmaze-{maze}-{kind}", disable=not progress, dynamic_ncols=True)
    tr = run_segments(
        size // num_envs // segment, lambda: _init(env, cells_xy, eval_goal, num_envs, jax.random.fold_in(key, 0)),
        lambda i, state: _segment(env, planner, cells_xy, eval_goal, policy, params, jax.random.fold_in(key, i + 1),
                                  segment, episode_length, state),
        checkpoint, fingerprint, tick=lambda: bar.update(segment * num_envs))
    bar.close()
    data = jax.device_get(flatten_env_major(jax.tree.map(jnp.asarray, tr)))
    data = jax.tree.map(lambda x: np.asarray(x, np.float32), data)
    meta = {"name": f"antmaze-{maze}-{kind}", "env": f"antmaze-{maze}", "backend": "mjx", "kind": kind,
            "size": size, "seed": seed, "num_envs": num_envs, "episode_length": episode_length,
            "version": __version__, "cells": [list(c) for c in cells],
            "eval_goal_cell": list(MAZES[maze].goal_cell), "controller": {"env": CONTROLLER_ENV, **info},
            "returns": episode_return_stats(data), "stats": collection_stats(data, episode_length)}
    return data, meta


def collection_stats(data, episode_length: int) -> dict:
    """Episodes, the share that reach the evaluation goal (any reward), and the share cut short (upside down)."""
    rewards = np.asarray(data.rewards)
    ends = np.flatnonzero(np.asarray(data.timeouts) > 0)
    starts = np.concatenate([[0], ends[:-1] + 1])
    reached = np.array([rewards[a:b + 1].any() for a, b in zip(starts, ends)])
    lengths = ends - starts + 1
    return {"episodes": int(ends.size), "success_rate": float(reached.mean()) if ends.size else float("nan"),
            "reward_rate": float(rewards.mean()),
            "cut_short": float(np.mean(lengths < episode_length)) if ends.size else float("nan")}
