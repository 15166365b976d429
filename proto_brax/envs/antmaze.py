"""D4RL AntMaze (umaze / medium / large) as a Brax ``PipelineEnv`` on the MJX backend.

What is reproduced, and from where:

* **Maps** are gymnasium-robotics' ``U_MAZE``, ``MEDIUM_MAZE`` and ``LARGE_MAZE`` (the D4RL layouts), scaled by
  ``maze_size_scaling = 4`` with walls of height ``0.5 * 4``. Those maps carry no reset/goal cells, so the D4RL
  *evaluation* cells (D4RL's ``U_MAZE_TEST``, ``BIG_MAZE_TEST``, ``HARDEST_MAZE_TEST``) are placed on them:
  reset (1, 1) in all three, goal (3, 1) umaze, (6, 6) medium, (7, 9) large.
* **Coordinates** follow gymnasium-robotics (``Maze.cell_rowcol_to_xy``): the maze is centred on the origin,
  ``x = (j + 0.5) s - W s / 2``, ``y = H s / 2 - (i + 0.5) s``. D4RL placed cell ``(i, j)`` at
  ``(j s, i s) - reset cell``: y grows with the row index, so D4RL's physical maze is the *mirror image* (in y) of this
  one, and D4RL-v2 transitions would need a reflection of the whole ant state, not just an xy shift. Minari's
  regenerated antmaze datasets were collected with gymnasium-robotics and are in this frame.
* **Ant** is gymnasium's ``ant.xml`` (the one gymnasium-robotics' ``AntMaze_*-v5`` loads), RK4, timestep 0.01,
  ``frame_skip = 5`` so one control step is 0.05 s, starting from the model's ``qpos0`` (torso at z = 0.75).
  Walls are one box per wall cell exactly as ``maze_v4.Maze.make_maze`` writes them (same positions, sizes,
  ``contype = conaffinity = 1``).
* **Reset** follows ``maze_v4.MazeEnv.reset``: the goal is a uniformly chosen goal cell (``'g'`` or ``'c'``; every
  empty cell when the map has none), the ant a uniformly chosen reset cell (``'r'`` or ``'c'``) other than the goal's
  cell; both cell centres get independent uniform noise of ``±0.25 * 4`` m per axis. On top, the ant's joints get
  gymnasium ``Ant`` reset noise (``qpos[2:] += U(±c)``, ``qvel += c N(0, 1)``, ``c = reset_noise_scale``, 0.1 by
  default as gymnasium's Ant and D4RL's ant). gymnasium-robotics v5 builds its ant with ``reset_noise_scale = 0``;
  pass ``reset_noise_scale=0.0`` to reproduce it exactly.
* **Reward** is D4RL's sparse ``1[‖xy − goal‖ ≤ 0.5]`` (gymnasium-robotics uses 0.45; D4RL's scores use 0.5),
  computed on the state after the step. Reaching the goal **terminates** the episode (``terminate_on_success``, the
  default): D4RL registers its antmaze tasks with ``eval=True``, whose ``step`` ends the episode at the goal, and
  PROTO's and IQL's online runs use those envs, so a return is 0 or 1 (the success flag) and the episode length is
  the steps to the goal (the paper's Figure 5). D4RL *collected* its datasets without it (the planner keeps going,
  timeouts every 1000 steps): ``terminate_on_success=False``, as gymnasium-robotics' ``continuing_task=True``. The
  time limits are D4RL's (700 umaze, 1000 medium/large; the registry holds them). ``done`` is also 1 if the physics
  state stops being finite, so a blown-up simulation ends its episode instead of poisoning a replay buffer.
  ``metrics["success"]`` repeats the reward as the success flag evaluations read.

**Observation layout** (29 dims, ``goal_in_obs=False``)::

    [x, y]  (2)  achieved goal = torso xy         = qpos[0:2]
    qpos[2:15]  (13)  torso z, quaternion, 8 joint angles
    qvel[0:14]  (14)  torso linear/angular velocity, 8 joint velocities

This is D4RL's flat antmaze observation (``concat(qpos[:15], qvel[:14])``, 29 dims), which is also
gymnasium-robotics' dict observation flattened as ``[achieved_goal, observation]`` with
``include_cfrc_ext_in_observation=False`` (its ``observation`` is ``qpos[2:] ++ qvel``, 27 dims). D4RL's observation
does **not** contain the goal: its evaluation goal is one fixed cell, so a policy trained on D4RL data has never seen
a goal input. Offline-to-online finetuning starts from those datasets, so the default keeps their layout;
``goal_in_obs=True`` appends the desired goal xy (31 dims, gymnasium-robotics' ``desired_goal``) for goal-conditioned
use. The goal is always in ``state.info["goal"]``.

**Speed and fidelity on MJX** (measured on the project's 2-core CPU, 2026-11-23; the machine was shared, so
speeds are ±30%). MJX evaluates every candidate (ant geom, wall box) pair with a fixed shape each step (13 x 62
pairs in the large maze), so the MJCF bounds contacts with MJX's custom numerics ``max_geom_pairs`` (broad phase:
keep the nearest pairs per collision-function group) and ``max_contact_points`` (keep the deepest contacts per condim
group); native MuJoCo ignores them. mujoco-mjx 3.17 reads a numeric as ``numeric_data[id]`` (by index, not through
``numeric_adr``), so these two must be the first entries of ``<custom>``. Unbounded, umaze ran 20 control steps/s at
batch 1 against 130 bounded. Only the torso and the four lower-leg capsules collide (``upper_leg_contacts=False``):
the upper-leg capsules sit inside the ankles' reach, and in native MuJoCo switching them off moved the torso by
at most 1 cm over 60 random-action steps, while MJX went from 130 to 290 steps/s at batch 1. The solver caps are
discussed at ``SOLVER_ITERATIONS``. Result (``benchmarks/antmaze_speed.py``): 240 control steps/s at batch 1 and
425 at batch 128 (all envs together), against 2500 for one native gymnasium-robotics env on one thread. On this CPU
even 128 batched MJX envs are ~6x slower than one native env; MJX's batch advantage needs an accelerator.

Two MJX 3.17 limitations make contacts differ from native MuJoCo 4.0 (tests/test_antmaze.py measures the effect):
the friction pyramid of a plane-capsule contact is world-aligned in MJX but turned about the normal in MuJoCo 4.0, and
MJX's box-capsule collider reports only penetrating contacts, so the 0.02 m contact margin is ignored against walls.
"""

