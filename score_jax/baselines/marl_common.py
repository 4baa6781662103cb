"""Pieces the multi-agent baselines share: per-agent stacked MLPs, agent constants, optimisers
(with the transfer freeze of old agents), array hyperparameters, and the ``Algorithm`` wrapper.

Every baseline keeps its per-agent parameters under an ``agents`` key with a leading agent
axis (``nn.vmap``), like SCORE's actors, so ``transfer.grow_stacked`` can add sub-spaces.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from score_jax import score
from score_jax.algorithms import Algorithm, action_width, discrete_width
from score_jax.networks.actor import Actors, actor_policy
from score_jax.networks.mlp import MLP
from score_jax.sac import AgentConsts, SACHyper, SACState, make_sac_update
from score_jax.trainer import OffPolicyAlgorithm


class StackedMLP(nn.Module):
    """n per-agent MLPs with their own weights, stacked on axis 0 under ``params["agents"]``.

    ``x [n, d_in] -> [n, out_dim]``: row i goes through agent i's MLP.
    """

    n_agents: int
    hidden: tuple[int, ...]
    out_dim: int

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        stacked = nn.vmap(MLP, variable_axes={"params": 0}, split_rngs={"params": True}, in_axes=0, out_axes=0, axis_size=self.n_agents)
        return stacked(tuple(self.hidden), self.out_dim, name="agents")(x)


def per_agent_input(obs: jax.Array, action: jax.Array) -> jax.Array:
    """``obs [obs], action [n, w] -> [n, obs + w]``: each agent sees the shared o and its own a_i."""
    return jnp.concatenate([jnp.broadcast_to(obs, (action.shape[0], obs.shape[-1])), action], -1)


def agent_consts(env, agent_index, width: int) -> AgentConsts:
    """Per-agent masks, grid sizes, entropy targets and defaults (no frozen critic inputs)."""
    return score.agent_consts(env.space, agent_index, width, None)


def reward_scale(cfg, env) -> float:
    return cfg.marl.reward_scale or getattr(env, "reward_scale", 1.0)


def sac_hyper(cfg, env) -> SACHyper:
    """The SAC hyperparameters of ISAC and MAAC as arrays (no DropNode: that is SCORE's)."""
    m, f = cfg.marl, lambda x: jnp.asarray(x, jnp.float32)
    return SACHyper(gamma=f(m.gamma), tau=f(m.tau), dropnode_prob=f(0.0), reward_scale=f(reward_scale(cfg, env)))


def trainable_agents(cfg, env, agent_index) -> np.ndarray | None:
    """In a transfer run (§4.3): ``[n]`` True for the agents that train (new sub-spaces, or all
    with ``finetune_old_actors``); None in an ordinary run."""
    if not cfg.transfer_new:
        return None
    new = set(cfg.transfer_new.split(","))
    return np.asarray([cfg.finetune_old_actors or env.space.names[i] in new for i in agent_index])


def adam(cfg, lr: float, trainable=None) -> optax.GradientTransformation:
    """Clipped Adam; with ``trainable`` the rows (leading agent axis) of frozen agents get zero updates."""
    parts = [optax.clip_by_global_norm(cfg.marl.grad_clip), optax.adam(lr)]
    if trainable is not None:
        from score_jax.transfer import freeze_agent_rows

        parts.append(freeze_agent_rows(trainable))
    return optax.chain(*parts)


def sac_optimizers(cfg, env, agent_index):
    """(actor, critic, alpha) optimisers of ISAC and MAAC; in a transfer run the old agents' actors are frozen."""
    m = cfg.marl
    return adam(cfg, m.actor_lr, trainable_agents(cfg, env, agent_index)), adam(cfg, m.critic_lr), optax.adam(m.alpha_lr)


def init_sac_state(actor, critic, consts: AgentConsts, init_alpha: float, actor_opt, critic_opt, alpha_opt) -> SACState:
    n = consts.valid.shape[0]
    log_alpha = jnp.full((n,), jnp.log(init_alpha), jnp.float32)
    return SACState(
        actor=actor, critic=critic, target_critic=critic, log_alpha=log_alpha,
        actor_opt=actor_opt.init(actor), critic_opt=critic_opt.init(critic), alpha_opt=alpha_opt.init(log_alpha), consts=consts,
    )


def grow_sac(src_run, template: SACState, p, key: jax.Array) -> SACState:
    """Transfer (§4.3) for ISAC / MAAC: old agents keep their actors, per-agent critics and
    temperatures, new agents start fresh, shared critic parts (MAAC's attention) are kept;
    optimiser states and constants are the grown run's fresh ones."""
    from score_jax.transfer import agent_rows, grow_stacked

    src: SACState = src_run.state.agent
    rows = agent_rows(p, src.log_alpha.shape[0])
    return template.replace(
        actor=grow_stacked(src.actor, template.actor, p), critic=grow_stacked(src.critic, template.critic, p),
        target_critic=grow_stacked(src.target_critic, template.target_critic, p),
        log_alpha=jnp.concatenate([src.log_alpha, template.log_alpha])[rows],
    )


def make_algorithm(name: str, init, act: Callable, update, hyper: Any, n_agents: int, width: int, networks=None, grow=None) -> Algorithm:
    """Wrap ``act(state, obs, key, deterministic)`` etc. into an ``Algorithm`` whose evaluation
    policy is the deterministic ``act``."""
    off = OffPolicyAlgorithm(name, init, act, update, hyper, n_agents, width)
    policy = lambda agent: (lambda env_state, k: act(agent, env_state.obs, k, True))
    return Algorithm(name, off, policy, networks, grow)


@dataclasses.dataclass(frozen=True)
class AgentNetworks:
    """Static structure shared by the multi-agent baselines: one (observation size, agent
    count, width) and the stacked actors built from it."""

    config: Any  # MarlConfig
    obs_size: int
    n_agents: int
    width: int
    max_choices: int
    discrete_width: int

    @property
    def actors(self) -> Actors:
        return Actors(self.config.actor, self.n_agents, self.width, self.max_choices, self.discrete_width)


@dataclasses.dataclass(frozen=True)
class SACAgentNetworks(AgentNetworks):
    """Stacked SAC actors of a SAC-based baseline (ISAC, MAAC); subclasses add the critic
    (``critic`` module, ``q_fn`` and ``init_critic``)."""

    def policy_fn(self, actor_params, consts: AgentConsts, obs, key, deterministic=False):
        """``obs [B, obs] -> (action [B, n, w], log_prob [B, n])``."""
        return actor_policy(self.actors, actor_params, consts, obs, key, deterministic)

    def init(self, key: jax.Array, consts: AgentConsts, optimizers) -> SACState:
        key_actor, key_critic = jax.random.split(key)
        actor = self.actors.init(key_actor, jnp.zeros(self.obs_size))["params"]
        return init_sac_state(actor, self.init_critic(key_critic, consts), consts, self.config.init_alpha, *optimizers)


def make_sac_baseline(name: str, networks_cls, cfg, env, agent_index) -> Algorithm:
    """A SAC-based baseline (``networks_cls``: a ``SACAgentNetworks``) on the shared SAC update."""
    width = action_width(cfg, env)
    nets = networks_cls(cfg.marl, env.observation_size, len(agent_index), width, env.space.max_choices, discrete_width(env.space))
    consts = agent_consts(env, agent_index, width)
    optimizers = sac_optimizers(cfg, env, agent_index)

    def act(state, obs, key, deterministic):
        return nets.policy_fn(state.actor, state.consts, obs, key, deterministic)[0]

    init = lambda k: nets.init(k, consts, optimizers)
    update = make_sac_update(nets.policy_fn, nets.q_fn, *optimizers)
    return make_algorithm(name, init, act, update, sac_hyper(cfg, env), len(agent_index), width, nets, grow_sac)
