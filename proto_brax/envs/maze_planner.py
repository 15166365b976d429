"""Waypoint planning for the AntMaze datasets, as D4RL made them: a goal-reaching ant steered through the maze.

The controller is ``antmaze.AntGoal``'s policy (it sees the ant from the frame pointing at its goal,
``antmaze.rotate_ant_obs``), so steering it only takes the direction of the next waypoint. The planner:
breadth-first search over free cells (4-connected) gives, for every (cell, goal cell) pair, the next cell on a
shortest path; the waypoint is that cell's centre, or the goal itself once in its cell. All of it is a
lookup table, so the controller is a pure jittable function of the observation.
"""

from __future__ import annotations

import collections
import dataclasses
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from proto_brax.envs.antmaze import MAZE_SIZE_SCALING, cell_to_xy, heading_to, rotate_ant_obs


@dataclasses.dataclass(frozen=True, eq=False)
class Planner:
    """Lookup tables of a maze (host numpy, closed over as constants by the jitted controller). Hashed by identity,
    so it can be a static argument of ``jit``."""

    rows: int
    cols: int
    scaling: float
    cell_id: np.ndarray  # [rows, cols] int32: index of each free cell, -1 for walls
    centres: np.ndarray  # [n_free, 2] float32 xy of each free cell
    next_cell: np.ndarray  # [n_free, n_free] int32: next free cell from c towards goal g (c itself when c == g)
    distance: np.ndarray  # [n_free, n_free] int32: BFS distance in cells (-1 unreachable)


def make_planner(layout: Sequence[Sequence], scaling: float = MAZE_SIZE_SCALING) -> Planner:
    """Build the BFS tables of a gymnasium-robotics style map (1 = wall; anything else is free)."""
    rows, cols = len(layout), len(layout[0])
    free = [(i, j) for i in range(rows) for j in range(cols) if layout[i][j] != 1]
    index = {c: k for k, c in enumerate(free)}
    n = len(free)
    distance = np.full((n, n), -1, np.int32)
    next_cell = np.tile(np.arange(n, dtype=np.int32)[:, None], (1, n))
    for g, goal in enumerate(free):  # BFS from each goal; a cell's next step is the neighbour it was reached from
        distance[g, g] = 0
        queue = collections.deque([goal])
        while queue:
            i, j = queue.popleft()
            here = index[(i, j)]
            for nb in ((i - 1, j), (i + 1, j), (i, j - 1), (i, j + 1)):
                k = index.get(nb)
                if k is not None and distance[k, g] < 0:
                    distance[k, g] = distance[here, g] + 1
                    next_cell[k, g] = here
                    queue.append(nb)
    centres = np.stack([cell_to_xy(c, layout, scaling) for c in free]).astype(np.float32)
    cell_id = np.full((rows, cols), -1, np.int32)
    for k, c in enumerate(free):
        cell_id[c] = k
    return Planner(rows, cols, float(scaling), cell_id, centres, next_cell, distance)


def cell_of(planner: Planner, xy: jax.Array) -> jax.Array:
    """Free-cell index of position ``xy`` (gymnasium-robotics' ``cell_xy_to_rowcol``); a position in a wall cell
    (the torso overlaps one at a corner) or off the grid gets the free cell whose centre is nearest."""
    s = planner.scaling
    i = jnp.floor((planner.rows / 2 * s - xy[..., 1]) / s).astype(jnp.int32)
    j = jnp.floor((xy[..., 0] + planner.cols / 2 * s) / s).astype(jnp.int32)
    inside = (i >= 0) & (i < planner.rows) & (j >= 0) & (j < planner.cols)
    k = jnp.where(inside, jnp.asarray(planner.cell_id)[jnp.clip(i, 0, planner.rows - 1),
                                                       jnp.clip(j, 0, planner.cols - 1)], -1)
    nearest = jnp.argmin(jnp.linalg.norm(jnp.asarray(planner.centres) - xy[..., None, :], axis=-1), axis=-1)
    return jnp.where(k >= 0, k, nearest).astype(jnp.int32)


def waypoint(planner: Planner, xy: jax.Array, goal: jax.Array) -> jax.Array:
    """Where to head now: the centre of the next cell on a shortest path to ``goal``, or ``goal`` in its cell."""
    here, target = cell_of(planner, xy), cell_of(planner, goal)
    nxt = jnp.asarray(planner.next_cell)[here, target]
    return jnp.where((here == target)[..., None], goal, jnp.asarray(planner.centres)[nxt])


def controller_obs(planner: Planner, obs: jax.Array, goal: jax.Array) -> jax.Array:
    """The ant-goal controller's 27-dim observation for a maze observation ``[xy, ant state]`` (29): the ant seen
    from the frame pointing at the next waypoint towards ``goal``."""
    xy = obs[..., :2]
    return rotate_ant_obs(obs[..., 2:29], heading_to(xy, waypoint(planner, xy, goal)))