from __future__ import annotations

import dataclasses
import os
import xml.etree.ElementTree as ET
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import PipelineEnv, State
from brax.io import mjcf

MAZE_SIZE_SCALING = 4.0  # D4RL / gymnasium-robotics AntMaze maze_size_scaling
MAZE_HEIGHT = 0.5  # gymnasium-robotics maze_height (walls are MAZE_HEIGHT * MAZE_SIZE_SCALING tall)
POSITION_NOISE = 0.25  # gymnasium-robotics position_noise_range, times the scaling
GOAL_RADIUS = 0.5  # D4RL antmaze sparse reward radius
FRAME_SKIP = 5  # gymnasium Ant frame_skip: control dt = 5 * 0.01 s

# MJX contact bounds and solver caps. Measured on the 2-core CPU (umaze, batch 128, 40 random-action steps from 128
# resets, 2026-11-23): Newton 8 / line search 8 reproduced the 100 / 50 trajectories exactly (every env, xy error 0)
# at 2.6x the speed (616 vs 239 control steps/s); 4 / 8 ran 785 steps/s but drifted (median xy error 0.44 m after
# 40 steps, as large as the median displacement, 0.84 m): the solver had not converged. MJX solves in float32, where
# the default tolerance 1e-8 is never met, so the caps are also the iteration counts actually run.
MAX_GEOM_PAIRS = 8
MAX_CONTACT_POINTS = 16
SOLVER_ITERATIONS = 8
LS_ITERATIONS = 8

RESET, GOAL, COMBINED = "r", "g", "c"  # gymnasium-robotics cell markers (maps.RESET / GOAL / COMBINED)


