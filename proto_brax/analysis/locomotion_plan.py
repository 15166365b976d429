"""The published benchmarks: locomotion (its datasets, its methods and the paper's ablations, appendix), Adroit and
AntMaze (``DOMAINS``), run by ``benchmarks/locomotion.py`` and reported by ``proto_brax.analysis.results_md``; the
runner's queue of sweeps, each one's state (done, needs a bundle, shared, started, pending), its command line and its
publication."""

from __future__ import annotations

import contextlib
import dataclasses
import gzip
import json
import os
import shutil
import sys
from collections.abc import Iterator
from pathlib import Path

from proto_brax.agents.registry import METHODS, Method, pretrain_flags
from proto_brax.experiment.args import PRESETS, SweepArgs
from proto_brax.files import atomic_write, copy_atomic

DATASETS = tuple(f"{env}-{kind}" for env in ("hopper", "walker2d", "halfcheetah", "ant")
                 for kind in ("medium", "medium-replay", "random"))
PAPER_METHODS = ("proto-sac", "frozen", "direct", "iql", "sac-scratch", "proto-td3", "proto-bc")
PRESET = "paper-mujoco-100k"
# the ablations' middle values (proto-sac)
TAU0, ETA0 = PRESETS[PRESET].fields["tau"][0], PRESETS[PRESET].fields["eta"][0]


@dataclasses.dataclass(frozen=True)
class Ablation:
    """A runner pseudo-method: the sweep of the method ``base`` with ``flags`` added to its command line."""

    base: str
    flags: tuple[str, ...]
    summary: str
    bundle: str | None = None
    """A bundle directory under checkpoints/pretrained/DATASET that replaces the base method's (``--checkpoint``)."""
    bundle_hp: dict[str, float] | None = None
    """The pretraining hyper-parameters that make ``bundle`` (None: the pretraining defaults, this suite's)."""

    @property
    def values(self) -> tuple[float, ...]:
        """A grid ablation's non-default values (``--tau V1 V2`` -> (V1, V2))."""
        return tuple(float(v) for v in self.flags[1:])


# The paper's appendix: PROTO-SAC over the two non-default values of τ (0.5 and 2 × τ₀) and η (0.8 and 1.0), in one
# vmapped sweep each; the default value is the proto-sac sweep.
GRID_ABLATIONS = {
    "ablate-tau": Ablation("proto-sac", ("--tau", str(0.5 * TAU0), str(2 * TAU0)), "τ ∈ {0.5, 2} × τ₀"),
    "ablate-eta": Ablation("proto-sac", ("--eta", "0.8", "1.0"), "η ∈ {0.8, 1.0}"),
}
# What a fidelity ablation puts back: PROTO-SAC's settings under the preset (this suite's choices).
OURS = PRESETS[PRESET].apply(SweepArgs())


def put_back(field: str) -> tuple[str, ...]:
    """The sweep flags that set the ``Fidelity`` switch ``field`` to ours (tyro's spelling: a bool is a flag pair)."""
    value, name = getattr(OURS.fidelity, field), field.replace("_", "-")
    if isinstance(value, bool):
        return (f"--fidelity.{name}" if value else f"--fidelity.no-{name}",)
    return (f"--fidelity.{name}", str(value))


