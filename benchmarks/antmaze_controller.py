"""How well the AntMaze datasets' controller navigates: the last ant-goal snapshot steered by the BFS planner on each
maze's evaluation task (D4RL's start and goal cells; the episode ends at the goal).

    python benchmarks/antmaze_controller.py                  # umaze, medium, large; 8 episodes each
    python benchmarks/antmaze_controller.py --mazes umaze --episodes 16

Prints and writes ``benchmarks/results/antmaze_controller.json``: per maze and action mode (the mean action, and the
sampled actions that generate the datasets) the success rate and the steps to the goal.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import sys
import time
from pathlib import Path

import _quiet  # noqa: F401  (first: the quiet start)

ROOT = Path(__file__).resolve().parents[1]


@dataclasses.dataclass
class Args:
    mazes: tuple[str, ...] = ("umaze", "medium", "large")
    episodes: int = 8
    seed: int = 0
    out: Path = ROOT / "benchmarks" / "results" / "antmaze_controller.json"


@functools.lru_cache(maxsize=None)
def _navigate_fn():
    import jax

    @functools.partial(jax.jit, static_argnums=(0, 1, 2, 3, 4))
    def navigate(env, planner, horizon, nets, episodes, params, key, noise):
        """(returns, lengths) of ``episodes`` runs of the controller steered by the planner (``noise`` 0: the mean
        action; 1: sampled actions). ``env`` appends the goal to its observation (``goal_in_obs``)."""
        import jax.numpy as jnp

        from proto_brax.envs.maze_planner import controller_obs
        from proto_brax.train.evaluate import run_episodes_with_lengths

        def policy(obs, k):
            mean, log_std = nets.actor.apply(params, controller_obs(planner, obs, obs[:, 29:31]))
            return jnp.tanh(mean + noise * jnp.exp(log_std) * jax.random.normal(k, mean.shape))

        return run_episodes_with_lengths(env, horizon, policy, key, episodes)

    return navigate


def main(args: Args) -> dict:
    from proto_brax import envs

    os.environ["XLA_FLAGS"] = envs.mjx_xla_flags()
    import jax
    import numpy as np

    from proto_brax.data.generate import list_snapshots, load_snapshot_actor
    from proto_brax.envs import maze_planner as mp
    from proto_brax.envs.antmaze import AntMaze
    from proto_brax.files import write_json_atomic

    navigate = _navigate_fn()
    snap = list_snapshots("ant-goal")[-1]
    nets, params = load_snapshot_actor(snap, envs.make_env("ant-goal"))
    results = {"controller_step": snap.step, "controller_eval_return": snap.eval_return, "episodes": args.episodes,
               "command": "python benchmarks/antmaze_controller.py " + " ".join(sys.argv[1:]), "mazes": {}}
    for maze in args.mazes:
        env = AntMaze(maze, goal_in_obs=True)  # the evaluation task (it ends at the goal); the planner needs the goal
        horizon = envs.get_spec(f"antmaze-{maze}").episode_length
        planner = mp.make_planner(env.layout)

        rec = {}
        for mode, noise in (("mean_action", 0.0), ("sampled_actions", 1.0)):
            t0 = time.time()
            ret, length = map(np.asarray, navigate(env, planner, horizon, nets, args.episodes, params,
                                                   jax.random.PRNGKey(args.seed), noise))
            ok = ret > 0
            rec[mode] = {"success_rate": float(ok.mean()),
                         "steps_to_goal_mean": float(length[ok].mean()) if ok.any() else float("nan"),
                         "steps": length.tolist(), "seconds": time.time() - t0}
            print(f"antmaze-{maze} ({mode}, controller step {snap.step}): success {100 * ok.mean():.0f}% of "
                  f"{args.episodes}, steps to goal {rec[mode]['steps_to_goal_mean']:.0f} (horizon {horizon})",
                  flush=True)
        results["mazes"][maze] = rec
    write_json_atomic(args.out, results)
    print(f"wrote {args.out}")
    return results


if __name__ == "__main__":
    import tyro

    main(tyro.cli(Args))