@dataclasses.dataclass(frozen=True)
class MazeSpec:
    """A named D4RL maze: gymnasium-robotics' layout plus D4RL's evaluation reset and goal cells (row, column)."""

    layout_name: str  # attribute of gymnasium_robotics.envs.maze.maps
    reset_cell: tuple[int, int]
    goal_cell: tuple[int, int]


# D4RL's evaluation maps (U_MAZE_TEST, BIG_MAZE_TEST, HARDEST_MAZE_TEST) are these layouts with one 'r' and one 'g'.
MAZES: dict[str, MazeSpec] = {
    "umaze": MazeSpec("U_MAZE", reset_cell=(1, 1), goal_cell=(3, 1)),
    "medium": MazeSpec("MEDIUM_MAZE", reset_cell=(1, 1), goal_cell=(6, 6)),
    "large": MazeSpec("LARGE_MAZE", reset_cell=(1, 1), goal_cell=(7, 9)),
}


def maze_map(maze: str) -> list[list[int | str]]:
    """gymnasium-robotics' map for a named maze with D4RL's evaluation 'r' and 'g' cells marked."""
    if maze not in MAZES:
        raise ValueError(f"Unknown maze {maze!r}: choose one of {sorted(MAZES)}.")
    from gymnasium_robotics.envs.maze import maps

    spec = MAZES[maze]
    layout = [list(row) for row in getattr(maps, spec.layout_name)]
    for cell, mark in ((spec.reset_cell, RESET), (spec.goal_cell, GOAL)):
        i, j = cell
        if layout[i][j] != 0:
            raise ValueError(f"{maze}: cell {cell} is not free in {spec.layout_name}")
        layout[i][j] = mark
    return layout


def cell_to_xy(cell: Sequence[int], layout: Sequence[Sequence], scaling: float = MAZE_SIZE_SCALING) -> np.ndarray:
    """Cell ``(i, j)`` -> centre ``(x, y)``, as gymnasium-robotics' ``Maze.cell_rowcol_to_xy``."""
    length, width = len(layout), len(layout[0])
    x = (cell[1] + 0.5) * scaling - width / 2 * scaling
    y = length / 2 * scaling - (cell[0] + 0.5) * scaling
    return np.array([x, y])


def xy_to_cell(xy: Sequence[float], layout: Sequence[Sequence], scaling: float = MAZE_SIZE_SCALING) -> np.ndarray:
    """``(x, y)`` -> cell ``(i, j)``, as gymnasium-robotics' ``Maze.cell_xy_to_rowcol``."""
    length, width = len(layout), len(layout[0])
    i = np.floor((length / 2 * scaling - xy[1]) / scaling)
    j = np.floor((xy[0] + width / 2 * scaling) / scaling)
    return np.array([i, j], dtype=int)


def reset_and_goal_cells(layout: Sequence[Sequence]) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """Candidate (reset cells, goal cells) with gymnasium-robotics' ``Maze.make_maze`` rules.

    'r' cells are reset cells, 'g' goal cells, 'c' both. With no marked cell at all, every empty cell is both; with
    no reset ('r'/'c') cell every empty cell is a reset cell; likewise for goals.
    """
    cells = {mark: [] for mark in (RESET, GOAL, COMBINED, 0)}
    for i, row in enumerate(layout):
        for j, v in enumerate(row):
            if v in cells:
                cells[v].append((i, j))
    resets, goals, combined, empty = cells[RESET], cells[GOAL], cells[COMBINED], cells[0]
    if not resets and not goals and not combined:
        combined = empty
    elif not resets and not combined:
        resets = empty
    elif not goals and not combined:
        goals = empty
    return resets + combined, goals + combined


def ant_xml_path() -> str:
    """gymnasium's ``ant.xml``, the model gymnasium-robotics' AntMaze v5 builds its maze around."""
    from gymnasium.envs.mujoco import ant_v5

    return os.path.join(os.path.dirname(ant_v5.__file__), "assets", "ant.xml")