# FIDELITY.md's rows one at a time: proto-official with one of its choices put back to this suite's default (the
# official code's other choices kept), where proto-official's CIs separate from PROTO-SAC's. proto-official-online
# (a method) is the complement of the policy class and pretraining rows (6, 13, 14).
FIDELITY_ABLATIONS = {
    "official-but-actor-q": Ablation("proto-official", put_back("actor_q"),
                                     "row 1: the actor on the min of the two critics"),
    "official-but-temperature": Ablation("proto-official", put_back("temperature_loss"),
                                         "row 2: the temperature loss log α·(H − H̄)"),
    "official-but-start": Ablation("proto-official", (*put_back("online_preload"), "--learning-starts",
                                                      str(OURS.learning_starts)),
                                   f"row 4: an empty online buffer and {OURS.learning_starts:,} warm-up steps"),
    "official-but-critic-state": Ablation("proto-official", put_back("carry_critic_state"),
                                          "row 5: a fresh critic Adam state and target"),
    # Under the official policy class, from a bundle pretrained with this suite's EQL (IVR's extraction weight
    # exp(10 (Q − V)/α), z clip 5): with proto-official-online it splits row 6 from rows 13-14.
    "official-but-extraction": Ablation("proto-official", (), "rows 13-14: IVR's EQL extraction (weight scale 10, "
                                        "z clip 5) under the official policy class", bundle="eql-gaussian"),
    # The fourth cell of rows 6 × 13-14: our tanh-squashed policy class, pretrained with the official EQL.
    "official-but-policy-class": Ablation("proto-official", ("--policy", OURS.policy),
                                          "row 6: the tanh-squashed policy class, pretrained with the official EQL",
                                          bundle="eql-official-tanh",
                                          bundle_hp=METHODS["proto-official"].defaults["pretrain_hp"]),
}
# FIDELITY.md's rows that act only where clipped double-Q is off or success is reported (AntMaze): PROTO-SAC with one
# official-code choice, the other way round from FIDELITY_ABLATIONS.
OFFICIAL_ROWS = {
    "ours-but-random-target": Ablation("proto-sac", ("--fidelity.unclipped-target", "random"),
                                       "row 3: one target critic drawn at random per update (clipped double-Q off)"),
    "ours-but-behaviour-eval": Ablation("proto-sac", ("--fidelity.eval-mode", "behaviour"),
                                        "row 11: evaluated with sampled actions, as the policy trains"),
}
ABLATIONS = {**GRID_ABLATIONS, **FIDELITY_ABLATIONS, **OFFICIAL_ROWS}


@dataclasses.dataclass(frozen=True)
class Domain:
    """One benchmark the runner (``benchmarks/locomotion.py --domain``) queues: its datasets and methods, the preset
    its sweeps start from and the reduced online budget they run at."""

    name: str  # results/<name>/DATASET/METHOD, runs/<name>/DATASET/METHOD
    datasets: tuple[str, ...]
    methods: tuple[str, ...]
    preset: str
    steps: int  # online budget per run (the paper: 10⁶)
    eval_every: int
    eval_episodes: int | None = None  # None: the preset's
    anneal_over_budget: bool = True
    """True: α annealed over the budget, the same fraction of the run as the paper's (locomotion). False: the preset's
    horizon, the paper's 10⁶ (AntMaze, Adroit: τ 5e-5 moves π̄ slowly, and a short run would anneal α away)."""
    dataset_size: int | None = None  # --dataset-size (None: the registered default)
    bundle_flags: dict[str, tuple[str, ...]] = dataclasses.field(default_factory=dict)
    """Per bundle kind, the pretraining flags of the domain (the PROTO paper's EQL; the IQL paper's IQL)."""
    cost_env: str = "hopper"
    """The env claim 3 (PROTO costs about what SAC costs) is timed on: ``benchmarks/methods_cost.py --env``."""

    def cost_command(self) -> str:
        """The measurement of claim 3 on this domain, written to ``benchmarks/results/methods_cost_NAME.json``."""
        return (f"python benchmarks/methods_cost.py --env {self.cost_env} --methods proto-sac sac-scratch --reps 7 "
                f"--out benchmarks/results/methods_cost_{self.name}.json")


LOCOMOTION = Domain("locomotion", DATASETS, PAPER_METHODS + tuple(GRID_ABLATIONS), PRESET, 50_000, 2_500,
                    dataset_size=1_000_000)
ADROIT = Domain("adroit", tuple(f"{t}-human" for t in ("pen", "door", "hammer")),
                # 10⁴ steps, evaluated every 10³: MJX steps one hand 230-590 times a second here (2026-12-07) and an
                # update costs about as much, so 10⁴ is what twelve 5-seed sweeps can afford on the 2-core CPU
                # (docs/MEASUREMENTS.md#adroit); the first evaluation falls at 10% of the run, where the drop is read
                ("proto-sac", "frozen", "direct", "iql"), "paper-adroit", 10_000, 1_000, anneal_over_budget=False,
                bundle_flags={"eql": ("--steps", "100000"),  # IQL's Adroit values: expectile 0.7, β 0.5
                              "iql": ("--steps", "100000", "--hp", "temperature", "0.5")},
                cost_env="pen")
