"""QMIX (Rashid et al. 2018; §5.1) over discretised sub-action spaces.

Each sub-space i is an agent with a Q network Q_i(o, .) over its K candidate sub-actions
(``qmix_candidates``: a centre plus a grid within centre +- radius; with the default prior the
centre is the default and starts with a Q head start, ``start_at_prior``, else it is the
mid-range point). Its choice maps to an ordinary normalised ``[n, width]`` action, so the
environment, replay, failures, evaluation and robustness sweep see nothing special. The
replay stores exactly the chosen candidate, and the update recovers its index as the nearest
candidate (uniform random warm-up actions map to their nearest candidate too).

Mixing (one sample, state s = o):
``Q_tot = w2(s)^T ELU(sum_{i active} |W1_i(s)| Q_i + b1(s)) + V(s)`` with hypernetworks
``W1_i`` (one linear head per agent, equal to QMIX's single linear hypernetwork), ``b1``,
``w2`` (abs: monotonic, dQ_tot/dQ_i >= 0) and ``V`` (two layers). Failed, padded and invalid
agents contribute exactly nothing (``where``), so growing the agent axis with a masked agent
leaves Q_tot unchanged. TD target with double Q and target networks:

    y = r + gamma (1 - d) Q_tot'(o', argmax_k Q_i(o', k) evaluated by Q_i'),
    L = mean (Q_tot - y)^2 / 2

Epsilon-greedy exploration per agent; the linear epsilon schedule is an array in the state
(changing it never recompiles). Deviation: agents are MLPs on the full observation (QMIX's
GRU agents address partial observability, which these environments do not have).

Transfer (§5.2.4): a subset run grows by the unseen agents (``grow_qmix``); with
``--single.transfer-variant`` it is instead built for every sub-space (``VariantQMIXNetworks``,
Table 3's QMIX-mask / QMIX-penalty): the unseen agents act their default candidate (the one the
environment receives), ``plain`` freezes their Q networks (the mixer trains), and ``penalty``
pulls their greedy choice to the default through the Boltzmann expectation of the deviation,
``sum_k softmax_k(Q_i(o, .)) |c_ik - d_i|^2`` (the arg-max itself has no gradient).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from score_jax.agents import variants
from score_jax.agents.base import Algorithm, BuildContext
from score_jax.agents.growth import freeze_agent_rows, grow_stacked
from score_jax.agents.marl import common as mc
from score_jax.agents.marl.config import MarlConfig
from score_jax.agents.marl.qmix_candidates import candidate_table
from score_jax.agents.replay import Transition, continuation
from score_jax.networks.mlp import MLP


class Mixer(nn.Module):
    """``q [n], obs [obs], mask [n] -> Q_tot []``, monotonic in every active q_i."""

    n_agents: int
    embed_dim: int

    @nn.compact
    def __call__(self, q: jax.Array, obs: jax.Array, mask: jax.Array) -> jax.Array:
        e = self.embed_dim
        w1 = jnp.abs(
            mc.StackedMLP(self.n_agents, (), e, name="w1")(
                jnp.broadcast_to(obs, (self.n_agents, obs.shape[-1]))
            )
        )
        hidden = jax.nn.elu(
            jnp.sum(jnp.where(mask[:, None], q[:, None] * w1, 0.0), 0) + nn.Dense(e, name="b1")(obs)
        )
        w2 = jnp.abs(nn.Dense(e, name="w2")(obs))
        return hidden @ w2 + MLP((e,), 1, name="v")(obs)[0]


@struct.dataclass
class QMIXConsts:
    valid: jax.Array  # [n] bool, agents that exist
    candidates: jax.Array  # [n, K, w] normalised candidate sub-actions
    candidate_valid: jax.Array  # [n, K] bool


@struct.dataclass
class EpsilonSchedule:
    """Linear decay from ``start`` to ``end`` over ``decay_updates`` gradient updates (arrays)."""

    start: jax.Array
    end: jax.Array
    decay_updates: jax.Array

    def __call__(self, updates: jax.Array) -> jax.Array:
        frac = jnp.clip(updates / jnp.maximum(self.decay_updates, 1.0), 0.0, 1.0)
        return self.start + (self.end - self.start) * frac


@struct.dataclass
class QMIXState:
    params: Any  # {"agent_q": stacked per-agent Q nets, "mixer": Mixer params}
    target: Any
    opt: Any
    consts: QMIXConsts
    epsilon: EpsilonSchedule
    updates: jax.Array  # [] int32


@struct.dataclass
class QMIXHyper:
    gamma: jax.Array
    tau: jax.Array
    reward_scale: jax.Array


@dataclasses.dataclass(frozen=True)
class QMIXNetworks:
    """Static structure of QMIX: ``n`` agents with ``K`` candidates each."""

    config: Any  # MarlConfig
    obs_size: int
    n_agents: int

    @property
    def agent_q(self) -> mc.StackedMLP:
        return mc.StackedMLP(
            self.n_agents, tuple(self.config.critic_hidden), self.config.qmix_candidates
        )

    @property
    def mixer(self) -> Mixer:
        return Mixer(self.n_agents, self.config.qmix_mixer_dim)

    def q_values(self, params, consts: QMIXConsts, obs) -> jax.Array:
        """``obs [B, obs] -> [B, n, K]`` per-agent Q over the candidates (invalid ones -inf)."""
        q = jax.vmap(
            lambda o: self.agent_q.apply(
                {"params": params["agent_q"]}, jnp.broadcast_to(o, (self.n_agents, o.shape[-1]))
            )
        )(obs)
        return jnp.where(consts.candidate_valid, q, -jnp.inf)

    def executed(self, consts: QMIXConsts, index: jax.Array) -> jax.Array:
        """``index [B, n] -> [B, n]``: the candidates the environment would receive."""
        return index

    def mix(self, params, q, obs, mask) -> jax.Array:
        """``q [B, n], obs [B, obs], mask [B, n] -> Q_tot [B]``."""
        return jax.vmap(lambda a, o, m: self.mixer.apply({"params": params["mixer"]}, a, o, m))(
            q, obs, mask
        )

    def init(self, key: jax.Array, prior=None):
        """Fresh parameters; ``prior`` (``[n]`` bool, None = all): the agents whose candidate 0
        (their default) starts ``qmix_prior_q`` ahead (``start_at_prior``)."""
        key_q, key_mix = jax.random.split(key)
        obs = jnp.zeros(self.obs_size)
        agent_q = self.agent_q.init(key_q, jnp.zeros((self.n_agents, self.obs_size)))["params"]
        agent_q = start_at_prior(agent_q, self.config, prior)
        mixer = self.mixer.init(
            key_mix, jnp.zeros(self.n_agents), obs, jnp.ones(self.n_agents, bool)
        )["params"]
        return {"agent_q": agent_q, "mixer": mixer}


def start_at_prior(agent_q, m: MarlConfig, prior=None):
    """Initial agent Q parameters (``StackedMLP``, leading agent axis): the output kernel scaled
    by ``m.actor.head_init_scale`` (a fresh Q_i is ~its bias, as a fresh actor is ~its prior),
    and ``m.qmix_prior_q`` added to the output bias of candidate 0 (the default, see
    ``qmix_candidates``) of the agents marked in ``prior`` (None = all)."""
    out = agent_q["agents"]["out"]
    n, k = out["bias"].shape
    on = jnp.ones(n) if prior is None else jnp.asarray(prior, jnp.float32)
    bonus = m.qmix_prior_q * on[:, None] * (jnp.arange(k) == 0)
    out = {"kernel": out["kernel"] * m.actor.head_init_scale, "bias": out["bias"] + bonus}
    return {**agent_q, "agents": {**agent_q["agents"], "out": out}}


@dataclasses.dataclass(frozen=True)
class VariantQMIXNetworks(QMIXNetworks):
    """QMIX built for every sub-space with a transfer variant (``mc.MarlVariant``).

    ``deviation [n, K]``: squared deviation of each candidate from its sub-space's default.
    """

    variant: Any = None  # mc.MarlVariant
    deviation: Any = None

    def q_values(self, params, consts: QMIXConsts, obs) -> jax.Array:
        v = self.variant
        head_mask = lambda p: {
            "agent_q": variants.agent_rows(p["agent_q"], v.unseen),
            "mixer": jax.tree.map(lambda _: np.zeros((), bool), p["mixer"]),
        }
        q = super().q_values(v.params(params, head_mask), consts, obs)
        return v.output(q, self.expected_deviation)

    def expected_deviation(self, q: jax.Array) -> jax.Array:
        """``q [B, n, K] -> [B]``: the unseen agents' Boltzmann-expected candidate deviation."""
        p = jax.nn.softmax(q, axis=-1)  # invalid candidates (-inf) get 0
        unseen = jnp.asarray(self.variant.unseen)[:, None]
        return jnp.sum(jnp.where(unseen, p * self.deviation, 0.0), axis=(-2, -1))

    def executed(self, consts: QMIXConsts, index: jax.Array) -> jax.Array:
        """The unseen agents' choices replaced by their defaults (``variants.replace_unseen``),
        as the environment receives them."""
        v = self.variant
        action = variants.replace_unseen(v.space, select_candidates(consts, index), v.seen)
        return candidate_index(consts, action)


