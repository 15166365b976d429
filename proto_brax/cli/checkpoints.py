"""``python -m proto_brax.checkpoints list | show | index | checksum | evaluate``: what is committed under
``checkpoints/``, and a bundle's policy evaluated again.

The command line sits above the library (``proto_brax.checkpoints``): the index reads the behaviour snapshots through
the dataset generator, which itself loads them with the library.
"""

from __future__ import annotations

import json
from pathlib import Path

from proto_brax.checkpoints import CheckpointError, add_checksum, find_bundles, read_metadata
from proto_brax.files import write_text_atomic


def index_markdown(root: Path) -> str:
    """A markdown index of the bundles and behaviour snapshots under ``root`` (checkpoints/INDEX.md)."""
    lines = ["# Committed checkpoints", "", "Regenerate with `python -m proto_brax.checkpoints index`.", "",
             "## Pretrained bundles", "", "| bundle | algo | dataset | seeds | steps | offline return | normalized |",
             "|---|---|---|---|---|---|---|"]
    for p in find_bundles(root):
        m = read_metadata(p)
        ev = m.get("offline_eval", {})
        ret, score = ev.get("return_mean", float("nan")), ev.get("normalized_score_mean", float("nan"))
        lines.append(f"| `{p.relative_to(root)}` | {m['algo']} | {m.get('dataset', '?')} | {m['seeds']} | {m['steps']} "
                     f"| {ret:.1f} | {score:.1f} |")
    lines += ["", "## Behaviour-policy snapshots (SAC from scratch)", "",
              "Eval: the training-time evaluation (10 episodes, mean action); behaviour: the stochastic policy that "
              "generates the datasets (`python -m proto_brax.datasets measure ENV`, 100 episodes). Expert = the final "
              "snapshot; medium = the behaviour return closest to a normalized ⅓.", "",
              "| env | snapshots | steps | final eval / behaviour return | medium snapshot | its behaviour return "
              "(normalized) |", "|---|---|---|---|---|---|"]
    from proto_brax import envs
    from proto_brax.data.cache import reference_returns
    from proto_brax.data.generate import list_snapshots, pick_expert_medium

    for env_dir in sorted((Path(root) / "behavior").glob("*")):
        snaps = list_snapshots(env_dir.name, Path(root) / "behavior") if any(env_dir.glob("step_*")) else []
        if not snaps:
            continue
        last, beh = snaps[-1], lambda s: s.metadata.get("behavior_return", {}).get("mean", float("nan"))
        if env_dir.name == "ant-goal":  # no expert/medium: its last snapshot steers the AntMaze datasets
            lines.append(f"| ant-goal (AntMaze datasets' controller) | {len(snaps)} | {last.step} | "
                         f"{last.eval_return:.1f} / - | - | - |")
            continue
        _, med = pick_expert_medium(snaps, reference_returns(envs.get_spec(env_dir.name)))
        score = float(envs.normalized_score(env_dir.name, beh(med)))
        f = lambda x: "not measured" if x != x else f"{x:.1f}"  # noqa: E731 (NaN: no behaviour return yet)
        lines.append(f"| {env_dir.name} | {len(snaps)} | {last.step} | {last.eval_return:.1f} / {f(beh(last))} | "
                     f"{med.step} | {f(beh(med))} ({f(score)}) |")
    return "\n".join(lines) + "\n"


