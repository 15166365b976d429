"""AntMaze data pieces: the BFS waypoint planner, the heading rotation of the ant's observation, and ``AntGoal``
(the goal-reaching task of the datasets' controller: reward, termination, goal redraw).

The two MJX tests (ant-goal's reward and the AntMaze collection's D4RL labels) compile MJX ant programs for ~3 min
on the CI's two cores, so they are marked slow; run them before changing AntMaze data code:
``pytest -m slow tests/test_maze_planner.py``."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from proto_brax import envs
from proto_brax.envs import antmaze
from proto_brax.envs import maze_planner as mp

# gymnasium-robotics' U_MAZE (1 = wall): the free cells form a U from (1, 1) round to (3, 1).
U = [[1, 1, 1, 1, 1], [1, 0, 0, 0, 1], [1, 1, 1, 0, 1], [1, 0, 0, 0, 1], [1, 1, 1, 1, 1]]
PATH = [(1, 1), (1, 2), (1, 3), (2, 3), (3, 3), (3, 2), (3, 1)]


def test_bfs_planner_follows_the_u():
    p = mp.make_planner(U)
    xy = lambda c: jnp.asarray(antmaze.cell_to_xy(c, U), jnp.float32)  # noqa: E731
    start, goal = PATH[0], PATH[-1]
    ids = [int(mp.cell_of(p, xy(c))) for c in PATH]
    assert p.distance[ids[0], ids[-1]] == 6 and p.distance[ids[3], ids[-1]] == 3
    for here, nxt in zip(ids, ids[1:]):  # each cell's next step towards the goal is the next cell of the U
        assert p.next_cell[here, ids[-1]] == nxt
    goal_xy = xy(goal) + jnp.array([0.7, -0.3])
    np.testing.assert_allclose(mp.waypoint(p, xy(start) + 0.5, goal_xy), xy(PATH[1]))
    np.testing.assert_allclose(mp.waypoint(p, xy(goal), goal_xy), goal_xy)  # in the goal's cell: the goal itself
    # batched, and a torso poking into a wall cell counts as the nearest free cell
    wall_poke = xy((2, 3)) + jnp.array([-2.3, 0.0])  # inside wall cell (2, 2), next to free (2, 3)
    wps = mp.waypoint(p, jnp.stack([wall_poke, xy((3, 3))]), jnp.stack([goal_xy, goal_xy]))
    np.testing.assert_allclose(wps, jnp.stack([xy((3, 3)), xy((3, 2))]))


def test_rotated_observation_points_the_goal_along_x():
    rng = np.random.default_rng(0)
    obs = jnp.asarray(rng.standard_normal(27), jnp.float32)
    q = jnp.asarray(rng.standard_normal(4), jnp.float32)
    obs = obs.at[1:5].set(q / jnp.linalg.norm(q))
    yaw = antmaze.ant_yaw(obs[1:5])
    r = antmaze.rotate_ant_obs(obs, yaw)
    assert abs(float(antmaze.ant_yaw(r[1:5]))) < 1e-5  # seen from its own heading, the torso faces +x
    np.testing.assert_allclose(jnp.linalg.norm(r[1:5]), 1.0, rtol=1e-6)
    # tilt (the torso's world z axis) and the untouched parts are unchanged
    tilt = lambda o: 1 - 2 * (o[2] ** 2 + o[3] ** 2)  # noqa: E731
    np.testing.assert_allclose(tilt(r), tilt(obs), atol=1e-6)
    np.testing.assert_array_equal(np.delete(np.asarray(r), [1, 2, 3, 4, 13, 14]),
                                  np.delete(np.asarray(obs), [1, 2, 3, 4, 13, 14]))
    # a velocity towards θ becomes +x; two turns compose
    theta = 2.2
    v = obs.at[13:15].set(1.7 * jnp.array([np.cos(theta), np.sin(theta)]))
    np.testing.assert_allclose(antmaze.rotate_ant_obs(v, theta)[13:15], [1.7, 0.0], atol=1e-5)
    np.testing.assert_allclose(antmaze.rotate_ant_obs(antmaze.rotate_ant_obs(obs, 0.4), 0.9),
                               antmaze.rotate_ant_obs(obs, 1.3), atol=1e-5)


@pytest.fixture(scope="module")
def antgoal():
    env = envs.make_env("ant-goal")
    return env, jax.jit(env.reset), jax.jit(env.step)


@pytest.mark.slow  # MJX compiles (~1-2 min each on 2 cores): kept out of CI, see the module docstring
def test_ant_goal_reward_termination_and_goal_redraw(antgoal):
    env, reset, step = antgoal
    assert (env.observation_size, env.action_size) == (27, 8) and envs.get_spec("ant-goal").episode_length == 1000
    s = reset(jax.random.PRNGKey(0))
    q, goal = s.pipeline_state.q, s.info["goal"]
    assert 2.0 <= float(jnp.linalg.norm(goal - q[:2])) <= 6.0
    np.testing.assert_allclose(s.obs, antmaze.rotate_ant_obs(jnp.concatenate([q[2:], s.pipeline_state.qd]),
                                                             antmaze.heading_to(q[:2], goal)), atol=1e-6)
    a = jnp.full(8, 0.3)
    nxt = step(s, a)
    dxy = nxt.pipeline_state.q[:2] - q[:2]
    u = (goal - q[:2]) / jnp.linalg.norm(goal - q[:2])
    progress = float(jnp.dot(dxy, u) / env.dt)
    np.testing.assert_allclose(float(nxt.reward), progress + 1.0 - 0.5 * 8 * 0.09, rtol=1e-4, atol=1e-5)
    assert float(nxt.done) == 0.0 and float(nxt.metrics["goals_reached"]) == 0.0
    # a goal under the ant is reached at once and redrawn 2-6 m away from where the ant is
    near = s.replace(info={**s.info, "goal": q[:2]})
    got = step(near, a)
    xy = got.pipeline_state.q[:2]
    assert float(got.metrics["goals_reached"]) == 1.0
    assert 2.0 - 0.01 <= float(jnp.linalg.norm(got.info["goal"] - xy)) <= 6.0 + 0.01
    # upside down (torso at a healthy height) ends the episode
    flipped = s.pipeline_state.replace(qpos=q.at[3:7].set(jnp.array([0.0, 1.0, 0.0, 0.0])).at[2].set(0.4))
    assert float(step(s.replace(pipeline_state=flipped), jnp.zeros(8)).done) == 1.0


@pytest.mark.slow  # MJX compiles (~1-2 min each on 2 cores): kept out of CI, see the module docstring
def test_antmaze_collection_labels_like_d4rl():
    """Collection mechanics with an untrained controller (a small random actor): D4RL's sparse rewards against the
    evaluation goal with terminals equal to them, episodes contiguous and cut by timeouts, starts in task cells,
    deterministic in the key."""
    from proto_brax.data import antmaze_data as ad
    from proto_brax.data.generate import flatten_env_major, stochastic_policy
    from proto_brax.envs.antmaze import cell_to_xy
    from proto_brax.networks import NetworkConfig, make_networks

    env, planner = ad.data_env("umaze")
    assert not env._terminate_on_success and ad.data_env("umaze")[1] is planner  # cached: segments compile once
    cells = ad.task_cells("umaze", "play")
    assert cells == [(1, 1), (3, 1)] and len(ad.task_cells("large", "diverse")) == 46
    centres = jnp.asarray(np.stack([cell_to_xy(c, env.layout) for c in cells]), jnp.float32)
    goal = centres[0]  # the evaluation goal at a start cell's centre, so that some episodes are rewarded at once
    nets = make_networks(NetworkConfig(hidden=(16, 16)), 8)
    params = nets.actor.init(jax.random.PRNGKey(0), jnp.zeros((1, 27)))
    policy = stochastic_policy(nets)

    def run():
        state = ad._init(env, centres, goal, 4, jax.random.PRNGKey(1))
        tr, state = ad._segment(env, planner, centres, goal, policy, params, jax.random.PRNGKey(2), 40, 15, state)
        return jax.device_get(flatten_env_major(tr))

    d = run()
    obs, nxt = np.asarray(d.observations), np.asarray(d.next_observations)
    assert obs.shape == (160, 29) and np.all(np.abs(d.actions) <= 1)
    want = (np.linalg.norm(nxt[:, :2] - np.asarray(goal), axis=1) <= 0.5).astype(np.float32)
    np.testing.assert_array_equal(d.rewards, want)
    np.testing.assert_array_equal(d.terminals, d.rewards)
    assert 0 < d.rewards.sum() < 160
    ends = np.flatnonzero(d.timeouts)
    starts = np.concatenate([[0], ends[:-1] + 1])
    assert np.all(ends - starts + 1 <= 15) and ends[-1] == 159
    for a, b in zip(starts, ends):  # contiguous within an episode; each starts within ±1 m of a task cell
        np.testing.assert_allclose(obs[a + 1:b + 1], nxt[a:b], atol=1e-6)
        assert np.min(np.abs(obs[a, :2] - np.asarray(centres)).max(axis=1)) <= ad.START_NOISE + 1e-5
    jax.tree.map(np.testing.assert_array_equal, d, run())
    stats = ad.collection_stats(d, 15)
    assert stats["episodes"] == ends.size and 0 < stats["success_rate"] <= 1
