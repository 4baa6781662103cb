"""Pieces the multi-agent baselines share: per-agent stacked MLPs, optimisers (with the transfer
freeze of old agents), array hyperparameters, and the SAC-based builder.

Every baseline keeps its per-agent parameters under an ``agents`` key with a leading agent
axis (``networks.stacked``), like SCORE's actors, so ``agents.growth.grow_stacked`` can add
sub-spaces. MADDPG, MAAC and QMIX can instead be built for every sub-space of the space with a
transfer variant (``MarlVariant``, ``agents.variants``).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from score_jax.agents import variants
from score_jax.agents.base import (
    AgentConsts,
    Algorithm,
    BuildContext,
    CriticKind,
    OffPolicyAlgorithm,
    agent_consts,
    deterministic_policy,
)
from score_jax.agents.growth import agent_rows, freeze_agent_rows, grow_stacked, identity_plan
from score_jax.agents.marl.config import MarlConfig
from score_jax.agents.sac.state import SACHyper, SACState
from score_jax.agents.sac.update import make_sac_update
from score_jax.core.spaces import CompositeSpace, pad_width
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
        pessimism=f(m.critic_pessimism),
    )


def adam(m: MarlConfig, lr: float, trainable=None) -> optax.GradientTransformation:
    """Clipped Adam; with ``trainable`` the rows (leading agent axis) of frozen agents get zero
    updates."""
    parts = [optax.clip_by_global_norm(m.grad_clip), optax.adam(lr)]
    if trainable is not None:
        parts.append(freeze_agent_rows(trainable))
    return optax.chain(*parts)


def sac_optimizers(m: MarlConfig, ctx: BuildContext, frozen_alpha=None):
    """(actor, critic, alpha) optimisers of ISAC and MAAC; in a transfer run the old agents'
    actors are frozen; ``frozen_alpha [n]`` (bool): temperatures that get zero updates."""
    alpha = optax.adam(m.alpha_lr)
    if frozen_alpha is not None:
        alpha = optax.chain(alpha, freeze_agent_rows(~np.asarray(frozen_alpha, bool)))
    return adam(m, m.actor_lr, ctx.trainable), adam(m, m.critic_lr), alpha


@dataclasses.dataclass(frozen=True)
class MarlVariant:
    """A multi-agent baseline built for every sub-space of ``space`` while its run controls only
    ``agent_index`` (a transfer variant, §5.4 Table 3; ``agents.variants``).

    The run layer sees the run's agents only (replay ``[B, k, w]``, ``act -> [B, k, w]``:
    ``rows``); the sub-spaces outside it get their defaults in the environment. The algorithm
    sees every sub-space: ``update`` lifts each replay batch to all of them with the defaults
    the environment received (``variants.lift_batch``), ``critic`` evaluates a critic on what
    the environment would receive (``variants.pass_unseen``: the unseen agents' actions
    replaced by their defaults in value, their actors still in the gradient), ``params``
    freezes the unseen agents' rows (``plain``) and ``output`` adds the ``penalty`` term on
    their deterministic sub-actions (``deviation``). In a run that controls every sub-space
    (a transfer run) every wrapper is the identity.
    """

    variant: str
    coef: float
    space: CompositeSpace
    agent_index: np.ndarray
    width: int

    @property
    def seen(self) -> np.ndarray:
        return variants.seen_mask(self.space, self.agent_index)

    @property
    def unseen(self) -> np.ndarray:
        return ~self.seen

    @property
    def subset(self) -> bool:
        """Whether some sub-space is unseen (else every wrapper is the identity)."""
        return bool(self.unseen.any())

    def context(self, ctx: BuildContext) -> BuildContext:
        """``ctx`` for the networks: every sub-space an agent (unseen ones trainable and, like
        the brax baselines' unseen heads, without the default prior: after transfer they are
        the new sub-spaces' actors, which start untrained, §4.3)."""
        trainable = None
        if ctx.trainable is not None:
            trainable = np.ones(self.space.n, bool)
            trainable[np.asarray(self.agent_index)] = ctx.trainable
        prior = np.zeros(self.space.n, bool)
        prior[np.asarray(self.agent_index)] = ctx.prior_mask
        return dataclasses.replace(
            ctx, agent_index=np.arange(self.space.n), trainable=trainable, prior=prior
        )

    def rows(self, action: jax.Array) -> jax.Array:
        """``[B, n, w] -> [B, k, w]``: the run's agents."""
        return action[:, np.asarray(self.agent_index)] if self.subset else action

    def update(self, update):
        """``update`` on replay batches lifted to every sub-space."""
        if not self.subset:
            return update
        lift = lambda batch: variants.lift_batch(self.space, batch, self.agent_index, self.seen)
        return lambda state, batch, key, hyper: update(state, lift(batch), key, hyper)

    def critic(self, q_fn):
        """``q_fn(params, consts, obs, action [B, n, w], mask)`` on what the environment
        receives."""
        if not self.subset:
            return q_fn
        return lambda params, consts, obs, action, mask: q_fn(
            params, consts, obs, variants.pass_unseen(self.space, action, self.seen), mask
        )

    def params(self, params, head_mask=None):
        """A policy's parameters: ``plain`` freezes the unseen agents' rows (``head_mask``,
        default every per-agent leaf's rows, ``variants.agent_rows``)."""
        if not self.subset:
            return params
        mask = head_mask or (lambda p: variants.agent_rows(p, self.unseen))
        return variants.variant_params(params, self.variant, mask)

    def output(self, out: jax.Array, deviation=None, on=None) -> jax.Array:
        """A policy's output, carrying the ``penalty`` term of ``deviation(on or out) [B]``
        (default: ``variants.agent_deviation`` of a ``[B, n, w]`` action)."""
        if not self.subset:
            return out
        return variants.variant_output(
            out, self.variant, deviation or self.deviation, self.coef, on
        )

    def deviation(self, action: jax.Array) -> jax.Array:
        """``[B, n, w] -> [B]`` summed squared deviation of the unseen agents' sub-actions from
        their defaults."""
        default = pad_width(self.space.default_action(), self.width, 0.0)
        dim_mask = pad_width(jnp.asarray(self.space.dim_mask), self.width, False)
        return variants.agent_deviation(action, default, dim_mask, self.unseen)

    def grow(self, grow):
        """Transfer keeps every agent where it is (the networks already have them all):
        ``grow(source, template, plan, key)`` with the identity plan."""
        return lambda src, template, p, key: grow(src, template, identity_plan(self.space.n), key)


def marl_variant(ctx: BuildContext, default: str | None = None) -> MarlVariant | None:
    """The run's transfer variant (``ctx.transfer_variant``, else ``default``); None: none."""
    name = ctx.transfer_variant or default
    if name is None:
        return None
    variants.check_variant(name)
    return MarlVariant(name, ctx.penalty_coef, ctx.space, np.asarray(ctx.agent_index), ctx.width)


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
    name: str,
    networks_cls: type[SACAgentNetworks],
    m: MarlConfig,
    ctx: BuildContext,
    variant: MarlVariant | None = None,
) -> Algorithm:
    """A SAC-based baseline (``networks_cls``: a ``SACAgentNetworks``) on the shared SAC update;
    with a ``variant``, built for every sub-space (``MarlVariant``; ``plain`` also freezes the
    unseen agents' temperatures, which a frozen actor's fixed entropy would otherwise drive
    without end)."""
    net_ctx = ctx if variant is None else variant.context(ctx)
    nets = networks_cls.for_context(m, net_ctx)
    consts = marl_consts(m, net_ctx)
    plain = variant is not None and variant.subset and variant.variant == "plain"
    optimizers = sac_optimizers(m, net_ctx, variant.unseen if plain else None)
    policy_fn, q_fn, grow, rows = nets.policy_fn, nets.q_fn, grow_sac, lambda a: a
    if variant is not None:

        def policy_fn(actor_params, consts, obs, key, deterministic=False):
            actor_params = variant.params(actor_params)
            action, logp = nets.policy_fn(actor_params, consts, obs, key, deterministic)
            if variant.subset and variant.variant == "penalty":  # on the deterministic action
                det = nets.policy_fn(actor_params, consts, obs, key, True)[0]
                action = variant.output(action, on=det)
            return action, logp

        q_fn, grow, rows = variant.critic(nets.q_fn), variant.grow(grow_sac), variant.rows

    def act(state, obs, key, deterministic):
        return rows(nets.policy_fn(state.actor, state.consts, obs, key, deterministic)[0])

    init = lambda k, frozen=None: nets.init(k, consts, optimizers)
    kind: CriticKind = nets.critic_kind
    update = make_sac_update(policy_fn, q_fn, *optimizers, critic=kind)
    if variant is not None:
        update = variant.update(update)
    return make_algorithm(name, init, act, update, sac_hyper(m, ctx.env), ctx, nets, grow)
