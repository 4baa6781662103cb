"""MAAC: multi-actor-attention-critic (Iqbal & Sha 2019; §5.1), on the shared SAC update.

Each sub-space i is an agent with a SAC actor pi_i(a_i | o) (SCORE's stacked actors) and its
own Q_i, computed by an attention critic (MAAC §3.2) for one sample:

    e_i     = LeakyReLU(g_i(o, a_i))                       per-agent one-layer encoder
    a_ij    = softmax_j( (W_k e_j)^T (W_q e_i) / sqrt(d_h) )   over the OTHER active agents j != i
    x_i     = sum_j a_ij LeakyReLU(V e_j)                  W_q, W_k, V shared; one set per head
    Q_i     = f_i(e_i, x_i)                                 per-agent MLP head

Failed, padded and invalid agents are removed from the attention with ``where``: they get
exactly zero weight and send nothing. One critic and its target, as in MAAC (no clipped
double Q), per-agent temperatures as in our SAC; all agents regress on the team reward
(``agents.sac``'s per-agent loss with ``q [B, 1, n]``).

Each actor is trained against its own Q_i only, as in MAAC: the senders' embeddings see the
other agents' actions through ``stop_gradient``, so dQ_i/da_j = 0 for j != i in the actor
loss (values and critic gradients are unchanged). Deviations, stated: the paper runs MAAC on
a discretised space; here the actors keep the composite space (tanh-Gaussian continuous
dims, straight-through Gumbel discrete dims, which is MAAC's own relaxation), so Q_i takes
a_i as an input instead of having one output per discrete action. MAAC's counterfactual
baseline reduces the variance of a score-function gradient; with the reparameterised SAC
gradient used here it has no effect and is left out.

Transfer (§5.2.4): a subset run grows by the unseen agents (``mc.grow_sac``); with
``--single.transfer-variant`` it is instead built for every sub-space and keeps them
(``mc.MarlVariant``, Table 3's MAAC-mask / MAAC-penalty).
"""

from __future__ import annotations

import dataclasses
import math

import flax.linen as nn
import jax
import jax.numpy as jnp

from score_jax.agents.base import AgentConsts, Algorithm, BuildContext
from score_jax.agents.marl import common as mc
from score_jax.agents.marl.config import MarlConfig


def masked_softmax(score: jax.Array, edge: jax.Array) -> jax.Array:
    """Softmax over the last axis restricted to ``edge``; masked entries are exactly 0 (a row
    without any edge is all 0). ``where`` only, so masked scores (even NaN) never leak."""
    top = jnp.max(jnp.where(edge, score, -jnp.inf), axis=-1, keepdims=True)
    top = jax.lax.stop_gradient(jnp.where(jnp.isfinite(top), top, 0.0))
    weight = jnp.where(edge, jnp.exp(jnp.where(edge, score - top, 0.0)), 0.0)
    total = jnp.sum(weight, axis=-1, keepdims=True)
    return weight / jnp.where(total > 0, total, 1.0)


class AttentionCritic(nn.Module):
    """One MAAC critic: ``obs [obs], action [n, w], mask [n] -> (q [n], attention [heads, n, n])``.

    ``attention[h, i, j]`` is agent i's weight on agent j; zero on the diagonal and for masked j.
    """

    n_agents: int
    embed_dim: int
    heads: int
    hidden: tuple[int, ...]

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array, mask: jax.Array):
        n, d, h = self.n_agents, self.embed_dim, self.heads
        encoder = mc.StackedMLP(n, (), d, name="encoder")
        embed = lambda a: nn.leaky_relu(encoder(mc.per_agent_input(obs, a)))
        e = embed(action)  # receivers: their own action, with gradient
        sender = jnp.where(mask[:, None], embed(jax.lax.stop_gradient(action)), 0.0)
        query = nn.Dense(d, use_bias=False, name="query")(e).reshape(n, h, d // h)
        key = nn.Dense(d, use_bias=False, name="key")(sender).reshape(n, h, d // h)
        value = nn.leaky_relu(nn.Dense(d, name="value")(sender)).reshape(n, h, d // h)
        score = jnp.einsum("ihc,jhc->hij", query, key) / math.sqrt(d // h)
        edge = (mask[None, :] & ~jnp.eye(n, dtype=bool))[None]  # [1, i, j]: active others
        attention = masked_softmax(score, edge)
        x = jnp.einsum("hij,jhc->ihc", attention, value).reshape(n, d)
        q = mc.StackedMLP(n, self.hidden, 1, name="head")(jnp.concatenate([e, x], -1))[:, 0]
        return q, attention


@dataclasses.dataclass(frozen=True)
class MAACNetworks(mc.SACAgentNetworks):
    """MAAC's stacked actors and attention critic."""

    @property
    def critic(self) -> AttentionCritic:
        m = self.config
        return AttentionCritic(
            self.n_agents, m.maac_embed_dim, m.maac_heads, tuple(m.critic_hidden)
        )

    def critic_apply(self, critic_params, consts: AgentConsts, obs, action, mask):
        """``[B, obs], [B, n, w], [B, n] -> (q [B, n], attention [B, heads, n, n])``."""
        apply = lambda o, a, m: self.critic.apply({"params": critic_params}, o, a, m & consts.valid)
        return jax.vmap(apply)(obs, action, mask)

    def q_fn(self, critic_params, consts: AgentConsts, obs, action, mask):
        """``[B, obs], [B, n, w], [B, n] -> [B, 1, n]`` per-agent Q_i (one critic)."""
        return self.critic_apply(critic_params, consts, obs, action, mask)[0][:, None]

    def init_critic(self, key: jax.Array, consts: AgentConsts):
        return self.critic.init(
            key, jnp.zeros(self.obs_size), jnp.zeros((self.n_agents, self.width)), consts.valid
        )["params"]


def make_maac(m: MarlConfig, ctx: BuildContext) -> Algorithm:
    """MAAC on the sub-spaces ``ctx.agent_index`` of ``ctx.env``; with a transfer variant
    (``ctx.transfer_variant``) built for every sub-space (``mc.MarlVariant``)."""
    return mc.make_sac_baseline("maac", MAACNetworks, m, ctx, mc.marl_variant(ctx))