def evaluate_bundle(path: str | Path, episodes: int | None = None, repeats: int = 1):
    """Returns [bundle seeds, repeats, episodes] of the bundle's policy (mean action) evaluated as pretraining
    evaluates it (``PretrainConfig.eval_episodes`` episodes side by side, or the hands' one at a time), the r-th
    repetition of seed s with the key ``fold_in(PRNGKey(s), r)``: repetition 0 with the recorded number of episodes
    is the evaluation recorded in ``offline_eval``, up to the rounding of a larger batch.

    One evaluation of 10 episodes is a noisy estimate where returns are all-or-nothing (the Adroit hands); more
    repetitions give the spread that the recorded number was drawn from."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from proto_brax.checkpoints import bundle_net, load_bundle
    from proto_brax.train.offline import PretrainConfig, make_pretrain

    state, meta = load_bundle(path)
    episodes = episodes or meta.get("offline_eval", {}).get("episodes", PretrainConfig.eval_episodes)
    pre = make_pretrain(PretrainConfig(algo=meta["algo"], env=meta["env"], net=bundle_net(meta), steps=1, log_every=1,
                                       eval_episodes=episodes))
    seeds = jax.vmap(jax.random.PRNGKey)(jnp.asarray(meta["seeds"], jnp.uint32))
    keys = jax.vmap(lambda k: jax.vmap(lambda r: jax.random.fold_in(k, r))(jnp.arange(repeats)))(seeds)
    per_seed = jax.vmap(jax.vmap(pre.evaluate, in_axes=(None, 0)))  # over the bundle's seeds, then the repetitions
    return np.asarray(jax.device_get(jax.jit(per_seed)(state.actor, keys))), meta


def print_evaluation(path: str, episodes: int | None = None, repeats: int = 1) -> None:
    """``evaluate``: each seed's and repetition's normalized score, the recorded one, and the mean over all."""
    import numpy as np

    from proto_brax import envs
    from proto_brax.analysis.stats import mean_ci

    returns, meta = evaluate_bundle(path, episodes, repeats)
    env = meta["env"]
    scores = np.asarray(envs.normalized_score(env, returns))  # [seeds, repeats, episodes]
    recorded = meta.get("offline_eval", {}).get("normalized_score_per_seed")
    for i, seed in enumerate(meta["seeds"]):
        per = ", ".join(f"{x:.1f}" for x in scores[i].mean(-1))
        rec = f" (recorded: {recorded[i]:.1f})" if recorded else ""
        print(f"seed {seed}: normalized score per repetition of {returns.shape[-1]} episodes: {per}{rec}")
    mean, lo, hi = mean_ci(scores.reshape(-1))
    print(f"{path}: {scores.size} episodes on {env}, normalized {mean:.1f} [{lo:.1f}, {hi:.1f}] (mean, 95% "
          f"bootstrap CI over episodes)")


def main(argv: list[str] | None = None) -> None:
    """python -m proto_brax.checkpoints list [ROOT] | show PATH | index [ROOT] | checksum PATH... | evaluate PATH
    [EPISODES [REPEATS]]"""
    import sys

    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in ("list", "show", "index", "checksum", "evaluate"):
        raise SystemExit("usage: python -m proto_brax.checkpoints list [ROOT=checkpoints] | show PATH | index [ROOT] "
                         "| checksum PATH... (record or verify bundles' content checksums) | evaluate PATH [EPISODES "
                         "[REPEATS]] (the bundle's policy evaluated again)")
    if argv[0] == "evaluate":
        if len(argv) < 2 or not all(a.isdigit() and int(a) > 0 for a in argv[2:4]) or len(argv) > 4:
            raise SystemExit("usage: python -m proto_brax.checkpoints evaluate PATH [EPISODES [REPEATS]] (positive "
                             "integers; default: the recorded evaluation's episodes, 1 repetition)")
        from proto_brax.train.grid import size_cpu_pool

        size_cpu_pool(1)  # before JAX's backend starts: the MJX hands' batched LAPACK needs a one-thread pool
        try:
            print_evaluation(argv[1], *(int(a) for a in argv[2:4]))
        except CheckpointError as e:  # not a bundle, or a corrupt one: the reason and the fix, in one line
            raise SystemExit(f"error: {e}") from None
        return
    if argv[0] == "checksum":
        for p in argv[1:]:
            print(f"{p}: content_sha256 {add_checksum(p)}")
        return
    if argv[0] == "index":
        root = Path(argv[1] if len(argv) > 1 else "checkpoints")
        text = index_markdown(root)
        write_text_atomic(root / "INDEX.md", text)
        print(text)
        return
    if argv[0] == "list":
        root = Path(argv[1] if len(argv) > 1 else "checkpoints")
        print(f"{'bundle':60s} {'algo':>5s} {'dataset':>26s} {'seeds':>5s} {'steps':>7s} {'offline score':>14s}")
        for p in find_bundles(root):
            m = read_metadata(p)
            score = m.get("offline_eval", {}).get("normalized_score_mean", float("nan"))
            print(f"{str(p):60s} {m['algo']:>5s} {m.get('dataset', '?'):>26s} {len(m['seeds']):>5d} {m['steps']:>7d} "
                  f"{score:>14.1f}")
    else:
        if len(argv) < 2:
            raise SystemExit("usage: python -m proto_brax.checkpoints show PATH")
        print(json.dumps(read_metadata(argv[1]), indent=2, sort_keys=True))
