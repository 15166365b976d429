"""AntMaze on MJX (proto_brax/envs/antmaze.py): sizes and registry, sparse reward, reset cells, and a trajectory
cross-check against gymnasium-robotics' own MuJoCo ``AntMaze_UMaze-v5``.

Everything physical runs unbatched through one module-scoped env whose ``reset`` and ``step`` are jitted once:
compiling them is most of this file's cost (~25 s and ~30-55 s on the loaded 2-core CPU); the tests then take
seconds.
"""

from __future__ import annotations

import os
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from proto_brax import envs
from proto_brax.envs import antmaze
from proto_brax.envs.antmaze import GOAL_RADIUS, MAZE_SIZE_SCALING, POSITION_NOISE, AntMaze

NOISE = POSITION_NOISE * MAZE_SIZE_SCALING  # ±1 m per axis around a cell centre


@pytest.fixture(scope="module")
def umaze():
    env = envs.make_env("antmaze-umaze")
    return types.SimpleNamespace(env=env, reset=jax.jit(env.reset), step=jax.jit(env.step))


def test_sizes_registry_and_model():
    expected = {"antmaze-umaze": 700, "antmaze-medium": 1000, "antmaze-large": 1000}
    for name, horizon in expected.items():
        spec = envs.get_spec(name)
        assert (spec.episode_length, spec.default_backend, spec.ref_random, spec.ref_expert) == (horizon, "mjx", 0, 1)
        env = envs.make_env(name)
        assert isinstance(env, AntMaze) and env.backend == "mjx"
        assert (env.observation_size, env.action_size) == (29, 8)
        mj = env.sys.mj_model
        walls = sum(v == 1 for row in env.layout for v in row)
        assert sum(mj.geom(i).name.startswith("block_") for i in range(mj.ngeom)) == walls
        # mjx 3.17 reads its contact numerics as numeric_data[id]: they must resolve to the intended values.
        from mujoco.mjx._src.collision_driver import _numeric

        assert _numeric(mj, "max_geom_pairs") == antmaze.MAX_GEOM_PAIRS
        assert _numeric(mj, "max_contact_points") == antmaze.MAX_CONTACT_POINTS
        assert np.isclose(float(env.dt), 0.05) and mj.opt.integrator == 1  # RK4, 5 x 0.01 s
        np.testing.assert_allclose(env.sys.init_q, mj.qpos0)  # gymnasium's start pose (z 0.75), not brax's init_qpos
    assert float(envs.normalized_score("antmaze-large", 1.0)) == 100.0
    assert AntMaze("umaze", goal_in_obs=True).observation_size == 31
    with pytest.raises(ValueError):
        envs.make_env("antmaze-umaze", "generalized")


def test_cells_follow_gymnasium_robotics():
    from gymnasium_robotics.envs.maze.maps import MEDIUM_MAZE_DIVERSE_GR, U_MAZE
    from gymnasium_robotics.envs.maze.maze_v4 import Maze

    ref = Maze(U_MAZE, MAZE_SIZE_SCALING, antmaze.MAZE_HEIGHT)
    for cell in [(1, 1), (3, 1), (2, 3), (0, 4)]:
        xy = antmaze.cell_to_xy(cell, U_MAZE)
        np.testing.assert_allclose(xy, ref.cell_rowcol_to_xy(np.array(cell)))
        np.testing.assert_array_equal(antmaze.xy_to_cell(xy + 0.9, U_MAZE), cell)
    # D4RL's evaluation cells, placed on gymnasium-robotics' maps.
    assert antmaze.maze_map("umaze")[1][1] == "r" and antmaze.maze_map("umaze")[3][1] == "g"
    assert antmaze.maze_map("large")[7][9] == "g"
    # Unmarked map: every empty cell is both; 'c' cells are both and nothing else is.
    resets, goals = antmaze.reset_and_goal_cells(U_MAZE)
    assert resets == goals and len(resets) == 7
    resets, goals = antmaze.reset_and_goal_cells(MEDIUM_MAZE_DIVERSE_GR)
    assert resets == goals == [(1, 1), (2, 6), (5, 1), (6, 5)]

    # Start/goal sampling on a 'c' map: never the same cell, every cell used, noise within ±0.25 s.
    centres = jnp.asarray(np.stack([antmaze.cell_to_xy(c, MEDIUM_MAZE_DIVERSE_GR) for c in goals]), jnp.float32)
    start, goal = jax.vmap(antmaze.sample_start_and_goal, (0, None, None))(
        jax.random.split(jax.random.PRNGKey(0), 512), centres, centres
    )
    cell_of = lambda xy: np.argmin(np.linalg.norm(np.asarray(xy)[:, None] - np.asarray(centres)[None], axis=-1), 1)
    s_cell, g_cell = cell_of(start), cell_of(goal)
    assert np.all(s_cell != g_cell) and set(s_cell) == set(g_cell) == {0, 1, 2, 3}
    assert np.abs(np.asarray(start) - np.asarray(centres)[s_cell]).max() <= NOISE + 1e-5
    assert np.abs(np.asarray(goal) - np.asarray(centres)[g_cell]).max() <= NOISE + 1e-5


