"""Multi-agent soft actor-critic losses and the one-jit update (Alg. 1, lines 11-15).

Written once against two functions, so SCORE and the SAC-based baselines (ISAC, MAAC, the
ablations) share it:

- ``policy_fn(actor_params, consts, obs[B, obs], key, deterministic) -> (action[B, n, w], log_prob[B, n])``
  samples every sub-space's sub-action (decentralised actors);
- ``q_fn(critic_params, consts, obs[B, obs], action[B, n, w], mask[B, n]) -> q[B, 2]``
  evaluates the twin centralised critics on the agents where ``mask`` is True; or
  ``-> q[B, k, n]``: k critics (2 twins, or 1) of one Q_i per agent (ISAC, MAAC), each
  regressed on the team reward with its own entropy term, the losses summed over the agents
  where ``mask`` is True.

Agent masks (``valid`` agents, failed sub-spaces and DropNode) are arrays inside the update,
so changing them never recompiles anything.
"""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp
import optax
from flax import struct

from score_jax.failures import dropnode_mask
from score_jax.replay import Transition


@struct.dataclass
class AgentConsts:
    """Per-agent arrays that describe the sub-spaces (no recompilation when they change).

    Attributes:
      dim_mask: ``[n, w]`` bool, real dimensions of each sub-space.
      n_choices: ``[n, w]`` int32, grid size of discrete dims (0 = continuous).
      valid: ``[n]`` bool, agents that exist (False for padding when the agent axis is grown).
      target_entropy: ``[n]`` per-agent entropy target for the temperature alpha.
      critic_inputs: algorithm-specific frozen inputs of the critic (SCORE: HVAE params, c_i).
      default_action: ``[n, w]`` normalised default sub-actions, the actors' prior (None = none).
    """

    dim_mask: jax.Array
    n_choices: jax.Array
    valid: jax.Array
    target_entropy: jax.Array
    critic_inputs: Any = None
    default_action: Any = None


@struct.dataclass
class SACHyper:
    """Hyperparameters fed as arrays, so sweeping them does not recompile."""

    gamma: jax.Array
    tau: jax.Array
    dropnode_prob: jax.Array
    reward_scale: jax.Array


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


@struct.dataclass
class SACMetrics:
    critic_loss: jax.Array
    actor_loss: jax.Array
    alpha: jax.Array  # mean over agents
    entropy: jax.Array  # mean over the batch of -sum_i log pi_i (active agents)
    q_mean: jax.Array


PolicyFn = Callable[..., tuple[jax.Array, jax.Array]]
QFn = Callable[..., jax.Array]


def target_entropy(dim_mask, n_choices, discrete_scale: float = 0.1, continuous: float = -1.0) -> jax.Array:
    """``[n]`` entropy target: ``continuous`` per continuous dim, ``discrete_scale * log(n_choices)``
    per discrete dim (the entropy of a uniform choice scaled down)."""
    per_dim = jnp.where(n_choices > 0, discrete_scale * jnp.log(jnp.maximum(n_choices, 1)), continuous)
    return jnp.sum(jnp.where(dim_mask, per_dim, 0.0), axis=-1)


def critic_loss(critic_params, state: SACState, batch: Transition, mask, key, hyper: SACHyper, policy_fn: PolicyFn, q_fn: QFn):
    """Alg. 1 lines 12-13: mean over the batch of the sum over both critics of (Q_j - y)^2 / 2.

    Centralised ``q [B, 2]``: ``y = r + gamma (min_j Q'_j - sum_i alpha_i log pi_i)``.
    Per-agent ``q [B, k, n]``: ``y_i = r + gamma (min_j Q'_ij - alpha_i log pi_i)`` and the
    squared errors are summed over the agents where ``mask`` is True (independent learners).
    """
    consts = state.consts
    next_action, next_logp = policy_fn(state.actor, consts, batch.next_obs, key, False)
    next_q = jnp.min(q_fn(state.target_critic, consts, batch.next_obs, next_action, mask), axis=1)  # [B] or [B, n]
    entropy = jnp.where(mask, jnp.exp(state.log_alpha) * next_logp, 0.0)  # [B, n]
    per_agent = next_q.ndim == 2
    soft_next = next_q - (entropy if per_agent else jnp.sum(entropy, axis=-1))
    reward = batch.reward[:, None] if per_agent else batch.reward
    not_done = (1.0 - batch.terminal)[:, None] if per_agent else 1.0 - batch.terminal
    y = hyper.reward_scale * reward + hyper.gamma * not_done * soft_next
    q = q_fn(critic_params, consts, batch.obs, batch.action, mask)
    err = (q - jax.lax.stop_gradient(y)[:, None]) ** 2
    if per_agent:
        err = jnp.where(mask[:, None, :], err, 0.0)
        q_mean = jnp.sum(jnp.where(mask[:, None, :], q, 0.0)) / jnp.maximum(q.shape[1] * jnp.sum(mask), 1.0)
    else:
        q_mean = jnp.mean(q)
    loss = 0.5 * jnp.mean(jnp.sum(err.reshape(err.shape[0], -1), axis=-1))
    return loss, q_mean


