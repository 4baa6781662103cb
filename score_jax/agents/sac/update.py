"""The one-jit multi-agent SAC update (Alg. 1, lines 11-15), shared by SCORE, ISAC and MAAC.

Agent masks (``valid`` agents, failed sub-spaces and DropNode) are arrays inside the update,
so changing them never recompiles anything.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax

from score_jax.agents.base import CriticKind
from score_jax.agents.replay import Transition
from score_jax.agents.sac.losses import PolicyFn, QFn, actor_loss, alpha_loss, critic_loss
from score_jax.agents.sac.state import SACHyper, SACState
from score_jax.core.failures import dropnode_mask


def make_sac_update(
    policy_fn: PolicyFn,
    q_fn: QFn,
    actor_opt: optax.GradientTransformation,
    critic_opt: optax.GradientTransformation,
    alpha_opt: optax.GradientTransformation,
    critic: CriticKind = "centralised",
):
    """Returns ``update(state, batch, key, hyper) -> (state, metrics)`` (pure; jit it or scan it).

    Critics, all actors (one stacked parameter tree), alpha and the Polyak targets are updated
    in one function; the critic and actor losses both use the parameters the update starts
    from. The critic mask of each sample is ``valid & batch.active & DropNode``. ``metrics``:
    ``critic_loss``, ``actor_loss``, ``alpha`` (mean over agents), ``entropy`` (batch mean of
    -sum_i log pi_i over active agents) and ``q_mean``, each ``[]``.
    """
    if critic not in ("centralised", "per_agent"):
        raise ValueError(f"critic must be 'centralised' or 'per_agent', got {critic!r}")

    def update(state: SACState, batch: Transition, key: jax.Array, hyper: SACHyper):
        key_drop, key_critic, key_actor = jax.random.split(key, 3)
        b = batch.reward.shape[0]
        valid = state.consts.valid & batch.active
        mask = jax.vmap(dropnode_mask, in_axes=(0, 0, None))(
            jax.random.split(key_drop, b), valid, hyper.dropnode_prob
        )

        # Both losses read the critics of the start of the update (as brax's SAC does), so the
        # critic's state-side forward pass (SCORE: e_o and the hypernetwork's GAT weights of
        # o) is one computation shared by the two gradients.
        (c_loss, q_mean), c_grads = jax.value_and_grad(critic_loss, has_aux=True)(
            state.critic, state, batch, mask, key_critic, hyper, policy_fn, q_fn, critic
        )
        (a_loss, logp), a_grads = jax.value_and_grad(actor_loss, has_aux=True)(
            state.actor, state, batch, mask, key_actor, policy_fn, q_fn, critic, hyper.pessimism
        )
        c_updates, critic_opt_state = critic_opt.update(c_grads, state.critic_opt, state.critic)
        critic_params = optax.apply_updates(state.critic, c_updates)
        a_updates, actor_opt_state = actor_opt.update(a_grads, state.actor_opt, state.actor)
        actor = optax.apply_updates(state.actor, a_updates)

        al_grad = jax.grad(alpha_loss)(state.log_alpha, logp, mask, state.consts)
        al_update, alpha_opt_state = alpha_opt.update(al_grad, state.alpha_opt, state.log_alpha)
        log_alpha = optax.apply_updates(state.log_alpha, al_update)

        target = optax.incremental_update(critic_params, state.target_critic, hyper.tau)
        state = state.replace(
            actor=actor,
            critic=critic_params,
            target_critic=target,
            log_alpha=log_alpha,
            actor_opt=actor_opt_state,
            critic_opt=critic_opt_state,
            alpha_opt=alpha_opt_state,
        )
        metrics = {
            "critic_loss": c_loss,
            "actor_loss": a_loss,
            "alpha": jnp.mean(jnp.exp(log_alpha)),
            "entropy": -jnp.mean(jnp.sum(jnp.where(mask, logp, 0.0), -1)),
            "q_mean": q_mean,
        }
        return state, metrics

    return update