def maze_xml(
    layout: Sequence[Sequence],
    *,
    max_geom_pairs: int | None = MAX_GEOM_PAIRS,
    max_contact_points: int | None = MAX_CONTACT_POINTS,
    solver_iterations: int | None = SOLVER_ITERATIONS,
    ls_iterations: int | None = LS_ITERATIONS,
    solver_tolerance: float | None = None,
    integrator: str = "RK4",
    upper_leg_contacts: bool = False,
) -> str:
    """MJCF of the ant in a maze: gymnasium's ant.xml plus one box per wall cell, as gymnasium-robotics builds it.

    Boxes: centre of the cell at height ``h s / 2``, half-sizes ``(s / 2, s / 2, h s / 2)``, ``contype =
    conaffinity = 1`` (``maze_v4.Maze.make_maze``). ``None`` leaves a contact bound or solver setting at MuJoCo's
    default; with all four ``None`` and ``upper_leg_contacts=True`` the physics is gymnasium-robotics' model exactly
    (``integrator`` "RK4" is ant.xml's own; "Euler" is there only to measure what it would save). The MJX contact
    numerics are inserted as the first ``<custom>`` entries (mjx 3.17 reads numerics by index).
    """
    root = ET.parse(ant_xml_path()).getroot()
    if not upper_leg_contacts:
        for geom in root.iter("geom"):
            name = geom.get("name", "")
            if name.startswith("aux_") or name.endswith("_leg_geom"):
                geom.set("contype", "0")
    worldbody = root.find("worldbody")
    s, h = MAZE_SIZE_SCALING, MAZE_HEIGHT
    for i, row in enumerate(layout):
        for j, v in enumerate(row):
            if v == 1:
                x, y = cell_to_xy((i, j), layout, s)
                ET.SubElement(
                    worldbody,
                    "geom",
                    name=f"block_{i}_{j}",
                    pos=f"{x} {y} {h / 2 * s}",
                    size=f"{0.5 * s} {0.5 * s} {h / 2 * s}",
                    type="box",
                    contype="1",
                    conaffinity="1",
                    rgba="0.7 0.5 0.3 1.0",
                )
    custom = root.find("custom")
    if custom is None:
        custom = ET.SubElement(root, "custom")
    # ant.xml's legacy ``init_qpos`` numeric (torso z 0.55, ankles at ±1 rad) is read by brax as its initial pose, but
    # gymnasium's Ant and gymnasium-robotics start from the model's qpos0 (torso z 0.75, joints 0): drop it.
    for numeric in custom.findall("numeric"):
        if numeric.get("name") == "init_qpos":
            custom.remove(numeric)
    bounds = [("max_contact_points", max_contact_points), ("max_geom_pairs", max_geom_pairs)]
    for name, value in bounds:
        if value is not None:
            custom.insert(0, ET.Element("numeric", name=name, data=str(int(value))))
    option = root.find("option")
    option.set("integrator", integrator)
    if solver_iterations is not None:
        option.set("iterations", str(int(solver_iterations)))
    if ls_iterations is not None:
        option.set("ls_iterations", str(int(ls_iterations)))
    if solver_tolerance is not None:
        option.set("tolerance", repr(float(solver_tolerance)))
    return ET.tostring(root, encoding="unicode")


def sparse_reward(xy: jax.Array, goal: jax.Array) -> tuple[jax.Array, jax.Array]:
    """D4RL antmaze reward ``1[‖xy − goal‖ ≤ 0.5]`` and the distance; NaN xy gives reward 0."""
    dist = jnp.linalg.norm(xy - goal, axis=-1)
    return (dist <= GOAL_RADIUS).astype(jnp.float32), dist


def sample_start_and_goal(
    key: jax.Array, reset_xy: jax.Array, goal_xy: jax.Array, scaling: float = MAZE_SIZE_SCALING
) -> tuple[jax.Array, jax.Array]:
    """Draw ``(start xy, goal xy)`` as gymnasium-robotics' ``MazeEnv.reset`` does, from cell centres ``(n, 2)``.

    The goal is a uniform goal cell plus ``U(±0.25 s)`` per axis. gymnasium-robotics then redraws the reset cell while
    its centre lies within ``0.5 s`` of the noisy goal, i.e. while it is the goal's own cell; drawing uniformly from
    the other cells is the same distribution without a loop. The start gets its own ``U(±0.25 s)`` noise.
    """
    k_goal, k_goal_noise, k_start, k_start_noise = jax.random.split(key, 4)
    noise = POSITION_NOISE * scaling
    goal = goal_xy[jax.random.randint(k_goal, (), 0, goal_xy.shape[0])]
    goal = goal + jax.random.uniform(k_goal_noise, (2,), minval=-noise, maxval=noise)
    allowed = jnp.linalg.norm(reset_xy - goal, axis=-1) > 0.5 * scaling
    start = reset_xy[jax.random.categorical(k_start, jnp.where(allowed, 0.0, -jnp.inf))]
    start = start + jax.random.uniform(k_start_noise, (2,), minval=-noise, maxval=noise)
    return start, goal


