"""SCORE's settings (``--score.*``): network sizes (static), ASRL, and the SAC scalars (fed as
arrays). The ablations of Table 2 are switches of ``CriticConfig`` (aggregation, hypernet,
asrl), not separate code."""

from __future__ import annotations

import dataclasses

from score_jax.agents.sac.config import SACSettings
from score_jax.networks.actor import ActorConfig
from score_jax.networks.critic import CriticConfig
from score_jax.networks.hvae import HVAEConfig


@dataclasses.dataclass(frozen=True)
class ScoreConfig(SACSettings):
    """SCORE hyperparameters (network sizes are static; the SAC scalars are fed as arrays)."""

    actor_lr: float = 1e-4
    """Adam step size of the actors (a tenth of the critic's: Adam moves the actors by about
    this much per update even when the critic's action gradient is mostly noise)."""
    init_alpha: float = 0.001
    """Initial entropy temperature of every agent. Small, so that the entropy bonus does not
    outweigh the reward at the start: at 0.1 the greenhouse's actors opened their Gaussians to
    the log-std ceiling (tanh then plays bang-bang, the default-centred start is lost) and
    learning waited for alpha to decay (docs/learning.md, entry 6). Alpha then follows the
    entropy targets as before."""
    critic_lr: float = 1e-3
    """Adam step size of the critics (and of c_i when ASRL is off)."""
    hvae: HVAEConfig = HVAEConfig()
    """The HVAE of ASRL (§4.1)."""
    critic: CriticConfig = CriticConfig()
    """The graph critic (§4.2) and its ablation switches."""
    actor: ActorConfig = ActorConfig()
    """The per-sub-space actors."""
    asrl_k: int = 16
    """Random fixings of the other sub-spaces per sub-space (§4.1)."""
    asrl_j: int = 8
    """Random sub-actions per fixing (§4.1)."""
    asrl_steps: int = 1500
    """HVAE training steps."""
    dropnode_prob: float = 0.1
    """Probability that an agent is masked in the critic during an update (DropNode, §4.2)."""