def select_candidates(consts: QMIXConsts, index: jax.Array) -> jax.Array:
    """``index [B, n] -> action [B, n, w]`` (invalid agents 0)."""
    action = jnp.take_along_axis(consts.candidates[None], index[..., None, None], axis=2)[:, :, 0]
    return jnp.where(consts.valid[None, :, None], action, 0.0)


def candidate_index(consts: QMIXConsts, action: jax.Array) -> jax.Array:
    """``action [B, n, w] -> [B, n]`` index of the nearest valid candidate (exact for stored
    choices)."""
    dist = jnp.sum((action[:, :, None, :] - consts.candidates[None]) ** 2, -1)
    return jnp.argmin(jnp.where(consts.candidate_valid, dist, jnp.inf), -1)


def pick(q: jax.Array, index: jax.Array) -> jax.Array:
    """``q [B, n, K], index [B, n] -> [B, n]``."""
    return jnp.take_along_axis(q, index[..., None], -1)[..., 0]


def qmix_loss(
    params, state: QMIXState, batch: Transition, mask, hyper: QMIXHyper, nets: QMIXNetworks
):
    consts = state.consts
    q = pick(nets.q_values(params, consts, batch.obs), candidate_index(consts, batch.action))
    q_tot = nets.mix(params, jnp.where(mask, q, 0.0), batch.obs, mask)
    next_index = nets.executed(
        consts, jnp.argmax(jax.lax.stop_gradient(nets.q_values(params, consts, batch.next_obs)), -1)
    )  # double Q
    next_q = pick(nets.q_values(state.target, consts, batch.next_obs), next_index)
    next_tot = nets.mix(state.target, jnp.where(mask, next_q, 0.0), batch.next_obs, mask)
    y = hyper.reward_scale * batch.reward + hyper.gamma * continuation(batch) * next_tot
    return 0.5 * jnp.mean((q_tot - jax.lax.stop_gradient(y)) ** 2), jnp.mean(q_tot)