class AntMaze(PipelineEnv):
    """D4RL AntMaze on Brax's MJX pipeline (see the module docstring for every choice and its source).

    ``maze`` is a name of ``MAZES`` ("umaze", "medium", "large") or a gymnasium-robotics style map (list of rows of
    0 / 1 / 'r' / 'g' / 'c'). ``reset_noise_scale`` is the ant's joint reset noise (0 = gymnasium-robotics v5).
    ``goal_in_obs`` appends the goal xy to the observation. ``terminate_on_success`` ends the episode at the goal
    (D4RL's evaluation tasks; off to collect data). Other keyword arguments (contact bounds, solver caps) go to
    ``maze_xml``.
    """

    def __init__(
        self,
        maze: str | Sequence[Sequence] = "umaze",
        backend: str = "mjx",
        reset_noise_scale: float = 0.1,
        goal_in_obs: bool = False,
        terminate_on_success: bool = True,
        **xml_kwargs,
    ):
        if backend != "mjx":
            raise ValueError(f"AntMaze runs on the mjx backend only (RK4 integrator), not {backend!r}.")
        layout = maze_map(maze) if isinstance(maze, str) else [list(r) for r in maze]
        resets, goals = reset_and_goal_cells(layout)
        if not goals or any(set(resets) <= {g} for g in goals):
            raise ValueError("The maze needs a goal cell and, for every goal cell, a different reset cell.")
        sys = mjcf.loads(maze_xml(layout, **xml_kwargs))
        super().__init__(sys=sys, backend=backend, n_frames=FRAME_SKIP)
        self.layout = layout
        self._reset_xy = jnp.asarray(np.stack([cell_to_xy(c, layout) for c in resets]), jnp.float32)
        self._goal_xy = jnp.asarray(np.stack([cell_to_xy(c, layout) for c in goals]), jnp.float32)
        self._reset_noise_scale = reset_noise_scale
        self._goal_in_obs = goal_in_obs
        self._terminate_on_success = terminate_on_success

    def reset(self, rng: jax.Array) -> State:
        k_cells, k_ant = jax.random.split(rng)
        xy, goal = sample_start_and_goal(k_cells, self._reset_xy, self._goal_xy)
        return self.reset_at(k_ant, xy, goal)

    def reset_at(self, rng: jax.Array, xy: jax.Array, goal: jax.Array) -> State:
        """A fresh episode with the torso at ``xy`` and the goal at ``goal`` (dataset collection picks its own)."""
        pipeline_state = self._ant_at(rng, xy)
        reward, dist = sparse_reward(pipeline_state.q[:2], goal)
        zero = jnp.zeros(())
        metrics = {"success": reward, "goal_distance": dist}
        return State(pipeline_state, self._obs(pipeline_state, goal), reward, zero, metrics, {"goal": goal})

    def _ant_at(self, rng: jax.Array, xy: jax.Array):
        """Physics state with the torso at ``xy`` and gymnasium Ant's reset noise on the rest of qpos and on qvel."""
        k_q, k_qd = jax.random.split(rng)
        c = self._reset_noise_scale
        q_rest = self.sys.init_q[2:] + jax.random.uniform(k_q, (self.sys.q_size() - 2,), minval=-c, maxval=c)
        qvel = c * jax.random.normal(k_qd, (self.sys.qd_size(),))
        return self.pipeline_init(jnp.concatenate([xy, q_rest]), qvel)

    def step(self, state: State, action: jax.Array) -> State:
        pipeline_state = self.pipeline_step(state.pipeline_state, action)
        goal = state.info["goal"]
        reward, dist = sparse_reward(pipeline_state.q[:2], goal)
        finite = is_finite(pipeline_state)
        done = 1.0 - finite.astype(jnp.float32)
        if self._terminate_on_success:
            done = jnp.maximum(done, reward)
        # A blown-up state ends the episode; zeroing its observation keeps the terminal transition finite (its next
        # observation is never bootstrapped from, but NaN * 0 would still poison a critic target).
        obs = jnp.where(finite, self._obs(pipeline_state, goal), 0.0)
        metrics = {**state.metrics, "success": reward, "goal_distance": dist}
        return state.replace(pipeline_state=pipeline_state, obs=obs, reward=reward, done=done, metrics=metrics)

    def _obs(self, pipeline_state, goal: jax.Array) -> jax.Array:
        parts = [pipeline_state.q, pipeline_state.qd]  # = [xy, qpos[2:], qvel]: D4RL's 29-dim layout
        if self._goal_in_obs:
            parts.append(goal)
        return jnp.concatenate(parts)

    @property
    def observation_size(self) -> int:
        return self.sys.q_size() + self.sys.qd_size() + (2 if self._goal_in_obs else 0)


