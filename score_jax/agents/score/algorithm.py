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
from score_jax.agents.score.networks import FrozenInputs
from score_jax.agents.score.transfer import embed_new, grow_agent, transfer_optimizers


def make_score(sc: ScoreConfig, ctx: BuildContext) -> Algorithm:
    """SCORE on the sub-spaces ``ctx.agent_index`` of ``ctx.env``; its ``pretrain`` is ASRL
    (§4.1), run by the run layer for all seeds at once before training."""
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

    def asrl(keys: jax.Array) -> FrozenInputs:
        """ASRL of every seed: ``keys [K, 2]`` (the seeds' build keys) -> ``[K, ...]``."""
        ctx.log(f"ASRL: training the HVAE on observation sets of {ctx.n_agents} sub-spaces ...")
        key_asrl = jax.vmap(lambda k: jax.random.split(k)[0])(keys)
        return pretrain(env, agent_index, sc, width, key_asrl, log=ctx.log, fixed_default=fixed)

    frozen_shapes = lambda: frozen_template(env, agent_index, sc, width)
    if ctx.trainable is not None:  # a fine-tuning run grown from a subset run (§4.3)
        optimizers = transfer_optimizers(sc, ctx.trainable, ctx.finetune_encoder)
    else:
        optimizers = sn.make_optimizers(sc)
    update = sn.make_update(nets, optimizers)

    def act(state, obs, key, deterministic):
        return nets.policy_fn(state.actor, state.consts, obs, key, deterministic)[0]

    def grow(source: SACState, template: SACState, plan: TransferPlan, key: jax.Array) -> SACState:
        """SCORE transfer (§4.3): embed the new sub-spaces with the frozen HVAE, then grow."""
        return grow_agent(source, template, plan, embed_new(source, nets, env, plan, key), key)

    def init(key: jax.Array, frozen: FrozenInputs | None = None) -> SACState:
        frozen = frozen_shapes() if frozen is None else frozen
        consts = agent_consts(
            env.space, agent_index, width, frozen, sc.entropy_targets, ctx.prior_mask
        )
        return sn.init_state(nets, key, consts, optimizers)

    off = OffPolicyAlgorithm("score", init, act, update, sn.hyper(sc, env), ctx.n_agents, width)
    uses_asrl = sc.critic.asrl
    return Algorithm(
        "score",
        off,
        deterministic_policy(act),
        nets,
        grow,
        pretrain=asrl if uses_asrl else None,
        frozen_template=frozen_shapes if uses_asrl else None,
    )
