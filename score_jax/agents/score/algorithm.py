"""SCORE as an ``Algorithm``: the builder the registry calls for ``--algo score``."""

from __future__ import annotations

import jax
import numpy as np

from score_jax.agents.base import (
    Algorithm,
    BuildContext,
    OffPolicyAlgorithm,
    agent_consts,
    deterministic_policy,
)
from score_jax.agents.growth import TransferPlan
from score_jax.agents.sac.state import SACState
from score_jax.agents.score import networks as sn
from score_jax.agents.score.asrl import frozen_template, pretrain
from score_jax.agents.score.config import ScoreConfig
from score_jax.agents.score.transfer import embed_new, grow_agent, transfer_optimizers


def make_score(sc: ScoreConfig, ctx: BuildContext, key: jax.Array) -> Algorithm:
    """SCORE on the sub-spaces ``ctx.agent_index`` of ``ctx.env``; runs ASRL when
    ``ctx.pretrain``."""
    env, agent_index, width = ctx.env, ctx.agent_index, ctx.width
    nets = sn.ScoreNetworks(
        sc,
        env.observation_size,
        ctx.n_agents,
        width,
        env.space.max_choices,
        env.space.discrete_width,
    )
    fixed = np.ones(env.space.n, bool)
    fixed[np.asarray(agent_index)] = False
    key_asrl, _ = jax.random.split(key)
    if ctx.pretrain:
        ctx.log(f"ASRL: training the HVAE on observation sets of {ctx.n_agents} sub-spaces ...")
        frozen = pretrain(env, agent_index, sc, width, key_asrl, log=ctx.log, fixed_default=fixed)
    else:
        frozen = frozen_template(env, agent_index, sc, width)
    consts = agent_consts(env.space, agent_index, width, frozen, sc.entropy_targets)
    if ctx.trainable is not None:  # a fine-tuning run grown from a subset run (§4.3)
        optimizers = transfer_optimizers(sc, ctx.trainable)
    else:
        optimizers = sn.make_optimizers(sc)
    update = sn.make_update(nets, optimizers)

    def act(state, obs, key, deterministic):
        return nets.policy_fn(state.actor, state.consts, obs, key, deterministic)[0]

    def grow(source: SACState, template: SACState, plan: TransferPlan, key: jax.Array) -> SACState:
        """SCORE transfer (§4.3): embed the new sub-spaces with the frozen HVAE, then grow."""
        return grow_agent(source, template, plan, embed_new(source, nets, env, plan, key), key)

    init = lambda k: sn.init_state(nets, k, consts, optimizers)
    off = OffPolicyAlgorithm("score", init, act, update, sn.hyper(sc, env), ctx.n_agents, width)
    return Algorithm("score", off, deterministic_policy(act), nets, grow)
