"""Settings of the multi-agent baselines (ISAC, MADDPG, MAAC, QMIX; §5.1).

One frozen dataclass exposed on the command line as ``--marl.*`` (``TrainConfig.marl``).
Network sizes and QMIX's candidate count change shapes (static); the scalars that only scale
arrays (gamma, tau, reward scale, exploration noise, epsilon schedule) are fed as arrays.
"""

from __future__ import annotations

import dataclasses

from score_jax.agents.sac.config import SACSettings
from score_jax.networks.actor import ActorConfig


@dataclasses.dataclass(frozen=True)
class MarlConfig(SACSettings):
    """Multi-agent baseline settings: the SAC settings (MADDPG and QMIX read the learning rates,
    discount, Polyak rate, reward scale and clipping), then one block per algorithm."""

    actor: ActorConfig = ActorConfig()
    """Per-sub-space actors of ISAC, MAAC and MADDPG (the same stacked actors as SCORE)."""
    critic_hidden: tuple[int, ...] = (128, 128)
    """Hidden widths of the critics: ISAC's per-agent Q_i, MADDPG's centralised Q, MAAC's
    per-agent output heads f_i and QMIX's per-agent Q networks."""
    maac_embed_dim: int = 64
    """MAAC: width of the per-agent (o, a_i) embeddings e_i and of the attention output."""
    maac_heads: int = 4
    """MAAC: attention heads (must divide ``maac_embed_dim``)."""
    maddpg_noise: float = 0.1
    """MADDPG: std of the Gaussian exploration noise on continuous dims (normalised units)."""
    qmix_candidates: int = 32
    """QMIX: K, candidate sub-actions per sub-space (a centre plus a grid around it: the default
    with ``--default-prior``, else the mid-range point; see ``qmix_candidates``)."""
    qmix_radius: float = 1.0
    """QMIX: the grid spans centre +- radius per dim (normalised units, clipped to [-1, 1])."""
    qmix_prior_q: float = 1.0
    """QMIX with ``--default-prior``: initial head start of the default candidate's Q_i (the
    output bias of the agent Q networks, reward-scaled units), so an untrained greedy agent
    plays its default. The agent Q networks' output layer starts as small as the actors'
    (``actor.head_init_scale``) either way: without the prior every candidate starts ~equal."""
    qmix_mixer_dim: int = 32
    """QMIX: width of the mixing network's hidden layer (its hypernetworks output these weights)."""
    qmix_eps_start: float = 1.0
    """QMIX: epsilon of epsilon-greedy exploration when updates start."""
    qmix_eps_end: float = 0.05
    """QMIX: final epsilon."""
    qmix_eps_decay_steps: int = 50_000
    """QMIX: environment steps (after ``learning_starts``) over which epsilon decays linearly."""

    def __post_init__(self):
        if self.maac_embed_dim % self.maac_heads:
            raise ValueError(
                f"maac_embed_dim={self.maac_embed_dim} must be a multiple of "
                f"maac_heads={self.maac_heads}"
            )
        if self.qmix_candidates < 2:
            raise ValueError(
                "qmix_candidates must be >= 2 (the default and at least one other), "
                f"got {self.qmix_candidates}"
            )
        if not 0.0 < self.qmix_radius <= 2.0:
            raise ValueError(
                f"qmix_radius must lie in (0, 2] (normalised units), got {self.qmix_radius}"
            )