# ------------------------------------------------------------------------------------------------------------------
# Goal reaching on the open floor: the low-level controller of the AntMaze datasets
# ------------------------------------------------------------------------------------------------------------------


def ant_yaw(quat: jax.Array) -> jax.Array:
    """Yaw (rotation about world z) of a (w, x, y, z) quaternion."""
    w, x, y, z = quat[..., 0], quat[..., 1], quat[..., 2], quat[..., 3]
    return jnp.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def upside_down(q: jax.Array) -> jax.Array:
    """The torso's z axis points down (its world z component, 1 − 2(qx² + qy²) of the qpos quaternion, is < 0)."""
    return 1.0 - 2.0 * (q[..., 4] ** 2 + q[..., 5] ** 2) < 0.0


def is_finite(pipeline_state) -> jax.Array:
    return jnp.all(jnp.isfinite(pipeline_state.q)) & jnp.all(jnp.isfinite(pipeline_state.qd))


def heading_to(xy: jax.Array, target: jax.Array) -> jax.Array:
    d = target - xy
    return jnp.arctan2(d[..., 1], d[..., 0])


def rotate_ant_obs(obs: jax.Array, theta: jax.Array) -> jax.Array:
    """Ant observation ``qpos[2:15] ++ qvel[0:14]`` (27) as seen from a frame turned by ``theta`` about z.

    The floor is flat, so the ant's dynamics do not depend on its heading: in the turned frame, "towards angle θ" is
    +x. Two parts change: the torso quaternion is pre-multiplied by R(−θ), and the world-frame linear velocity
    ``qvel[0:3]`` is turned by R(−θ). The free joint's angular velocity ``qvel[3:6]`` is in the torso's own frame
    (MuJoCo's convention) and the joint angles are body-relative, so they stay as they are.
    """
    half = -0.5 * theta
    rw, rz = jnp.cos(half), jnp.sin(half)  # R(−θ) as the quaternion (rw, 0, 0, rz)
    w, x, y, z = obs[..., 1], obs[..., 2], obs[..., 3], obs[..., 4]
    quat = jnp.stack([rw * w - rz * z, rw * x - rz * y, rw * y + rz * x, rw * z + rz * w], -1)  # R(−θ) ⊗ q
    c, s = jnp.cos(theta), jnp.sin(theta)
    vx, vy = obs[..., 13], obs[..., 14]
    vel = jnp.stack([c * vx + s * vy, -s * vx + c * vy], -1)
    return jnp.concatenate([obs[..., :1], quat, obs[..., 5:13], vel, obs[..., 15:]], -1)