def test_reset_cells_and_noise(umaze):
    env, layout = umaze.env, umaze.env.layout
    start_centre, goal_centre = antmaze.cell_to_xy((1, 1), layout), antmaze.cell_to_xy((3, 1), layout)
    states = [umaze.reset(k) for k in jax.random.split(jax.random.PRNGKey(1), 16)]
    xy = np.stack([np.asarray(s.pipeline_state.q[:2]) for s in states])
    goal = np.stack([np.asarray(s.info["goal"]) for s in states])
    assert np.abs(xy - start_centre).max() <= NOISE + 1e-5 and np.abs(goal - goal_centre).max() <= NOISE + 1e-5
    assert xy.std(0).min() > 0.2 and goal.std(0).min() > 0.2  # the ±1 m noise is drawn, per reset
    assert all(tuple(antmaze.xy_to_cell(p, layout)) == (1, 1) for p in xy)
    assert all(tuple(antmaze.xy_to_cell(g, layout)) == (3, 1) for g in goal)
    q = np.stack([np.asarray(s.pipeline_state.q) for s in states])
    dq = q - np.asarray(env.sys.init_q)
    dq = np.concatenate([dq[:, 2:3], dq[:, 7:]], axis=1)  # torso z and joint angles (the quaternion is renormalized)
    assert 0 < np.abs(dq).max() <= 0.1 + 1e-6  # gymnasium Ant's reset noise, scale 0.1
    np.testing.assert_allclose(np.linalg.norm(q[:, 3:7], axis=1), 1.0, atol=1e-6)
    s = states[0]
    assert s.obs.shape == (29,) and float(s.done) == 0.0 and float(s.reward) == 0.0
    np.testing.assert_allclose(s.obs, jnp.concatenate([s.pipeline_state.q, s.pipeline_state.qd]))


def test_sparse_reward_and_success(umaze):
    # Exact boundary of the pure reward (D4RL: within 0.5 m, inclusive).
    goal = jnp.array([1.0, -2.0])
    for d, r in [(0.0, 1.0), (0.3, 1.0), (0.5, 1.0), (0.5001, 0.0), (2.0, 0.0)]:
        reward, dist = antmaze.sparse_reward(goal + jnp.array([0.6, 0.8]) * d, goal)
        assert float(reward) == r and np.isclose(float(dist), d, atol=1e-6)

    # Through the env: place the ant (at rest, in the air) near the goal and take one zero-action step.
    base = umaze.reset(jax.random.PRNGKey(2))
    goal = base.info["goal"]
    q0 = umaze.env.sys.init_q
    for offset, expected in [(0.0, 1.0), (0.3, 1.0), (0.45, 1.0), (0.6, 0.0), (1.5, 0.0)]:
        xy = goal + jnp.array([0.8, -0.6]) * offset
        nxt = umaze.step(_place(base, q0.at[:2].set(xy), jnp.zeros(umaze.env.sys.qd_size())), jnp.zeros(8))
        dist = float(jnp.linalg.norm(nxt.pipeline_state.q[:2] - goal))
        assert abs(dist - offset) < 0.02  # one 0.05 s step barely moves a resting ant
        assert float(nxt.reward) == expected == float(nxt.metrics["success"]) == float(dist <= GOAL_RADIUS)
        assert np.isclose(float(nxt.metrics["goal_distance"]), dist, atol=1e-5)
        assert float(nxt.done) == expected  # D4RL's evaluation tasks end at the goal
        np.testing.assert_allclose(nxt.obs[:2], nxt.pipeline_state.q[:2])


def _native_umaze():
    import gymnasium as gym
    import gymnasium_robotics

    gym.register_envs(gymnasium_robotics)
    genv = gym.make("AntMaze_UMaze-v5", continuing_task=True, include_cfrc_ext_in_observation=False)
    os.remove(genv.unwrapped.tmp_xml_file_path)  # gymnasium-robotics leaves its generated maze XML in the temp dir
    genv.reset(seed=0)
    return genv