ANTMAZE = Domain("antmaze", tuple(f"antmaze-{m}" for m in ("umaze-diverse", "medium-play", "medium-diverse",
                                                             "large-diverse", "umaze", "large-play")),
                 ("proto-sac", "frozen", "direct", "iql"), "paper-antmaze", 50_000, 5_000, eval_episodes=20,
                 anneal_over_budget=False, dataset_size=1_000_000,
                 bundle_flags={"eql": ("--steps", "200000", "--hp", "alpha", "0.5"),  # IQL's AntMaze: 0.9, β 10
                               "iql": ("--steps", "200000", "--hp", "expectile", "0.9", "temperature", "10")},
                 cost_env="antmaze-medium")
# Gymnasium's MuJoCo v5 locomotion on MJX (envs/gym_v5.py), datasets recorded on gymnasium's own envs: the
# locomotion benchmark's preset, budget and paper methods (no ablations) on D4RL-comparable dynamics and references.
MUJOCO_V5 = Domain("mujoco-v5", tuple(f"{env}-v5-{kind}" for env in ("hopper", "halfcheetah")
                                      for kind in ("medium", "medium-replay", "random")),
                   ("proto-sac", "frozen", "direct", "iql"), PRESET, 50_000, 2_500, dataset_size=1_000_000,
                   cost_env="hopper-v5")
DOMAINS = {d.name: d for d in (LOCOMOTION, ADROIT, ANTMAZE, MUJOCO_V5)}


def env_of(dataset: str) -> str:
    """The env a registered dataset was recorded on (``hopper-medium`` -> ``hopper``, ``antmaze-umaze-diverse`` ->
    ``antmaze-umaze``, ``pen-human`` -> ``pen``)."""
    from proto_brax.data.generate import parse_name

    return parse_name(dataset)[0]


def method_of(name: str) -> Method:
    """The sweep method a runner method name stands for (an ablation's is its base method)."""
    return METHODS[ABLATIONS[name].base if name in ABLATIONS else name]


def planned_sweeps(datasets: tuple[str, ...], methods: tuple[str, ...],
                   ablation_datasets: tuple[str, ...]) -> list[tuple[str, str]]:
    """The runner's queue, in order: every (dataset, method), an ablation only on ``ablation_datasets``."""
    return [(d, m) for d in datasets for m in methods if m not in ABLATIONS or d in ablation_datasets]


def sweep_command(dataset: str, method: str, out: Path, seeds: tuple[int, ...], steps: int, eval_every: int,
                  single_core: bool, resume: bool, domain: Domain = LOCOMOTION, report: bool = True) -> list[str]:
    """``python -m proto_brax.sweep`` of one (dataset, method) into ``out``: the domain's preset, the online budget
    ``steps`` (α annealed over all of it where the domain says so), the ablation's two values, the dataset (unless the
    method trains on none)."""
    m = method_of(method)
    cmd = [sys.executable, "-m", "proto_brax.sweep", "--preset", domain.preset, "--algo", m.name,
           "--env", env_of(dataset), "--seeds", *map(str, seeds), "--steps", str(steps),
           "--eval-every", str(eval_every), "--out", str(out)]
    if domain.anneal_over_budget:
        cmd += ["--anneal-horizon", str(float(steps))]
    if domain.eval_episodes is not None:
        cmd += ["--eval-episodes", str(domain.eval_episodes)]
    if method in ABLATIONS:
        cmd += ABLATIONS[method].flags
        if ABLATIONS[method].bundle is not None:
            cmd += ["--checkpoint", f"checkpoints/pretrained/{dataset}/{ABLATIONS[method].bundle}"]
    if m.uses_dataset:
        cmd += ["--dataset", dataset]
        if domain.dataset_size is not None:
            cmd += ["--dataset-size", str(domain.dataset_size)]
    if single_core:  # the runs one after another through the one-run program: a one-thread vmap of 5 is 0.80x
        # (SAC) to 0.65x (RLPD) of that rate (docs/MEASUREMENTS.md#run-block), and each run is then its one-seed
        # part's bit for bit
        cmd += ["--devices", "1", "--block", "map"]
    if not report:  # a one-seed part: its merged sweep gets the report
        cmd += ["--no-report"]
    return cmd + (["--resume"] if resume else [])


def sweep_env(single_core: bool) -> dict[str, str]:
    """The sweep's environment: with ``single_core``, one XLA thread."""
    # Here, not at the top: proto_brax.envs loads MuJoCo and Brax, which RESULTS.md's driver (through this module)
    # does not need.
    from proto_brax.envs import single_thread_xla_flags

    env = dict(os.environ)
    if single_core:
        env["XLA_FLAGS"] = single_thread_xla_flags()
    return env


