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

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


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
        action; 1: sampled actions)."""
        import jax.numpy as jnp

        from proto_brax.antmaze import heading_to, rotate_ant_obs
        from proto_brax.data import maze_planner as mp

        k_reset, k_run = jax.random.split(key)
        s = jax.vmap(env.reset)(jax.random.split(k_reset, episodes))

        def body(carry, k):
            s, ret, alive, length = carry
            xy = s.obs[:, :2]
            theta = heading_to(xy, mp.waypoint(planner, xy, s.info["goal"]))
            mean, log_std = nets.actor.apply(params, rotate_ant_obs(s.obs[:, 2:], theta))
            a = jnp.tanh(mean + noise * jnp.exp(log_std) * jax.random.normal(k, mean.shape))
            s = jax.vmap(env.step)(s, a)
            ret = ret + jnp.where(alive, s.reward, 0.0)
            return (s, ret, alive & (s.done == 0), length + alive.astype(jnp.int32)), None

        init = (s, jnp.zeros(episodes), jnp.ones(episodes, bool), jnp.zeros(episodes, jnp.int32))
        (_, ret, _, length), _ = jax.lax.scan(body, init, jax.random.split(k_run, horizon))
        return ret, length

    return navigate


def main(args: Args) -> dict:
    from proto_brax import envs

    os.environ["XLA_FLAGS"] = envs.mjx_xla_flags()
    import jax
    import numpy as np

    from proto_brax.checkpoints import write_json_atomic
    from proto_brax.data import maze_planner as mp
    from proto_brax.data.generate import list_snapshots, load_snapshot_actor

    navigate = _navigate_fn()
    snap = list_snapshots("ant-goal")[-1]
    nets, params = load_snapshot_actor(snap, envs.make_env("ant-goal"))
    results = {"controller_step": snap.step, "controller_eval_return": snap.eval_return, "episodes": args.episodes,
               "command": "python benchmarks/antmaze_controller.py " + " ".join(sys.argv[1:]), "mazes": {}}
    for maze in args.mazes:
        env = envs.make_env(f"antmaze-{maze}")  # the evaluation task: it ends at the goal
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