def _place(state, qpos, qvel):
    """``state`` with the ant at ``qpos`` / ``qvel``: every MJX step starts with ``forward`` from qpos and qvel, so the
    other fields need no recomputation (and the test needs no extra jit of ``pipeline_init``)."""
    qpos, qvel = jnp.asarray(qpos, jnp.float32), jnp.asarray(qvel, jnp.float32)
    return state.replace(pipeline_state=state.pipeline_state.replace(qpos=qpos, qvel=qvel, q=qpos, qd=qvel))


def _rollouts(umaze, genv, qpos, qvel, actions):
    """qpos after each control step: ours (MJX) and gymnasium-robotics' (native MuJoCo), same start and actions."""
    ant = genv.unwrapped.ant_env
    ant.set_state(qpos, qvel)
    native = []
    for a in actions:
        genv.step(a)
        native.append(ant.data.qpos.copy())
    state = _place(umaze.reset(jax.random.PRNGKey(0)), qpos, qvel)
    ours = []
    for a in actions:
        state = umaze.step(state, jnp.asarray(a))
        ours.append(np.asarray(state.pipeline_state.q))
    return np.array(ours), np.array(native)


def test_trajectory_matches_gymnasium_robotics(umaze):
    """Same start, same actions, 20 control steps: MJX vs gymnasium-robotics' native MuJoCo AntMaze_UMaze-v5.

    Before the first foot touches the floor (control steps 1-3) the two agree to float32 precision (measured max
    |qpos| error 1.5e-5): model, RK4, timestep, frame skip, actuators and joint limits are the same. Contacts then
    differ, for reasons measured while writing this test (2026-11-23):

    * friction pyramids: with pyramidal cones the pyramid's orientation about the contact normal matters; native
      MuJoCo 4.0 turns the plane-capsule contact frame (~60 degrees here), mjx 3.17 builds a world-aligned one. With
      elliptic cones, which don't depend on it, MJX matched native to 1e-6 m over 10 steps on the floor;
    * walls: mjx 3.17's box-capsule collider reports only penetrating contacts, so the 0.02 m contact margin of the
      ant's geoms is ignored against walls and the feet meet a wall ~1 cm later than in native MuJoCo;
    * our MJX settings: Newton 8 / line search 8 iterations (native 100 / 50; in MJX 8 / 8 gave the same
      trajectories as 100 / 50), contacts bounded (max_geom_pairs 8, max_contact_points 16) and the upper-leg
      capsules not colliding (native MuJoCo never used them in these two scenarios: the same trajectories without).

    The ant under large random torques is chaotic, so the contact-time gap grows. Measured max errors over 20 steps:
    free floor xy 0.30 m and qpos 0.29; thrown into a wall xy 0.36 m (torso nearest to the wall face at x = -6:
    ours -5.30, native -5.53). The tolerances leave ~50% margin; the pre-contact check is the tight one.
    """
    genv = _native_umaze()
    try:
        model = genv.unwrapped.ant_env.model
        ours_mj = umaze.env.sys.mj_model
        for i in range(model.ngeom):  # identical walls (names, positions, sizes)
            name = model.geom(i).name
            if name.startswith("block_"):
                np.testing.assert_allclose(ours_mj.geom(name).pos, model.geom(i).pos)
                np.testing.assert_allclose(ours_mj.geom(name).size, model.geom(i).size)
        rng = np.random.default_rng(0)
        qpos = model.qpos0.copy()
        qpos[:2] = antmaze.cell_to_xy((1, 1), umaze.env.layout)
        qpos[7:] += rng.uniform(-0.1, 0.1, 8)
        qvel = 0.1 * rng.standard_normal(14)
        actions = rng.uniform(-1, 1, (20, 8)).astype(np.float32)
        ours, native = _rollouts(umaze, genv, qpos, qvel, actions)
        xy_err = np.linalg.norm(ours[:, :2] - native[:, :2], axis=-1)
        assert np.abs(ours[:3] - native[:3]).max() < 1e-4  # measured 1.5e-5
        assert xy_err.max() < 0.45  # measured 0.30
        assert np.abs(ours - native).max() < 0.45  # measured 0.29

        # Thrown at 3 m/s towards the wall 1 m to its left (cell (1, 0) is a wall, face at x = -6): the walls must
        # stop the torso (radius 0.25) in both simulators.
        qpos = model.qpos0.copy()
        qpos[:2] = [-5.0, 4.0]
        qvel = np.zeros(14)
        qvel[0] = -3.0
        ours, native = _rollouts(umaze, genv, qpos, qvel, np.zeros((20, 8), np.float32))
        xy_err = np.linalg.norm(ours[:, :2] - native[:, :2], axis=-1)
        assert ours[:, 0].min() > -6.0 + 0.25 and native[:, 0].min() > -6.0 + 0.25
        assert xy_err.max() < 0.55  # measured 0.36
    finally:
        genv.close()
