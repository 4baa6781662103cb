"""The SAC settings every SAC-based algorithm exposes (SCORE as ``--score.*``, the multi-agent
baselines as ``--marl.*``); each owner subclasses ``SACSettings`` to choose its defaults."""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class SACSettings:
    """Learning rates, temperature, discounting and target settings of an actor-critic learner."""

    actor_lr: float = 3e-4
    """Adam step size of the actors."""
    critic_lr: float = 3e-4
    """Adam step size of the critics."""
    alpha_lr: float = 3e-4
    """Adam step size of log alpha (automatic entropy tuning, one alpha per agent)."""
    init_alpha: float = 0.1
    """Initial entropy temperature alpha."""
    gamma: float = 0.99
    """Discount factor."""
    tau: float = 0.005
    """Polyak rate of every target network (Alg. 1 line 15: rho = 1 - tau)."""
    critic_pessimism: float = 1.0
    """How the twin critics' estimates combine in the TD targets and the actor's objective:
    ``mean - beta |Q1 - Q2| / 2`` with this beta in [0, 1]. 1 is clipped double Q (their
    minimum, SAC's and the paper's), 0 their mean (less pessimistic about actions away from the
    replay data, where the twins disagree most). Fed as an array: changing it does not
    recompile."""
    reward_scale: float | None = None
    """Rewards are multiplied by this in the targets; None = the environment's suggestion
    (``env.hints.reward_scale``: 0.05 for the greenhouse's cumulative reward, else 1)."""
    grad_clip: float = 10.0
    """Global-norm gradient clipping of every network."""
    discrete_entropy_scale: float = 0.1
    """Entropy target of a discrete dim as a fraction of a uniform choice's,
    ``scale * log(n_choices)``. Small enough that the deterministic (argmax) action is the choice
    the stochastic policy mostly plays, so evaluation sees what training explored."""
    continuous_entropy_target: float = -1.0
    """Entropy target per continuous dim (SAC's usual -1 per dim)."""

    def resolved_reward_scale(self, env) -> float:
        """``reward_scale``, or the environment's suggestion when it is None."""
        return float(env.hints.reward_scale if self.reward_scale is None else self.reward_scale)

    @property
    def entropy_targets(self) -> tuple[float, float]:
        """``(discrete_entropy_scale, continuous_entropy_target)`` for
        ``agents.base.agent_consts``."""
        return (self.discrete_entropy_scale, self.continuous_entropy_target)