def make_qmix_update(nets: QMIXNetworks, opt: optax.GradientTransformation):
    """``update(state, batch, key, hyper) -> (state, metrics)``; mask = valid & batch.active.
    ``metrics``: ``critic_loss`` (TD loss of Q_tot), ``q_mean`` and ``epsilon``, each ``[]``."""

    def update(state: QMIXState, batch: Transition, key: jax.Array, hyper: QMIXHyper):
        mask = state.consts.valid[None, :] & batch.active
        (loss, q_mean), grads = jax.value_and_grad(qmix_loss, has_aux=True)(
            state.params, state, batch, mask, hyper, nets
        )
        updates, opt_state = opt.update(grads, state.opt, state.params)
        params = optax.apply_updates(state.params, updates)
        target = optax.incremental_update(params, state.target, hyper.tau)
        state = state.replace(
            params=params, target=target, opt=opt_state, updates=state.updates + 1
        )
        return state, {
            "critic_loss": loss,
            "q_mean": q_mean,
            "epsilon": state.epsilon(state.updates),
        }

    return update


def qmix_optimizer(m: MarlConfig, trainable=None) -> optax.GradientTransformation:
    """Clipped Adam; in a transfer run the old agents' Q networks are frozen, the mixer trains."""
    if trainable is None:
        return mc.adam(m, m.critic_lr)
    labels = lambda p: {
        "agent_q": jax.tree.map(lambda _: "agents", p["agent_q"]),
        "mixer": jax.tree.map(lambda _: "mixer", p["mixer"]),
    }
    lr = m.critic_lr
    split = optax.multi_transform(
        {
            "agents": optax.chain(optax.adam(lr), freeze_agent_rows(trainable)),
            "mixer": optax.adam(lr),
        },
        labels,
    )
    return optax.chain(optax.clip_by_global_norm(m.grad_clip), split)