class AntGoal(AntMaze):
    """Goal reaching with AntMaze's ant and physics on an open floor: the controller the AntMaze datasets steer.

    D4RL made its AntMaze data with a goal-reaching ant driven by a waypoint planner; this is the task that ant
    learns here (SAC from scratch, ``python -m proto_brax.data.behavior --env ant-goal``). Goals are drawn at
    ``goal_distance`` (uniform range, metres) in a uniform direction from the ant; reaching one (0.5 m, as AntMaze)
    draws the next from where the ant is, so an episode holds several and the ant learns to turn. The observation is
    the ant's 27-dim state seen from the frame whose +x points at the goal (``rotate_ant_obs``), which is all the
    maze planner then needs to supply: the direction of the next waypoint. Reward (gymnasium Ant's terms, with
    progress in place of forward velocity): velocity towards the goal + 1 while healthy − 0.5 ‖a‖²; the episode ends
    when the torso leaves z ∈ [0.2, 1.0] or turns upside down (gymnasium's z test alone lets a flipped ant, torso at
    0.27 m, count as healthy).
    """

    def __init__(self, backend: str = "mjx", goal_distance: tuple[float, float] = (2.0, 6.0),
                 reset_noise_scale: float = 0.1, **xml_kwargs):
        super().__init__([[0] * 3 for _ in range(3)], backend=backend, reset_noise_scale=reset_noise_scale,
                         terminate_on_success=False, **xml_kwargs)  # no wall cell: the floor alone
        self._goal_distance = goal_distance

    def _new_goal(self, key: jax.Array, xy: jax.Array) -> jax.Array:
        k_d, k_a = jax.random.split(key)
        d = jax.random.uniform(k_d, (), minval=self._goal_distance[0], maxval=self._goal_distance[1])
        a = jax.random.uniform(k_a, (), minval=-jnp.pi, maxval=jnp.pi)
        return xy + d * jnp.stack([jnp.cos(a), jnp.sin(a)])

    def reset(self, rng: jax.Array) -> State:
        k_goal, k_ant, k_next = jax.random.split(rng, 3)
        pipeline_state = self._ant_at(k_ant, jnp.zeros(2))
        goal = self._new_goal(k_goal, pipeline_state.q[:2])
        zero = jnp.zeros(())
        metrics = {"goals_reached": zero, "goal_distance": jnp.linalg.norm(goal - pipeline_state.q[:2]),
                   "progress": zero}
        return State(pipeline_state, self._goal_obs(pipeline_state, goal), zero, zero, metrics,
                     {"goal": goal, "key": k_next})

    def step(self, state: State, action: jax.Array) -> State:
        pipeline_state = self.pipeline_step(state.pipeline_state, action)
        goal, xy0, xy = state.info["goal"], state.pipeline_state.q[:2], pipeline_state.q[:2]
        u = (goal - xy0) / jnp.maximum(jnp.linalg.norm(goal - xy0), 1e-6)
        progress = jnp.dot(xy - xy0, u) / self.dt
        z = pipeline_state.q[2]
        finite = is_finite(pipeline_state)
        healthy = (z >= 0.2) & (z <= 1.0) & ~upside_down(pipeline_state.q) & finite
        reward = progress + 1.0 - 0.5 * jnp.sum(jnp.square(action))
        key, k_goal = jax.random.split(state.info["key"])
        reached = jnp.linalg.norm(xy - goal) <= GOAL_RADIUS
        goal = jnp.where(reached, self._new_goal(k_goal, xy), goal)
        obs = jnp.where(finite, self._goal_obs(pipeline_state, goal), 0.0)
        metrics = {"goals_reached": state.metrics["goals_reached"] + reached,
                   "goal_distance": jnp.linalg.norm(goal - xy), "progress": progress}
        return state.replace(pipeline_state=pipeline_state, obs=obs, reward=jnp.where(finite, reward, 0.0),
                             done=1.0 - healthy.astype(jnp.float32), metrics=metrics,
                             info={**state.info, "goal": goal, "key": key})

    def _goal_obs(self, pipeline_state, goal: jax.Array) -> jax.Array:
        q, qd = pipeline_state.q, pipeline_state.qd
        return rotate_ant_obs(jnp.concatenate([q[2:], qd]), heading_to(q[:2], goal))

    @property
    def observation_size(self) -> int:
        return self.sys.q_size() + self.sys.qd_size() - 2
