"""SCORE's transfer to unseen sub-action spaces (§4.3, Fig. 5).

Starting from a run trained on a subset of sub-spaces:
1. embed the unseen sub-spaces with the FROZEN HVAE (their observation sets are collected in
   the environment that now has them; ``asrl.embed_new_spaces``);
2. grow the agent axis: the old actors keep their parameters, the new actors start fresh
   (untrained: no default prior, so mid-range with uniform choices, unless the transfer asks
   for it with ``TransferSpec.new_actor_prior``; the grown run's ``AgentConsts`` say which
   actors act around their default); the agents are re-ordered into the space's order, so the
   result is an ordinary run over the new sub-space set (the graph critic is permutation
   invariant);
3. fine-tune only p_w, the GAT (or its hypernetwork) and f_xi of the critic (and the critic's
   own encoders with ``finetune_critic_encoder``), train the new actors, and keep the old
   actors frozen (or fine-tune them with ``finetune_old_actors``).

Frozen parameters get exactly zero updates, so they stay bitwise unchanged.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax

from score_jax.agents.growth import TransferPlan, agent_rows, freeze_agent_rows
from score_jax.agents.sac.state import SACState
from score_jax.agents.score.asrl import embed_new_spaces
from score_jax.agents.score.config import ScoreConfig
from score_jax.agents.score.networks import ScoreNetworks
from score_jax.networks.actor import grow_agents, select_agents
from score_jax.networks.critic import finetune_mask


def transfer_optimizers(cfg: ScoreConfig, trainable_agents, finetune_encoder: bool = False):
    """(actor, critic, alpha) optimisers of a fine-tuning run (§4.3).

    Actors: Adam, then the rows of frozen agents zeroed. Critic: Adam on p_w, GAT / hypernet
    and f_xi (and the free codes c_i when ASRL is off, and the critic's own encoders with
    ``finetune_encoder``); every other subtree frozen.
    """
    clip = optax.clip_by_global_norm(cfg.grad_clip)
    actor_opt = optax.chain(clip, optax.adam(cfg.actor_lr), freeze_agent_rows(trainable_agents))

    def labels(critic_vars):
        net = jax.tree.map(
            lambda t: "train" if t else "freeze", finetune_mask(critic_vars.net, finetune_encoder)
        )
        c = None if critic_vars.c is None else jax.tree.map(lambda _: "train", critic_vars.c)
        return critic_vars.replace(net=net, c=c)

    critic_opt = optax.multi_transform(
        {"train": optax.chain(clip, optax.adam(cfg.critic_lr)), "freeze": optax.set_to_zero()},
        labels,
    )
    return actor_opt, critic_opt, optax.adam(cfg.alpha_lr)


def grow_agent(
    source: SACState, template: SACState, p: TransferPlan, new_c, key: jax.Array
) -> SACState:
    """The grown algorithm state: old actors and critic from ``source``, fresh new actors.

    ``template`` is a fresh state of the grown run (right shapes, fresh optimiser states of
    the fine-tuning optimisers, and its constants: which agents have the default prior);
    ``new_c`` ``[n_new, c_dim]`` are the frozen-HVAE embeddings
    of the new sub-spaces (None when ASRL is off).
    """
    n_src = jax.tree.leaves(source.actor)[0].shape[0]
    pick = agent_rows(p, n_src)
    actor = select_agents(grow_agents(source.actor, template.actor), pick)
    new_rank = np.cumsum(p.is_new) - 1  # index among the new sub-spaces
    pick_c = np.where(p.is_new, n_src + new_rank, p.source_row)
    frozen = template.consts.critic_inputs
    if frozen.c is not None:
        c_all = jnp.concatenate([source.consts.critic_inputs.c, new_c], 0)[pick_c]
        frozen = frozen.replace(hvae_params=source.consts.critic_inputs.hvae_params, c=c_all)

    def grow_free_c(src_c):  # ASRL off: the learned codes of old agents, fresh codes for new ones
        return None if src_c is None else jnp.concatenate([src_c, template.critic.c], 0)[pick]

    critic = source.critic.replace(c=grow_free_c(source.critic.c))
    target = source.target_critic.replace(c=grow_free_c(source.target_critic.c))
    return template.replace(
        actor=actor,
        critic=critic,
        target_critic=target,
        log_alpha=jnp.concatenate([source.log_alpha, template.log_alpha])[pick],
        consts=template.consts.replace(critic_inputs=frozen),
    )


def embed_new(source: SACState, nets: ScoreNetworks, env, p: TransferPlan, key: jax.Array):
    """Frozen-HVAE embeddings ``[n_new, c_dim]`` of the new sub-spaces (None when ASRL is off).

    ``source`` is the trained run's agent state (its frozen HVAE parameters), ``nets`` the
    grown run's networks (same HVAE), ``env`` the environment that now has the new sub-spaces.
    """
    sc = nets.config
    if not sc.critic.asrl:
        return None
    params = source.consts.critic_inputs.hvae_params
    new = [int(i) for i in p.agent_index[p.is_new]]
    return embed_new_spaces(env, nets.hvae, params, key, new, sc.asrl_k, sc.asrl_j)