def missing_bundle(dataset: str, method: str, pretrained: Path, domain: Domain = LOCOMOTION) -> str | None:
    """The command that makes the pretrained bundle ``method`` starts from on ``dataset`` when ``pretrained`` (the
    repository's ``checkpoints/pretrained``) lacks it; None when it is there or the method needs none."""
    m = method_of(method)
    if not m.bundles:
        return None
    kind = m.bundles[0]  # the bundle kind that --checkpoint auto picks
    bundle, hp, policy = m.auto_bundle, m.defaults.get("pretrain_hp"), m.defaults.get("policy", "tanh_gaussian")
    if (ablation := ABLATIONS.get(method)) is not None and ablation.bundle is not None:
        bundle, hp = ablation.bundle, ablation.bundle_hp
        if "--policy" in ablation.flags:
            policy = ablation.flags[ablation.flags.index("--policy") + 1]
    if (pretrained / dataset / bundle / "metadata.json").exists():
        return None
    extra = "".join(f" {f}" for f in (*domain.bundle_flags.get(kind, ()), *pretrain_flags(policy, hp)))
    return (f"python -m proto_brax.pretrain --dataset {dataset} --algo {kind}{extra} --out "
            f"checkpoints/pretrained/{dataset}/{bundle}")


@contextlib.contextmanager
def gzip_atomic(path: Path) -> Iterator[gzip.GzipFile]:
    """Write the gzip file ``path`` atomically, without a name or a time in its header: the same bytes on a rerun."""
    with atomic_write(path, "wb") as raw, gzip.GzipFile(fileobj=raw, mode="wb", filename="", mtime=0) as g:
        yield g


def publish(src: Path, dst: Path) -> None:
    """Copy a finished sweep ``src`` to the results tree at ``dst``; summary.json goes last, as it marks the sweep
    done."""
    dst.mkdir(parents=True, exist_ok=True)
    copy_atomic(src / "config.json", dst / "config.json")
    with open(src / "metrics.jsonl", "rb") as f, gzip_atomic(dst / "metrics.jsonl.gz") as g:
        shutil.copyfileobj(f, g)
    for f in sorted((src / "report").rglob("*")):  # the sweep's report PNGs (none when it made no report)
        if f.is_file():
            copy_atomic(f, dst / "report" / f.relative_to(src / "report"))
    copy_atomic(src / "summary.json", dst / "summary.json")


SEEDS = (0, 1, 2, 3, 4)  # the published sweeps' seeds; a sweep run seed by seed is merged once all of them are in
# What one-seed parts of one sweep may differ in: their seed and where and how they ran. Everything else in their
# configs (the method, every hyper-parameter, the bundle, the dataset's content hash) must agree.
PART_FIELDS = ("grid", "layout", "dataset_metadata", "merged_from")


def part_dir(sweep: Path, seed: int) -> Path:
    """Where the one-seed part ``seed`` of the sweep ``sweep`` (a working or a published directory) lives."""
    return sweep / "parts" / f"seed-{seed}"


def _part(path: Path):
    """A published one-seed part, read as any sweep (``report.load_sweep``)."""
    from proto_brax.analysis.report import load_sweep

    sweep = load_sweep(path)
    if len(sweep.config.get("grid", [])) != 1:
        raise ValueError(f"{path} is not a one-seed part (its grid has {len(sweep.config.get('grid', []))} runs): "
                         "parts come from `benchmarks/locomotion.py run --per-seed`.")
    return sweep


