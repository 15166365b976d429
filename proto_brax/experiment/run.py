"""Run a planned sweep chunk by chunk (progress bar, metrics rows, resume checkpoints, TensorBoard) and
``run_sweep``: plan -> prepare --out -> pretrain -> run -> summarize."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from proto_brax.experiment.args import SweepArgs
from proto_brax.experiment.outdir import append_rows, prepare_out, truncate_metrics
from proto_brax.experiment.plan import Plan, plan_sweep, pretrain_into_out
from proto_brax.experiment.summary import episode_stats, summarize
from proto_brax.files import release_dir


def metric_rows(chunk: int, m: dict, grid, env: str, updates_per_s: float) -> list[dict]:
    from proto_brax.envs import normalized_score

    scalar_keys = [k for k, v in m.items() if np.ndim(v) == 1]
    rows = []
    for i, point in enumerate(grid.points):
        row = {"chunk": chunk, "run": i, **point}
        row.update({k: float(m[k][i]) for k in scalar_keys})
        row["step"] = int(m["step"][i])
        row["normalized_score"] = float(normalized_score(env, row["eval_return"]))
        row["eval_returns"] = [float(x) for x in m["eval_returns"][i]]
        row.update(episode_stats(env, m["eval_returns"][i], m["eval_lengths"][i], m["eval_success_steps"][i]))
        row["diverged"] = not all(np.isfinite(row[k]) for k in ("eval_return", "critic_loss", "q_mean"))
        row["grid_updates_per_s"] = updates_per_s
        rows.append(row)
    return rows


def _tensorboard_writers(out: Path, grid):
    try:
        from tensorboardX import SummaryWriter
    except ImportError as e:
        raise ImportError("--tensorboard needs tensorboardX: pip install 'proto_brax[tensorboard]'") from e
    writers = []
    for i, point in enumerate(grid.points):
        w = SummaryWriter(str(out / "tensorboard" / f"run_{i:03d}"))
        w.add_text("hparams", json.dumps(point))
        writers.append(w)
    return writers


def _write_tensorboard(writers, rows: list[dict]) -> None:
    for r in rows:
        for k, v in r.items():
            if isinstance(v, float) and k not in ("tau", "eta", "alpha0", "anneal_horizon"):
                writers[r["run"]].add_scalar(k, v, r["step"])
        writers[r["run"]].flush()


def train_dataset(plan: Plan):
    """The offline data as the runs train on it: rewards transformed, Cal-QL's returns-to-go, on the device."""
    import jax

    from proto_brax.agents.registry import agent
    from proto_brax.data.dataset import transform_rewards, with_returns_to_go

    cfg, dataset = plan.cfg, plan.dataset
    if dataset is None:
        return None
    dataset = transform_rewards(dataset, cfg.reward_scale, cfg.reward_shift)
    if agent(cfg.algo).mc_returns:  # Cal-QL's calibration bound: returns-to-go with the runs' γ
        dataset = with_returns_to_go(dataset, float(np.asarray(plan.grid.hparams.gamma)[0]))
    return jax.tree.map(jax.numpy.asarray, dataset)


