"""Pieces the multi-agent baselines share: per-agent stacked MLPs, optimisers (with the transfer
freeze of old agents), array hyperparameters, and the SAC-based builder.

Every baseline keeps its per-agent parameters under an ``agents`` key with a leading agent
axis (``networks.stacked``), like SCORE's actors, so ``agents.growth.grow_stacked`` can add
sub-spaces.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax

from score_jax.agents.base import (
    AgentConsts,
    Algorithm,
    BuildContext,
    CriticKind,
    OffPolicyAlgorithm,
    agent_consts,
    deterministic_policy,
)
from score_jax.agents.growth import agent_rows, freeze_agent_rows, grow_stacked
from score_jax.agents.marl.config import MarlConfig
from score_jax.agents.sac.state import SACHyper, SACState
from score_jax.agents.sac.update import make_sac_update
from score_jax.networks.actor import Actors, actor_policy
from score_jax.networks.mlp import MLP
from score_jax.networks.stacked import stacked


class StackedMLP(nn.Module):
    """n per-agent MLPs with their own weights, stacked on axis 0 under ``params["agents"]``.

    ``x [n, d_in] -> [n, out_dim]``: row i goes through agent i's MLP.
    """

    n_agents: int
    hidden: tuple[int, ...]
    out_dim: int

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        return stacked(MLP, self.n_agents, in_axes=0)(
            tuple(self.hidden), self.out_dim, name="agents"
        )(x)


def per_agent_input(obs: jax.Array, action: jax.Array) -> jax.Array:
    """``obs [obs], action [n, w] -> [n, obs + w]``: each agent sees the shared o and its own
    a_i."""
    return jnp.concatenate([jnp.broadcast_to(obs, (action.shape[0], obs.shape[-1])), action], -1)


def marl_consts(m: MarlConfig, ctx: BuildContext) -> AgentConsts:
    """Per-agent masks, grid sizes, entropy targets and defaults with the agents' prior
    (``ctx.prior_mask``; no frozen critic inputs)."""
    return agent_consts(
        ctx.space, ctx.agent_index, ctx.width, None, m.entropy_targets, ctx.prior_mask
    )


def sac_hyper(m: MarlConfig, env) -> SACHyper:
    """The SAC hyperparameters of ISAC and MAAC as arrays (no DropNode: that is SCORE's)."""
    f = lambda x: jnp.asarray(x, jnp.float32)
    return SACHyper(
        gamma=f(m.gamma),
        tau=f(m.tau),
        dropnode_prob=f(0.0),
        reward_scale=f(m.resolved_reward_scale(env)),
    )


def adam(m: MarlConfig, lr: float, trainable=None) -> optax.GradientTransformation:
    """Clipped Adam; with ``trainable`` the rows (leading agent axis) of frozen agents get zero
    updates."""
    parts = [optax.clip_by_global_norm(m.grad_clip), optax.adam(lr)]
    if trainable is not None:
        parts.append(freeze_agent_rows(trainable))
    return optax.chain(*parts)


def sac_optimizers(m: MarlConfig, ctx: BuildContext):
    """(actor, critic, alpha) optimisers of ISAC and MAAC; in a transfer run the old agents'
    actors are frozen."""
    return adam(m, m.actor_lr, ctx.trainable), adam(m, m.critic_lr), optax.adam(m.alpha_lr)


def init_sac_state(
    actor, critic, consts: AgentConsts, init_alpha: float, actor_opt, critic_opt, alpha_opt
) -> SACState:
    n = consts.valid.shape[0]
    log_alpha = jnp.full((n,), jnp.log(init_alpha), jnp.float32)
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


def grow_sac(src: SACState, template: SACState, p, key: jax.Array) -> SACState:
    """Transfer (§4.3) for ISAC / MAAC: old agents keep their actors, per-agent critics and
    temperatures, new agents start fresh, shared critic parts (MAAC's attention) are kept;
    optimiser states and constants are the grown run's fresh ones (so whether a new actor has
    the default prior is the grown run's ``ctx.prior``, as for SCORE)."""
    rows = agent_rows(p, src.log_alpha.shape[0])
    return template.replace(
        actor=grow_stacked(src.actor, template.actor, p),
        critic=grow_stacked(src.critic, template.critic, p),
        target_critic=grow_stacked(src.target_critic, template.target_critic, p),
        log_alpha=jnp.concatenate([src.log_alpha, template.log_alpha])[rows],
    )


def make_algorithm(
    name: str, init, act, update, hyper: Any, ctx: BuildContext, networks=None, grow=None
) -> Algorithm:
    """Wrap ``act(state, obs, key, deterministic)`` etc. into an ``Algorithm`` whose evaluation
    policy is the deterministic ``act``."""
    off = OffPolicyAlgorithm(name, init, act, update, hyper, ctx.n_agents, ctx.width)
    return Algorithm(name, off, deterministic_policy(act), networks, grow)


@dataclasses.dataclass(frozen=True)
class AgentNetworks:
    """Static structure shared by the multi-agent baselines: one (observation size, agent
    count, width) and the stacked actors built from it."""

    config: MarlConfig
    obs_size: int
    n_agents: int
    width: int
    max_choices: int
    discrete_width: int

    @classmethod
    def for_context(cls, m: MarlConfig, ctx: BuildContext):
        return cls(
            m,
            ctx.env.observation_size,
            ctx.n_agents,
            ctx.width,
            ctx.space.max_choices,
            ctx.space.discrete_width,
        )

    @property
    def actors(self) -> Actors:
        return Actors(
            self.config.actor, self.n_agents, self.width, self.max_choices, self.discrete_width
        )


@dataclasses.dataclass(frozen=True)
class SACAgentNetworks(AgentNetworks):
    """Stacked SAC actors of a SAC-based baseline (ISAC, MAAC); subclasses add the critic
    (``critic`` module, ``q_fn`` and ``init_critic``) and say its ``critic_kind``."""

    critic_kind = "per_agent"

    def policy_fn(self, actor_params, consts: AgentConsts, obs, key, deterministic=False):
        """``obs [B, obs] -> (action [B, n, w], log_prob [B, n])``."""
        return actor_policy(self.actors, actor_params, consts, obs, key, deterministic)

    def init(self, key: jax.Array, consts: AgentConsts, optimizers) -> SACState:
        key_actor, key_critic = jax.random.split(key)
        actor = self.actors.init(key_actor, jnp.zeros(self.obs_size))["params"]
        return init_sac_state(
            actor, self.init_critic(key_critic, consts), consts, self.config.init_alpha, *optimizers
        )


def make_sac_baseline(
    name: str, networks_cls: type[SACAgentNetworks], m: MarlConfig, ctx: BuildContext
) -> Algorithm:
    """A SAC-based baseline (``networks_cls``: a ``SACAgentNetworks``) on the shared SAC update."""
    nets = networks_cls.for_context(m, ctx)
    consts = marl_consts(m, ctx)
    optimizers = sac_optimizers(m, ctx)

    def act(state, obs, key, deterministic):
        return nets.policy_fn(state.actor, state.consts, obs, key, deterministic)[0]

    init = lambda k, frozen=None: nets.init(k, consts, optimizers)
    kind: CriticKind = nets.critic_kind
    update = make_sac_update(nets.policy_fn, nets.q_fn, *optimizers, critic=kind)
    return make_algorithm(name, init, act, update, sac_hyper(m, ctx.env), ctx, nets, grow_sac)
