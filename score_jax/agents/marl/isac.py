"""ISAC: independent soft actor-critic, one learner per sub-action space (§5.1).

Every sub-space i is an agent with its own SAC actor pi_i(a_i | o) (SCORE's stacked actors)
and its own twin critic Q_i(o, a_i) that sees only its own sub-action; all agents regress on
the team reward r:

    y_i  = r + gamma (1 - d) (min_j Q'_ij(o', a'_i) - alpha_i log pi_i(a'_i | o')),
           a'_i ~ pi_i(o')
    L_Q  = sum_{i active} sum_j (Q_ij(o, a_i) - y_i)^2 / 2,
    L_pi = sum_{i active} alpha_i log pi_i - min_j Q_ij

(``agents.sac`` with ``per_agent`` critics). Failed, padded and invalid agents (``batch.active``,
``consts.valid``) drop out of both sums, so they get exactly zero gradient. Because nothing
couples the agents, transfer to unseen sub-spaces only adds agents (§5.2.4).
"""

from __future__ import annotations

import dataclasses

import flax.linen as nn
import jax
import jax.numpy as jnp

from score_jax.agents.base import AgentConsts, Algorithm, BuildContext
from score_jax.agents.marl import common as mc
from score_jax.agents.marl.config import MarlConfig


class IndependentCritics(nn.Module):
    """Twin per-agent critics: ``obs [obs], action [n, w] -> q [2, n]`` with Q_ij = Q_ij(o, a_i)."""

    n_agents: int
    hidden: tuple[int, ...]

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
        x = mc.per_agent_input(obs, action)
        q1 = mc.StackedMLP(self.n_agents, self.hidden, 1, name="q1")(x)[:, 0]
        q2 = mc.StackedMLP(self.n_agents, self.hidden, 1, name="q2")(x)[:, 0]
        return jnp.stack([q1, q2])


@dataclasses.dataclass(frozen=True)
class ISACNetworks(mc.SACAgentNetworks):
    """ISAC's stacked actors and per-agent twin critics."""

    @property
    def critic(self) -> IndependentCritics:
        return IndependentCritics(self.n_agents, tuple(self.config.critic_hidden))

    def q_fn(self, critic_params, consts: AgentConsts, obs, action, mask):
        """``[B, obs], [B, n, w], [B, n] -> [B, 2, n]``; Q_i ignores every other agent (and the
        mask)."""
        return jax.vmap(lambda o, a: self.critic.apply({"params": critic_params}, o, a))(
            obs, action
        )

    def init_critic(self, key: jax.Array, consts: AgentConsts):
        return self.critic.init(
            key, jnp.zeros(self.obs_size), jnp.zeros((self.n_agents, self.width))
        )["params"]


def make_isac(m: MarlConfig, ctx: BuildContext) -> Algorithm:
    """ISAC on the sub-spaces ``ctx.agent_index`` of ``ctx.env``."""
    if ctx.transfer_variant is not None:
        raise ValueError("isac has no transfer variants: its transfer adds agents (§5.2.4)")
    return mc.make_sac_baseline("isac", ISACNetworks, m, ctx)