def actor_loss(actor_params, state: SACState, batch: Transition, mask, key, policy_fn: PolicyFn, q_fn: QFn):
    """Alg. 1 line 14: mean of sum_i alpha_i log pi_i - min_j Q_j(o, a~(o)); masked agents excluded.

    With per-agent critics (``q [B, k, n]``) the Q term is ``sum_i min_j Q_ij`` over the agents
    where ``mask`` is True. Returns ``(loss, log_prob [B, n])`` (the log-probs feed the
    temperature update)."""
    consts = state.consts
    action, logp = policy_fn(actor_params, consts, batch.obs, key, False)
    q = jnp.min(q_fn(state.critic, consts, batch.obs, action, mask), axis=1)  # [B] or [B, n]
    if q.ndim == 2:
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


def make_sac_update(
    policy_fn: PolicyFn,
    q_fn: QFn,
    actor_opt: optax.GradientTransformation,
    critic_opt: optax.GradientTransformation,
    alpha_opt: optax.GradientTransformation,
):
    """Returns ``update(state, batch, key, hyper) -> (state, SACMetrics)`` (pure; jit it or scan it).

    Critics, all actors (one stacked parameter tree), alpha and the Polyak targets are updated
    in one function; the critic and actor losses both use the parameters the update starts
    from. The critic mask of each sample is ``valid & batch.active & DropNode``.
    """

    def update(state: SACState, batch: Transition, key: jax.Array, hyper: SACHyper):
        key_drop, key_critic, key_actor = jax.random.split(key, 3)
        b = batch.reward.shape[0]
        valid = state.consts.valid & batch.active
        mask = jax.vmap(dropnode_mask, in_axes=(0, 0, None))(jax.random.split(key_drop, b), valid, hyper.dropnode_prob)

        # Both losses read the critics of the start of the update (as brax's SAC does), so the
        # critic's state-side forward pass (SCORE: e_o and the hypernetwork's GAT weights of
        # o) is one computation shared by the two gradients.
        (c_loss, q_mean), c_grads = jax.value_and_grad(critic_loss, has_aux=True)(
            state.critic, state, batch, mask, key_critic, hyper, policy_fn, q_fn
        )
        (a_loss, logp), a_grads = jax.value_and_grad(actor_loss, has_aux=True)(
            state.actor, state, batch, mask, key_actor, policy_fn, q_fn
        )
        c_updates, critic_opt_state = critic_opt.update(c_grads, state.critic_opt, state.critic)
        critic = optax.apply_updates(state.critic, c_updates)
        a_updates, actor_opt_state = actor_opt.update(a_grads, state.actor_opt, state.actor)
        actor = optax.apply_updates(state.actor, a_updates)

        al_grad = jax.grad(alpha_loss)(state.log_alpha, logp, mask, state.consts)
        al_update, alpha_opt_state = alpha_opt.update(al_grad, state.alpha_opt, state.log_alpha)
        log_alpha = optax.apply_updates(state.log_alpha, al_update)

        target = optax.incremental_update(critic, state.target_critic, hyper.tau)
        state = state.replace(
            actor=actor, critic=critic, target_critic=target, log_alpha=log_alpha,
            actor_opt=actor_opt_state, critic_opt=critic_opt_state, alpha_opt=alpha_opt_state,
        )
        metrics = SACMetrics(c_loss, a_loss, jnp.mean(jnp.exp(log_alpha)), -jnp.mean(jnp.sum(jnp.where(mask, logp, 0.0), -1)), q_mean)
        return state, metrics

    return update
