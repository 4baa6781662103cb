"""MADDPG (Lowe et al. 2017; §5.1): deterministic per-sub-space actors, one centralised critic.

- Actors mu_i(o): SCORE's stacked actor networks read deterministically: ``tanh(mean)`` on
  continuous dims and the arg-max grid value on discrete dims, whose gradient flows through
  the softmax relaxation (straight-through, paper footnote 3, as MADDPG/MAAC do for discrete
  actions). Their log-std outputs are unused.
- Exploration: Gaussian noise (``MarlConfig.maddpg_noise``, an array in the state) on the
  continuous dims, clipped to [-1, 1]; discrete dims are Gumbel-max samples of the logits.
- Critic: one MLP Q(o, a) over the observation, all agents' sub-actions flattened to
  ``[n * width]`` with masked (failed, invalid) agents zeroed, and the mask itself (so a zeroed
  agent differs from one that chose 0). With the team reward, MADDPG's per-agent critics
  Q_i(o, a_1..a_n) all regress on the same target, so one critic is the same model.
- Update: DDPG with target actors and a target critic (``ddpg.py``), no twin critics.

The critic's input layer has one slot per sub-space, so MADDPG cannot grow by unseen
sub-spaces: it is a fixed-width baseline, always built for every sub-space of the space, and a
``--subspaces`` run treats the unseen ones with its transfer variant (``mc.MarlVariant``,
``--single.transfer-variant``, default ``plain``; Table 3). Transfer then fine-tunes the same
networks on the full space (``keep_ddpg``).
"""

from __future__ import annotations

import dataclasses

import flax.linen as nn
import jax
import jax.numpy as jnp

from score_jax.agents.base import AgentConsts, Algorithm, BuildContext
from score_jax.agents.marl import common as mc
from score_jax.agents.marl.config import MarlConfig
from score_jax.agents.marl.ddpg import DDPGHyper, DDPGState, make_ddpg_update
from score_jax.networks.actor import actor_policy
from score_jax.networks.mlp import MLP


class CentralCritic(nn.Module):
    """``obs [obs], action [n, w], mask [n] -> q []`` over the flattened, masked joint action."""

    hidden: tuple[int, ...]

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array, mask: jax.Array) -> jax.Array:
        joint = jnp.where(mask[:, None], action, 0.0).reshape(-1)
        return MLP(tuple(self.hidden), 1, name="q")(
            jnp.concatenate([obs, joint, mask.astype(obs.dtype)])
        )[0]


@dataclasses.dataclass(frozen=True)
class MADDPGNetworks(mc.AgentNetworks):
    """Static structure of MADDPG for one (observation size, agent count, width)."""

    @property
    def critic(self) -> CentralCritic:
        return CentralCritic(tuple(self.config.critic_hidden))

    def policy_fn(self, actor_params, consts: AgentConsts, obs):
        """``obs [B, obs] -> action [B, n, w]``: mu(o), differentiable (straight-through on
        discrete dims)."""
        return actor_policy(self.actors, actor_params, consts, obs, jax.random.PRNGKey(0), True)[0]

    def explore(self, actor_params, consts: AgentConsts, obs, key, noise_std):
        """``obs [B, obs] -> action [B, n, w]``: mu(o) + clipped Gaussian noise; Gumbel-max
        discrete dims."""
        key_gumbel, key_noise = jax.random.split(key)
        det = self.policy_fn(actor_params, consts, obs)
        sampled = actor_policy(self.actors, actor_params, consts, obs, key_gumbel, False)[0]
        noisy = jnp.clip(det + noise_std * jax.random.normal(key_noise, det.shape), -1.0, 1.0)
        continuous = consts.dim_mask & (consts.n_choices <= 0) & consts.valid[:, None]
        return jnp.where(continuous[None], noisy, sampled)

    def q_fn(self, critic_params, consts: AgentConsts, obs, action, mask):
        """``[B, obs], [B, n, w], [B, n] -> [B]`` centralised Q over the agents in
        ``mask & valid``."""
        return jax.vmap(
            lambda o, a, m: self.critic.apply({"params": critic_params}, o, a, m & consts.valid)
        )(obs, action, mask)

    def init(self, key: jax.Array, consts: AgentConsts, optimizers, noise_std: float) -> DDPGState:
        key_actor, key_critic = jax.random.split(key)
        obs = jnp.zeros(self.obs_size)
        actor = self.actors.init(key_actor, obs)["params"]
        critic = self.critic.init(
            key_critic, obs, jnp.zeros((self.n_agents, self.width)), consts.valid
        )["params"]
        actor_opt, critic_opt = optimizers
        return DDPGState(
            actor,
            critic,
            actor,
            critic,
            actor_opt.init(actor),
            critic_opt.init(critic),
            consts,
            jnp.float32(noise_std),
        )


def keep_ddpg(src: DDPGState, template: DDPGState, p, key: jax.Array) -> DDPGState:
    """Transfer of MADDPG (its networks already cover every sub-space, ``p`` keeps every agent
    where it is): the trained actors, critic and targets; optimiser states, constants and noise
    are the fine-tuning run's fresh ones."""
    del p, key
    return template.replace(
        actor=src.actor,
        critic=src.critic,
        target_actor=src.target_actor,
        target_critic=src.target_critic,
    )


def make_maddpg(m: MarlConfig, ctx: BuildContext) -> Algorithm:
    """MADDPG for every sub-space of ``ctx.env`` controlling ``ctx.agent_index`` (the others at
    their defaults, treated with the transfer variant)."""
    variant = mc.marl_variant(ctx, default="plain")
    net_ctx = variant.context(ctx)
    nets = MADDPGNetworks.for_context(m, net_ctx)
    consts = mc.marl_consts(m, net_ctx)
    optimizers = (mc.adam(m, m.actor_lr, net_ctx.trainable), mc.adam(m, m.critic_lr))
    policy_fn = lambda actor, consts, obs: variant.output(
        nets.policy_fn(variant.params(actor), consts, obs)
    )
    update = variant.update(make_ddpg_update(policy_fn, variant.critic(nets.q_fn), *optimizers))

    def act(state: DDPGState, obs, key, deterministic):
        if deterministic:
            return variant.rows(nets.policy_fn(state.actor, state.consts, obs))
        return variant.rows(nets.explore(state.actor, state.consts, obs, key, state.noise_std))

    f = lambda x: jnp.asarray(x, jnp.float32)
    hyper = DDPGHyper(
        gamma=f(m.gamma), tau=f(m.tau), reward_scale=f(m.resolved_reward_scale(ctx.env))
    )
    init = lambda k, frozen=None: nets.init(k, consts, optimizers, m.maddpg_noise)
    return mc.make_algorithm("maddpg", init, act, update, hyper, ctx, nets, variant.grow(keep_ddpg))
