"""IQL: implicit Q-learning (Kostrikov, Nair, Levine, ICLR 2022): expectile value regression, AWR extraction.

Offline pretraining (``update`` on an ``OfflineState``) and online finetuning (``ONLINE``) share the same losses.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from proto_brax.agents import sac
from proto_brax.agents.insample import OfflineHParams, OfflineState, insample_update
from proto_brax.agents.learner import Learner, OnlineAlgorithm
from proto_brax.config import FinetuneConfig, HParams, positive
from proto_brax.data.dataset import Transition
from proto_brax.networks import Networks


@struct.dataclass
class IQLHParams(HParams):
    """IQL's own traced hyper-parameters (Kostrikov et al. 2022, MuJoCo values)."""

    expectile: jax.Array = 0.7  # expectile τ of the value regression
    awr_temperature: jax.Array = 3.0  # inverse temperature β of the extraction weight exp(β (Q − V))
    awr_weight_max: jax.Array = 100.0  # extraction weights are clipped to [0, awr_weight_max]

    @classmethod
    def check(cls, v: dict[str, np.ndarray]) -> None:
        super().check(v)
        if np.any((v["expectile"] <= 0) | (v["expectile"] >= 1)):
            raise ValueError(f"expectile must lie in (0, 1); got {v['expectile']}.")
        positive("awr_weight_max", v=v)


def value_loss(q: jax.Array, v: jax.Array, hp: OfflineHParams) -> jax.Array:
    """Expectile regression E[|τ − 1(u < 0)| u²], u = Q − V (IQL Eq. 5; τ = 0.7 MuJoCo, 0.9 AntMaze)."""
    u = q - v
    return jnp.mean(jnp.abs(hp.expectile - (u < 0).astype(u.dtype)) * u**2)


def weight(q: jax.Array, v: jax.Array, hp: OfflineHParams) -> jax.Array:
    """AWR weight min(exp(β (Q − V)), w_max) (IQL Eq. 7; β = 3 MuJoCo, 10 AntMaze; w_max 100)."""
    return jnp.minimum(jnp.exp(hp.temperature * (q - v)), hp.weight_max)


def update(state, batch, nets, hp: OfflineHParams, extract_actions=None):
    return insample_update(state, batch, nets, hp, value_loss, weight, extract_actions)


# ---------------------------------------------------------------------------------------------------------------
# Online finetuning (IQL paper, Section 5.3): the same three losses on replay batches that keep the dataset; actions
# are sampled from the extracted policy.


def offline_view(learner: Learner) -> OfflineState:
    """The learner's fields that the in-sample update reads and writes."""
    return OfflineState(actor=learner.actor, critic=learner.critic, critic_target=learner.critic_target,
                        value=learner.value, actor_opt=learner.actor_opt, critic_opt=learner.critic_opt,
                        value_opt=learner.value_opt)


def offline_hparams(hp: IQLHParams) -> OfflineHParams:
    """IQL's traced values taken from the finetuning ``HParams`` (learning rates live in the optimizer states)."""
    return OfflineHParams(expectile=hp.expectile, temperature=hp.awr_temperature, weight_max=hp.awr_weight_max,
                          gamma=hp.gamma, target_tau=hp.target_tau)


def merge(learner: Learner, state: OfflineState) -> Learner:
    return learner.replace(actor=state.actor, critic=state.critic, critic_target=state.critic_target,
                           value=state.value, actor_opt=state.actor_opt, critic_opt=state.critic_opt,
                           value_opt=state.value_opt)


def online_update(learner: Learner, batch: Transition, key: jax.Array, alpha: jax.Array, hp: IQLHParams,
                  nets: Networks, cfg: FinetuneConfig, step: jax.Array) -> tuple[Learner, dict]:
    """One IQL step (expectile V, AWR π, Q → r + γV′, target Polyak) on a replay batch; α (PROTO's) is unused."""
    del key, alpha, cfg, step
    state, info = update(offline_view(learner), batch, nets, offline_hparams(hp))
    return merge(learner, state), {**info, "actor_updates": jnp.ones(())}


ONLINE = OnlineAlgorithm(update=online_update, act=sac.act, deviation=sac.deviation, value=True, hparams=IQLHParams,
                         policies=("tanh_gaussian", "gaussian"))
