"""The multi-agent DDPG losses and the one-jit update (MADDPG, Lowe et al. 2017; §5.1).

Written against two functions, like ``agents.sac``:

- ``policy_fn(actor_params, consts, obs[B, obs]) -> action[B, n, w]``: every agent's
  deterministic sub-action, differentiable in the actor parameters;
- ``q_fn(critic_params, consts, obs[B, obs], action[B, n, w], mask[B, n]) -> q[B]``: the
  centralised critic over the agents where ``mask`` is True.

One critic, its target and the target actors (no twin critics, no entropy), Polyak-averaged:

    y   = r + gamma (1 - d) Q'(o', mu'(o'))            L_Q  = mean (Q(o, a) - y)^2 / 2
    L_mu = -mean Q(o, mu(o))                            (all actors at once: sum of the
                                                          per-agent deterministic gradients)

The mask of each sample is ``consts.valid & batch.active`` (an array, never a recompile).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct

from score_jax.agents.base import AgentConsts
from score_jax.agents.replay import Transition, continuation


@struct.dataclass
class DDPGHyper:
    """Hyperparameters fed as arrays, so sweeping them does not recompile."""

    gamma: jax.Array
    tau: jax.Array
    reward_scale: jax.Array


@struct.dataclass
class DDPGState:
    actor: Any
    critic: Any
    target_actor: Any
    target_critic: Any
    actor_opt: Any
    critic_opt: Any
    consts: AgentConsts
    noise_std: jax.Array  # [] Gaussian exploration noise of continuous dims (read by ``act``)


DetPolicyFn = Callable[..., jax.Array]
QFn = Callable[..., jax.Array]


def ddpg_critic_loss(
    critic_params,
    state: DDPGState,
    batch: Transition,
    mask,
    hyper: DDPGHyper,
    policy_fn: DetPolicyFn,
    q_fn: QFn,
):
    """TD regression of the centralised critic on the target actors' next action."""
    consts = state.consts
    next_q = q_fn(
        state.target_critic,
        consts,
        batch.next_obs,
        policy_fn(state.target_actor, consts, batch.next_obs),
        mask,
    )
    y = hyper.reward_scale * batch.reward + hyper.gamma * continuation(batch) * next_q
    q = q_fn(critic_params, consts, batch.obs, batch.action, mask)
    return 0.5 * jnp.mean((q - jax.lax.stop_gradient(y)) ** 2), jnp.mean(q)


def ddpg_actor_loss(
    actor_params, state: DDPGState, batch: Transition, mask, policy_fn: DetPolicyFn, q_fn: QFn
):
    """-Q(o, mu(o)); masked agents' actions never reach the critic, so their actors get zero
    gradient."""
    return -jnp.mean(
        q_fn(
            state.critic,
            state.consts,
            batch.obs,
            policy_fn(actor_params, state.consts, batch.obs),
            mask,
        )
    )


def make_ddpg_update(
    policy_fn: DetPolicyFn,
    q_fn: QFn,
    actor_opt: optax.GradientTransformation,
    critic_opt: optax.GradientTransformation,
):
    """Returns ``update(state, batch, key, hyper) -> (state, metrics)`` (pure; jit or scan it);
    ``metrics``: ``critic_loss``, ``actor_loss`` and ``q_mean``, each ``[]``."""

    def update(state: DDPGState, batch: Transition, key: jax.Array, hyper: DDPGHyper):
        mask = state.consts.valid[None, :] & batch.active
        (c_loss, q_mean), c_grads = jax.value_and_grad(ddpg_critic_loss, has_aux=True)(
            state.critic, state, batch, mask, hyper, policy_fn, q_fn
        )
        c_updates, critic_opt_state = critic_opt.update(c_grads, state.critic_opt, state.critic)
        critic = optax.apply_updates(state.critic, c_updates)
        state = state.replace(critic=critic, critic_opt=critic_opt_state)

        a_loss, a_grads = jax.value_and_grad(ddpg_actor_loss)(
            state.actor, state, batch, mask, policy_fn, q_fn
        )
        a_updates, actor_opt_state = actor_opt.update(a_grads, state.actor_opt, state.actor)
        actor = optax.apply_updates(state.actor, a_updates)

        state = state.replace(
            actor=actor,
            actor_opt=actor_opt_state,
            target_actor=optax.incremental_update(actor, state.target_actor, hyper.tau),
            target_critic=optax.incremental_update(critic, state.target_critic, hyper.tau),
        )
        return state, {"critic_loss": c_loss, "actor_loss": a_loss, "q_mean": q_mean}

    return update
