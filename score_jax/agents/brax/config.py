"""Settings of the single-agent baselines (``--algo sac|ppo|hppo``, §5.1) and of the transfer
variant a baseline built for the full space trains a subset run with (§5.2.4, §5.4, Table 3;
sac, ppo, hppo, maddpg, and maac, qmix when asked).

One field on ``TrainConfig`` (``single``), so on the command line: ``--single.hidden 64 64``,
``--single.ppo.unroll-length 20``, ``--single.sac.min-replay-size 2000``,
``--single.transfer-variant penalty``.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

TransferVariant = Literal["plain", "mask", "penalty"]


@dataclasses.dataclass(frozen=True)
class BraxPPOConfig:
    """``brax.training.agents.ppo.train`` settings shared by PPO and H-PPO.

    One PPO iteration collects ``batch_size * num_minibatches * unroll_length`` env steps
    (``batch_size * num_minibatches`` must be a multiple of ``num_envs``).
    """

    unroll_length: int = 10
    """Steps per unroll (the GAE window)."""
    batch_size: int = 32
    """Unrolls per minibatch."""
    num_minibatches: int = 8
    """Minibatches per iteration."""
    updates_per_batch: int = 4
    """Passes over the iteration's data."""
    entropy_cost: float = 1e-3
    """Weight of the entropy bonus."""
    clipping_epsilon: float = 0.2
    """PPO ratio clip."""
    gae_lambda: float = 0.95
    """GAE lambda."""
    max_grad_norm: float = 1.0
    """Global-norm gradient clip."""


@dataclasses.dataclass(frozen=True)
class BraxSACConfig:
    """``brax.training.agents.sac.train`` settings."""

    batch_size: int = 128
    """Transitions per gradient update."""
    min_replay_size: int = 1000
    """Transitions collected (with the initial policy) before updates start."""
    replay_capacity: int = 100_000
    """Replay buffer size (capped at the run's env steps)."""
    grad_updates_per_step: int = 1
    """Gradient updates per vectorised env step."""
    tau: float = 0.005
    """Polyak rate of the target Q networks."""


@dataclasses.dataclass(frozen=True)
class SingleAgentConfig:
    """Single-agent baselines trained by brax, and the transfer variants of every baseline built
    for the full space."""

    hidden: tuple[int, ...] = (256, 256)
    """Hidden widths of the policy (H-PPO: its shared trunk) and of the value / Q networks."""
    head_hidden: int = 64
    """H-PPO: hidden width of each sub-actor head (one head per sub-action space)."""
    head_init_scale: float = 0.01
    """Scale of the policy's output layer's initial kernel (SAC / PPO: the MLP's last layer,
    H-PPO: every head's), as SCORE's actors: a fresh policy outputs ~its bias, so where it
    starts is set by ``--default-prior`` alone (the default, or mid-range and uniform)."""
    prior_logit: float = 3.0
    """H-PPO with ``--default-prior``: initial logit bonus of a discrete dim's default choice
    (as SCORE's ``actor.prior_logit``); SAC / PPO see discrete dims as continuous flat columns
    and start them at the default's value instead."""
    num_envs: int = 16
    """Parallel environments of brax's rollouts."""
    learning_rate: float = 3e-4
    """Adam step size (all networks)."""
    discounting: float = 0.99
    """Discount factor."""
    reward_scaling: float | None = None
    """Rewards are multiplied by this in the losses; None = the environment's suggestion
    (``env.hints.reward_scale``)."""
    normalize_observations: bool = False
    """brax's running mean/std observation normaliser (the greenhouse's observations are already
    in [-1, 1])."""
    epochs: int = 10
    """brax training epochs when ``--eval-every`` is 0 (else one per ``eval_every`` steps); each
    ends with one metrics.csv row and, when ``--eval-every`` is set, a deterministic evaluation
    (PPO / H-PPO: the project's evaluator; SAC: brax's evaluator, which SAC always runs)."""
    ppo: BraxPPOConfig = BraxPPOConfig()
    """PPO / H-PPO settings."""
    sac: BraxSACConfig = BraxSACConfig()
    """SAC settings."""
    transfer_variant: TransferVariant | None = None
    """How a baseline built for the full space treats the heads (agents) of the sub-spaces it
    does not see in a ``--subspaces`` run (Table 3; ``agents.variants``); the environment always
    gets those sub-spaces' defaults. ``plain`` freezes them, ``mask`` trains them, ``penalty`` =
    mask plus a penalty on their outputs' deviation from the defaults. Taken by the fixed-width
    baselines sac, ppo, hppo, maddpg (None = plain) and by maac, qmix (None = no variant: the
    run is built on its sub-spaces and transfer grows it); score and isac have none."""
    penalty_coef: float = 1.0
    """Weight of the ``penalty`` variant's term (mean over the batch of the summed squared
    deviation of the unseen heads' sub-actions from the defaults, in normalised units)."""