def grow_qmix(src: QMIXState, template: QMIXState, p, key: jax.Array) -> QMIXState:
    """Transfer (§4.3): old agents keep their Q networks and mixer heads W1_i, new ones start
    fresh, the shared mixer parts are kept; candidates, optimiser and epsilon are the grown
    run's (a new agent without the default prior: a grid centred mid-range, no Q head start)."""
    return template.replace(
        params=grow_stacked(src.params, template.params, p),
        target=grow_stacked(src.target, template.target, p),
    )


def make_qmix(m: MarlConfig, ctx: BuildContext) -> Algorithm:
    """QMIX on the sub-spaces ``ctx.agent_index`` of ``ctx.env``; with a transfer variant
    (``ctx.transfer_variant``) built for every sub-space (``VariantQMIXNetworks``)."""
    variant = mc.marl_variant(ctx)
    net_ctx = ctx if variant is None else variant.context(ctx)
    width, n = ctx.width, net_ctx.n_agents
    prior = net_ctx.prior_mask
    # An unseen sub-space's grid keeps its default as a candidate (``executed`` maps the default
    # the environment receives onto it); only its Q bonus follows the prior.
    centred = prior if variant is None else prior | ~np.asarray(variant.seen, bool)
    cands, cand_valid = candidate_table(
        ctx.space, net_ctx.agent_index, width, m.qmix_candidates, m.qmix_radius, centred
    )
    if variant is None or not variant.subset:
        nets = QMIXNetworks(m, ctx.env.observation_size, n)
    else:
        default = np.asarray(variant.space.default_action())
        default = np.pad(default, ((0, 0), (0, width - default.shape[1])))
        deviation = np.where(cand_valid, np.sum((cands - default[:, None]) ** 2, -1), 0.0)
        nets = VariantQMIXNetworks(m, ctx.env.observation_size, n, variant, deviation)
    consts = QMIXConsts(jnp.ones(n, bool), jnp.asarray(cands), jnp.asarray(cand_valid))
    opt = qmix_optimizer(m, net_ctx.trainable)
    f = lambda x: jnp.asarray(x, jnp.float32)
    decay_updates = (
        m.qmix_eps_decay_steps / ctx.num_envs * ctx.updates_per_step
    )  # env steps -> updates
    epsilon = EpsilonSchedule(f(m.qmix_eps_start), f(m.qmix_eps_end), f(decay_updates))

    def init(k, frozen=None):
        params = nets.init(k, prior)
        return QMIXState(
            params, params, opt.init(params), consts, epsilon, jnp.zeros((), jnp.int32)
        )

    def act(state: QMIXState, obs, key, deterministic):
        q = nets.q_values(state.params, state.consts, obs)
        greedy = jnp.argmax(q, -1)
        if deterministic:
            return rows(select_candidates(state.consts, greedy))
        key_rand, key_eps = jax.random.split(key)
        uniform = jax.random.categorical(
            key_rand, jnp.where(state.consts.candidate_valid, 0.0, -jnp.inf), shape=greedy.shape
        )
        explore = jax.random.uniform(key_eps, greedy.shape) < state.epsilon(state.updates)
        return rows(select_candidates(state.consts, jnp.where(explore, uniform, greedy)))

    hyper = QMIXHyper(
        gamma=f(m.gamma), tau=f(m.tau), reward_scale=f(m.resolved_reward_scale(ctx.env))
    )
    update, grow, rows = make_qmix_update(nets, opt), grow_qmix, lambda a: a
    if variant is not None:
        update, grow, rows = variant.update(update), variant.grow(grow_qmix), variant.rows
    return mc.make_algorithm("qmix", init, act, update, hyper, ctx, nets, grow)
