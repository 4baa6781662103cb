"""SCORE's networks and update (§4.2, Alg. 1): the hypernetwork GAT twin critic over the frozen
ASRL encoders, the per-sub-space SAC actors, and their optimisers.

With ``critic.asrl=False`` the encoders are trained from scratch inside the critic and the
sub-space codes c_i are free parameters learned with the critic; with ``critic.finetune_asrl``
the critic's encoders start as the HVAE's and train with it (the codes c_i stay ASRL's).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct

from score_jax.agents.base import AgentConsts
from score_jax.agents.sac.state import SACHyper, SACState
from score_jax.agents.sac.update import make_sac_update
from score_jax.agents.score.config import ScoreConfig
from score_jax.networks.actor import Actors, actor_policy
from score_jax.networks.critic import AgentEmbeddings, GraphCritic, TwinCritic
from score_jax.networks.hvae import HVAE


def random_space_codes(key: jax.Array, n: int, c_dim: int) -> jax.Array:
    """``[n, c_dim]`` fixed N(0, I) codes: a stand-in for c_i when ASRL is switched off."""
    return jax.random.normal(key, (n, c_dim))


@struct.dataclass
class CriticVars:
    """Trainable critic variables: the twin network, and c_i when ASRL is off (else None)."""

    net: Any
    c: Any


@struct.dataclass
class FrozenInputs:
    """The frozen ASRL outputs the critic reads (None fields when ASRL is off)."""

    hvae_params: Any
    c: Any


@dataclasses.dataclass(frozen=True)
class ScoreNetworks:
    """Static structure of SCORE for one (observation size, agent count, width)."""

    config: ScoreConfig
    obs_size: int
    n_agents: int
    width: int
    max_choices: int
    discrete_width: int = 0

    @property
    def actors(self) -> Actors:
        return Actors(
            self.config.actor, self.n_agents, self.width, self.max_choices, self.discrete_width
        )

    @property
    def critic(self) -> TwinCritic:
        return TwinCritic(self.config.critic, self.config.hvae, self.obs_size, self.width)

    @property
    def hvae(self) -> HVAE:
        return HVAE(self.config.hvae, self.obs_size, self.width)

    def policy_fn(self, actor_params, consts: AgentConsts, obs, key, deterministic=False):
        """``obs [B, obs] -> (action [B, n, w], log_prob [B, n])`` (Alg. 1 line 2)."""
        return actor_policy(self.actors, actor_params, consts, obs, key, deterministic)

    def q_fn(self, critic: CriticVars, consts: AgentConsts, obs, action, mask):
        """``[B, obs], [B, n, w], [B, n] -> [B, 2]`` twin Q-values (§4.2)."""
        frozen: FrozenInputs = consts.critic_inputs
        c = frozen.c if self.config.critic.asrl else critic.c
        apply = lambda o, a, m: self.critic.apply(
            {"params": critic.net}, o, a, consts.dim_mask, c, m & consts.valid, frozen.hvae_params
        )
        return jax.vmap(apply)(obs, action, mask)

    def agent_embeddings(
        self, critic: CriticVars, consts: AgentConsts, obs, action, mask
    ) -> AgentEmbeddings:
        """The twin critics' agent embeddings (Fig. 12) for the inputs of ``q_fn``:
        ``[B, obs], [B, n, w], [B, n] -> AgentEmbeddings`` with ``[B, 2, n, agent_dim]`` fields
        (axis 1: the twin). Each twin's ``GraphCritic`` is applied to its slice of the stacked
        parameters, the same computation ``q_fn`` runs."""
        frozen: FrozenInputs = consts.critic_inputs
        c = frozen.c if self.config.critic.asrl else critic.c
        one = GraphCritic(self.config.critic, self.config.hvae, self.obs_size, self.width)

        def apply(params, o, a, m):
            return one.apply(
                {"params": params},
                o,
                a,
                consts.dim_mask,
                c,
                m & consts.valid,
                frozen.hvae_params,
                method=GraphCritic.embeddings,
            )

        twins = jax.vmap(apply, in_axes=(0, None, None, None))  # over the twins' stacked params
        return jax.vmap(twins, in_axes=(None, 0, 0, 0))(critic.net["critics"], obs, action, mask)


def with_asrl_encoders(net: Any, hvae_params: Any) -> Any:
    """The twin critic's params ``net`` with both twins' own encoders (``critics/encoder``, the
    modules the critic calls: q_phi's state encoder and q_psi) replaced by the trained HVAE's, so
    fine-tuning (``CriticConfig.finetune_asrl``) starts from ASRL's representation."""
    twins = net["critics"]
    own = twins["encoder"]
    copied = {
        name: jax.tree.map(lambda leaf, src: jnp.broadcast_to(src, leaf.shape), own[name], hvae)
        for name, hvae in ((name, hvae_params[name]) for name in own)
    }
    return {**net, "critics": {**twins, "encoder": copied}}


def make_optimizers(cfg: ScoreConfig):
    clip = optax.clip_by_global_norm(cfg.grad_clip)
    return (
        optax.chain(clip, optax.adam(cfg.actor_lr)),
        optax.chain(clip, optax.adam(cfg.critic_lr)),
        optax.adam(cfg.alpha_lr),
    )


def init_state(
    nets: ScoreNetworks, key: jax.Array, consts: AgentConsts, optimizers=None
) -> SACState:
    """Fresh actor/critic parameters, targets, optimiser states and log alpha."""
    cfg = nets.config
    key_actor, key_critic, key_c = jax.random.split(key, 3)
    obs = jnp.zeros(nets.obs_size)
    actions = jnp.zeros((nets.n_agents, nets.width))
    actor = nets.actors.init(key_actor, obs)["params"]
    free_c = (
        None
        if cfg.critic.asrl
        else random_space_codes(key_c, nets.n_agents, cfg.hvae.space_embed_dim)
    )
    c = consts.critic_inputs.c if cfg.critic.asrl else free_c
    net = nets.critic.init(
        key_critic, obs, actions, consts.dim_mask, c, consts.valid, consts.critic_inputs.hvae_params
    )["params"]
    if cfg.critic.asrl and cfg.critic.finetune_asrl:
        net = with_asrl_encoders(net, consts.critic_inputs.hvae_params)
    critic = CriticVars(net, free_c)
    actor_opt, critic_opt, alpha_opt = optimizers or make_optimizers(cfg)
    log_alpha = jnp.full(
        (nets.n_agents,), jnp.log(cfg.init_alpha), jnp.float32
    )  # one temperature per agent
    return SACState(
        actor=actor,
        critic=critic,
        target_critic=critic,
        log_alpha=log_alpha,
        actor_opt=actor_opt.init(actor),
        critic_opt=critic_opt.init(critic),
        alpha_opt=alpha_opt.init(log_alpha),
        consts=consts,
    )


def hyper(cfg: ScoreConfig, env) -> SACHyper:
    """The SAC scalars as arrays (the reward scale resolved against ``env.hints``)."""
    f = lambda x: jnp.asarray(x, jnp.float32)
    return SACHyper(
        gamma=f(cfg.gamma),
        tau=f(cfg.tau),
        dropnode_prob=f(cfg.dropnode_prob),
        reward_scale=f(cfg.resolved_reward_scale(env)),
        pessimism=f(cfg.critic_pessimism),
    )


def make_update(nets: ScoreNetworks, optimizers=None):
    """The one-jit SAC update of Alg. 1 lines 11-15 for these networks."""
    return make_sac_update(
        nets.policy_fn,
        nets.q_fn,
        *(optimizers or make_optimizers(nets.config)),
        critic="centralised",
    )