def execute(plan: Plan) -> float | None:
    """Run (or resume) the grid chunk by chunk: progress, metrics rows, resume checkpoints. Returns the seconds of
    the first chunk run (compilation included), None when nothing was left to run."""
    import jax
    from tqdm import tqdm

    from proto_brax import __version__, checkpoints
    from proto_brax.train.grid import compile_grid, grid_mesh, padded_size, run_grid

    args, cfg, grid, lead = plan.args, plan.cfg, plan.grid, plan.lead
    dataset = train_dataset(plan)
    mesh = grid_mesh()
    out = Path(args.out)
    metrics_path = out / "metrics.jsonl"
    print(f"grid: {grid.size} runs ({' × '.join(f'{k} {len(v)}' for k, v in plan.axes.items())} × "
          f"{len(args.seeds)} seeds), padded to {padded_size(grid.size, mesh)} over {mesh.devices.size} device(s) "
          f"{[d.platform for d in mesh.devices.flat]}; {cfg.steps} steps per run", flush=True)

    def restore(state):
        latest = checkpoints.latest_step(out / "state") if args.resume else None
        if latest is None:
            truncate_metrics(metrics_path, -1)  # nothing checkpointed yet: start over, dropping every logged row
            return state, 0
        state, meta = checkpoints.restore(latest, state)
        truncate_metrics(metrics_path, meta["chunks_done"], runs=grid.size)
        print(f"resumed after chunk {meta['chunks_done']} of {cfg.num_chunks}", flush=True)
        bar.update(meta["chunks_done"] * cfg.eval_every)
        return state, meta["chunks_done"]

    tb = _tensorboard_writers(out, grid) if args.tensorboard and lead else None
    bar = tqdm(total=cfg.steps, unit="step", desc="sweep", dynamic_ncols=True, file=sys.stdout)
    timing = {"t": time.time(), "first": None}

    def on_chunk(c, m, state):
        now = time.time()
        dt = now - timing["t"]
        if timing["first"] is None:
            timing["first"] = dt  # includes compilation
        updates_per_s = float(np.sum(m["updates"])) / dt
        rows = metric_rows(c, m, grid, cfg.env, updates_per_s)
        bar.update(cfg.eval_every)
        timing["t"] = time.time()
        if not lead:
            return
        append_rows(metrics_path, rows)
        if tb is not None:
            _write_tensorboard(tb, rows)
        if jax.process_count() == 1:  # across hosts the state is not gathered to one place: no resume checkpoints
            checkpoints.save_step(out / "state", c + 1, state, {"chunks_done": c + 1, "version": __version__})
        finite = [r["eval_return"] for r in rows if np.isfinite(r["eval_return"])]
        bar.set_postfix(eval=f"{np.mean(finite) if finite else float('nan'):.1f}", upd_s=f"{updates_per_s:.0f}")

    program = compile_grid(plan.ft, mesh, plan.per_run, args.block)

    def on_start(stats):
        """π₀ at step 0 (chunk −1): the reference of the initial drop; curves start there."""
        if not lead:
            return
        from proto_brax.envs import normalized_score

        returns, lengths, success_steps = stats
        rows = [{"chunk": -1, "run": i, **point, "step": 0, "eval_return": float(np.mean(returns[i])),
                 "eval_returns": [float(x) for x in returns[i]],
                 "normalized_score": float(normalized_score(cfg.env, float(np.mean(returns[i])))),
                 **episode_stats(cfg.env, returns[i], lengths[i], success_steps[i]),
                 "diverged": not bool(np.all(np.isfinite(returns[i]))), "initial": True,
                 "dev_pi0": 0.0, "dev_pibar": 0.0, "grid_updates_per_s": float("nan")}
                for i, point in enumerate(grid.points)]
        append_rows(metrics_path, rows)
        if tb is not None:
            _write_tensorboard(tb, rows)

    run_grid(plan.ft, grid, plan.pretrained, dataset, mesh=mesh, program=program, callback=on_chunk,
             restore=restore, on_start=on_start, per_run_pretrained=plan.per_run)
    bar.close()
    if tb is not None:
        for w in tb:
            w.close()
    return timing["first"]


def run_sweep(args: SweepArgs) -> list[dict]:
    """Plan (every check, nothing written), prepare --out, pretrain (--pretrain), run (or resume) the grid, summarize;
    returns the per-point summary (empty on processes other than 0)."""
    plan = plan_sweep(args)
    try:
        if plan.lead:
            prepare_out(args, plan.config)  # (takes --out's lock: one process writes a sweep)
        if args.pretrain is not None:
            plan = pretrain_into_out(plan)
        first = execute(plan)
        return summarize(plan, first) if plan.lead else []
    finally:
        release_dir(args.out)
