"""State and array hyperparameters of the multi-agent SAC update."""

from __future__ import annotations

from typing import Any

import jax
from flax import struct

from score_jax.agents.base import AgentConsts


@struct.dataclass
class SACHyper:
    """Hyperparameters fed as arrays, so sweeping them does not recompile."""

    gamma: jax.Array
    tau: jax.Array
    dropnode_prob: jax.Array
    reward_scale: jax.Array
    pessimism: jax.Array | float = 1.0
    """beta of ``losses.pessimistic_q`` for the targets and the actor (1: clipped double Q)."""


@struct.dataclass
class SACState:
    actor: Any
    critic: Any
    target_critic: Any
    log_alpha: jax.Array  # [n] one temperature per agent (or [] shared)
    actor_opt: Any
    critic_opt: Any
    alpha_opt: Any
    consts: AgentConsts