def merge_parts(parts: list[Path], dst: Path) -> dict:
    """Publish the one-seed sweeps ``parts`` (published by ``publish``) as one sweep at ``dst``, as if its seeds had
    run in one grid: config.json (the parts' shared config, their grid points in seed order, and ``merged_from``:
    each part's seed, layout and compile time), metrics.jsonl.gz (each part's rows, ``run`` renumbered by seed),
    summary.json (``summarize_runs`` over the merged rows) and the PNG report; summary.json last.

    A part is the same run as its seed inside a vmapped grid, up to the rounding of batched matmuls
    (``test_vmapped_grid_run_equals_single_run``). Parts whose configs differ beyond ``PART_FIELDS`` (another
    hyper-parameter, bundle or dataset build) or that repeat a seed are refused before anything is written."""
    from proto_brax.experiment.summary import summarize_runs
    from proto_brax.files import strict_json, write_json_atomic

    loaded = sorted((_part(p) for p in parts), key=lambda sw: sw.config["grid"][0]["seed"])
    seeds = [sw.config["grid"][0]["seed"] for sw in loaded]
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"parts {[str(sw.path) for sw in loaded]} repeat a seed ({seeds}): merge distinct seeds.")

    def shared(config: dict) -> dict:
        out = {k: v for k, v in config.items() if k not in PART_FIELDS}
        out["sweep"] = {k: v for k, v in config.get("sweep", {}).items() if k != "seeds"}
        out["dataset_content_hash"] = (config.get("dataset_metadata") or {}).get("content_hash")
        return out

    first = loaded[0].config
    a = shared(first)
    for sw in loaded[1:]:
        if a != (b := shared(sw.config)):
            keys = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
            raise ValueError(f"{sw.path} differs from {loaded[0].path} in {keys}: parts of one sweep must share every "
                             "setting, bundle and dataset build; rerun the odd part.")
    rows = [{**r, "run": run} for run, sw in enumerate(loaded) for r in sw.rows]
    compile_s = {s: (sw.summary or {}).get("first_chunk_seconds_incl_compile") for s, sw in zip(seeds, loaded)}
    config = {**first, "grid": [sw.config["grid"][0] for sw in loaded],
              "sweep": {**first.get("sweep", {}), "seeds": seeds},
              "layout": {"runs_per_program": 1, "parts": len(loaded)},
              "merged_from": [{"seed": s, "layout": sw.config.get("layout"),
                               "first_chunk_seconds_incl_compile": compile_s[s]} for s, sw in zip(seeds, loaded)]}
    head = loaded[0].summary or {}
    known = [x for x in compile_s.values() if x is not None]
    summary = {**head, "points": summarize_runs(rows, head.get("grid_keys", ["tau"])),
               "first_chunk_seconds_incl_compile": max(known) if known else None}
    dst.mkdir(parents=True, exist_ok=True)
    write_json_atomic(dst / "config.json", config)
    with gzip_atomic(dst / "metrics.jsonl.gz") as g:
        g.write("".join(json.dumps(strict_json(r)) + "\n" for r in rows).encode())
    from proto_brax.analysis.report import make_report

    make_report([dst], dst / "report", verbose=False)
    write_json_atomic(dst / "summary.json", strict_json(summary))
    return summary


def shared_sweep(dataset: str, method: str, results: Path, domain: Domain = LOCOMOTION) -> Path | None:
    """A published sweep (under ``results``) of a dataset-free method on another dataset of the same env, which this
    dataset shares."""
    if method not in METHODS or METHODS[method].uses_dataset:
        return None
    env = env_of(dataset)
    found = [results / d / method for d in domain.datasets
             if d != dataset and env_of(d) == env and (results / d / method / "summary.json").exists()]
    return found[0] if found else None


def copy_shared(src: Path, dst: Path) -> None:
    """Publish the shared sweep ``src`` as ``dst`` too: copied beside it first, then renamed over whatever ``dst``
    holds (an unfinished publish of its own, without summary.json)."""
    tmp = dst.parent / f".{dst.name}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(src, tmp)
    shutil.rmtree(dst, ignore_errors=True)
    tmp.replace(dst)


def sweep_status(dataset: str, method: str, runs: Path, results: Path, pretrained: Path,
                 domain: Domain = LOCOMOTION) -> str:
    """What ``locomotion.py status`` says of one sweep: done (published), needs bundle (with the command that makes
    it), shared (a dataset-free method's sweep on another dataset, copied on run), started (a working directory under
    ``runs``) or pending."""
    if (results / dataset / method / "summary.json").exists():
        return "done"
    if need := missing_bundle(dataset, method, pretrained, domain):
        return "needs bundle: " + need
    if (shared := shared_sweep(dataset, method, results, domain)) is not None:
        return f"shared: copies {shared.parent.name}'s on run"
    parts = [s for s in SEEDS if (part_dir(results / dataset / method, s) / "summary.json").exists()]
    if parts:
        return f"parts of seeds {parts} published (of {list(SEEDS)})"
    return "started" if (runs / dataset / method).exists() else "pending"
