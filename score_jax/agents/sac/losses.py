"""Multi-agent soft actor-critic losses (Alg. 1, lines 12-14).

Written once against two functions, so SCORE and the SAC-based baselines (ISAC, MAAC, the
ablations) share them:

- ``policy_fn(actor_params, consts, obs[B, obs], key, deterministic)``
  ``-> (action[B, n, w], log_prob[B, n])`` samples every sub-space's sub-action (decentralised
  actors);
- ``q_fn(critic_params, consts, obs[B, obs], action[B, n, w], mask[B, n])`` evaluates the
  critics on the agents where ``mask`` is True: ``-> q[B, 2]`` for a ``"centralised"`` critic
  (twin joint Q), or ``-> q[B, k, n]`` for ``"per_agent"`` critics (k = 2 twins or 1; one Q_i
  per agent, each regressed on the team reward with its own entropy term, the losses summed
  over the agents where ``mask`` is True). The kind is an explicit argument, never guessed
  from a shape.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from score_jax.agents.base import AgentConsts, CriticKind
from score_jax.agents.replay import Transition, continuation
from score_jax.agents.sac.state import SACHyper, SACState

PolicyFn = Callable[..., tuple[jax.Array, jax.Array]]
QFn = Callable[..., jax.Array]


def pessimistic_q(q: jax.Array, pessimism) -> jax.Array:
    """The critics' estimates on axis 1 combined with pessimism beta in [0, 1]:
    ``min_j Q_j + (1 - beta) (max_j Q_j - min_j Q_j) / 2``.

    For twins this is ``mean_j Q_j - beta |Q_1 - Q_2| / 2`` (the pessimism of Tactical Optimism
    and Pessimism, Moskovitz et al. 2021): beta = 1 is clipped double Q (``min``, SAC's and the
    paper's), beta = 0 the twins' mean. Written from the min so that beta = 1 gives exactly
    ``min`` (adding zero), bit for bit. ``q [B, k, ...] -> [B, ...]``.
    """
    low, high = jnp.min(q, axis=1), jnp.max(q, axis=1)
    return low + (1.0 - pessimism) * 0.5 * (high - low)


def critic_loss(
    critic_params,
    state: SACState,
    batch: Transition,
    mask,
    key,
    hyper: SACHyper,
    policy_fn: PolicyFn,
    q_fn: QFn,
    critic: CriticKind = "centralised",
):
    """Alg. 1 lines 12-13: mean over the batch of the sum over both critics of (Q_j - y)^2 / 2.

    Centralised ``q [B, 2]``: ``y = r + gamma (min_j Q'_j - sum_i alpha_i log pi_i)``.
    Per-agent ``q [B, k, n]``: ``y_i = r + gamma (min_j Q'_ij - alpha_i log pi_i)`` and the
    squared errors are summed over the agents where ``mask`` is True (independent learners).
    ``min_j`` is ``pessimistic_q`` with ``hyper.pessimism`` (exactly the min at 1).
    """
    consts = state.consts
    next_action, next_logp = policy_fn(state.actor, consts, batch.next_obs, key, False)
    next_q = pessimistic_q(
        q_fn(state.target_critic, consts, batch.next_obs, next_action, mask), hyper.pessimism
    )  # [B] or [B, n]
    entropy = jnp.where(mask, jnp.exp(state.log_alpha) * next_logp, 0.0)  # [B, n]
    per_agent = critic == "per_agent"
    soft_next = next_q - (entropy if per_agent else jnp.sum(entropy, axis=-1))
    reward = batch.reward[:, None] if per_agent else batch.reward
    not_done = continuation(batch)[:, None] if per_agent else continuation(batch)
    y = hyper.reward_scale * reward + hyper.gamma * not_done * soft_next
    q = q_fn(critic_params, consts, batch.obs, batch.action, mask)
    err = (q - jax.lax.stop_gradient(y)[:, None]) ** 2
    if per_agent:
        err = jnp.where(mask[:, None, :], err, 0.0)
        q_mean = jnp.sum(jnp.where(mask[:, None, :], q, 0.0)) / jnp.maximum(
            q.shape[1] * jnp.sum(mask), 1.0
        )
    else:
        q_mean = jnp.mean(q)
    loss = 0.5 * jnp.mean(jnp.sum(err.reshape(err.shape[0], -1), axis=-1))
    return loss, q_mean


def actor_loss(
    actor_params,
    state: SACState,
    batch: Transition,
    mask,
    key,
    policy_fn: PolicyFn,
    q_fn: QFn,
    critic: CriticKind = "centralised",
    pessimism=1.0,
):
    """Alg. 1 line 14: mean of sum_i alpha_i log pi_i - min_j Q_j(o, a~(o)); masked agents excluded.

    With per-agent critics (``q [B, k, n]``) the Q term is ``sum_i min_j Q_ij`` over the agents
    where ``mask`` is True. ``min_j`` is ``pessimistic_q`` with ``pessimism`` (the update passes
    ``hyper.pessimism``, as for the targets). Returns ``(loss, log_prob [B, n])`` (the
    log-probs feed the temperature update)."""
    consts = state.consts
    action, logp = policy_fn(actor_params, consts, batch.obs, key, False)
    q = pessimistic_q(
        q_fn(state.critic, consts, batch.obs, action, mask), pessimism
    )  # [B] or [B, n]
    if critic == "per_agent":
        q = jnp.sum(jnp.where(mask, q, 0.0), axis=-1)
    loss = jnp.mean(jnp.sum(jnp.where(mask, jnp.exp(state.log_alpha) * logp, 0.0), axis=-1) - q)
    return loss, logp


def alpha_loss(log_alpha, logp, mask, consts: AgentConsts):
    """Automatic entropy tuning: drive each agent's -log pi_i towards its target (masked).

    With one temperature per agent (``log_alpha [n]``) a sub-space with few dims (the lamp
    hours) keeps exploring even when the others' entropy dominates the sum; a shared
    ``log_alpha []`` gives the usual single-temperature SAC.
    """
    terms = jnp.where(mask, log_alpha * jax.lax.stop_gradient(logp + consts.target_entropy), 0.0)
    return -jnp.sum(terms) / mask.shape[0]
