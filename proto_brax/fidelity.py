"""Switches between this suite's choices and the official PROTO code's (FIDELITY.md): a light module (no JAX), so
the CLI can build its arguments from it before anything heavy is imported."""

from __future__ import annotations

import dataclasses
from typing import Literal


@dataclasses.dataclass(frozen=True)
class Fidelity:
    """Where PROTO-SAC / PROTO-TD3 here differ from the official PROTO code (github: Facebear-ljx/PROTO), one static
    switch per difference. The defaults are this suite's choices (the paper's equations where the paper states one);
    ``Fidelity.official()`` selects every choice of the official code. FIDELITY.md has, per row, the paper's
    statement, the official code's file and line, and the measured effect.
    """

    actor_q: Literal["backup", "mean"] = "backup"
    """SAC actor's Q over the critic ensemble: 'backup' = the target's reduction (min with clipped double-Q, else
    mean); 'mean' = always the mean (official code: ``(q1 + q2) / 2``)."""
    temperature_loss: Literal["log_alpha", "alpha"] = "log_alpha"
    """SAC temperature loss: log α_sac · (H − H̄) (SAC v2's derivation) or α_sac · (H − H̄) (official code)."""
    unclipped_target: Literal["mean", "random"] = "mean"
    """Target when clipped double-Q is off (the paper's AntMaze setting; official TD3 also on Adroit): the ensemble
    mean, or one target critic drawn at random per update (official code: REDQ-style ``subsample_ensemble`` of one)."""
    td3_backup: Literal["paper", "official"] = "paper"
    """PROTO-TD3 critic target. 'paper': Q̄(s′, a′_smoothed) − α‖π(s′) − π̄(s′)‖² per sample, a′ from the target
    actor plus clipped noise. 'official': Q̄(s′, π̄(s′)) (no smoothing) − α · mean over batch and action dims of
    (π(s′) + clipped noise − π̄(s′))², a batch-constant penalty."""
    td3_actor_critic: Literal[0, 1] = 0
    """Which critic PROTO-TD3's actor maximizes: Q₁ (TD3, TD3+BC) or Q₂ (official code unpacks ``q1, q1 = critic``
    and so uses the second)."""
    td3_expl_noise_clip: float | None = None
    """PROTO-TD3's exploration noise N(0, σ²) clipped to ±c before the action is clipped to [−1, 1]; None = no clip
    (TD3's own exploration); official 0.5 (with σ = 0.2, ``HParams.expl_noise``)."""
    td3_penalty: Literal["sum", "mean"] = "sum"
    """PROTO-TD3 actor penalty ‖π(s) − π̄(s)‖² summed over action dimensions (the norm) or averaged (official)."""
    eval_mode: Literal["deterministic", "behaviour"] = "deterministic"
    """Evaluation actions: the deterministic mean action, or the behaviour policy's (SAC: a sample; TD3: π(s) plus
    clipped exploration noise). The official code evaluates AntMaze with the behaviour policy, MuJoCo and Adroit
    deterministically, so ``official()`` leaves this to the AntMaze preset."""
    carry_critic_state: bool = False
    """Start finetuning with the pretrained critic's Adam state and its Polyak target critic (official code: one
    critic Model is trained offline and online); else a fresh Adam and target = the pretrained critic. The actor's
    Adam and the temperature start fresh either way, as in the official code. Needs the bundle's optimizer state
    (every bundle saved by ``python -m proto_brax.pretrain`` has it)."""
    online_preload: int = 0
    """Offline rows (drawn at random) copied into the online buffer at the start; the official code preloads 10,000
    (hard-coded) and then updates from the first env step, so its batches' offline share starts near 1 and decays as
    ½ + ½·10⁴/(10⁴ + t). With 0 the online half of a symmetric batch holds online rows only."""

    @classmethod
    def official(cls) -> "Fidelity":
        return cls(actor_q="mean", temperature_loss="alpha", unclipped_target="random", td3_backup="official",
                   td3_actor_critic=1, td3_penalty="mean", online_preload=10_000, td3_expl_noise_clip=0.5,
                   carry_critic_state=True)
