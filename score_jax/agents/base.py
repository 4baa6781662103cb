"""The agents layer's interfaces: what an algorithm hands to the run layer, and what the run
layer hands to an algorithm's builder.

An algorithm is built by ``builder(settings, ctx) -> Algorithm``, where ``settings`` is
its own section of the configuration (``ScoreConfig``, ``MarlConfig``, ``SingleAgentConfig``)
and ``ctx`` a ``BuildContext`` of numbers the run resolved once. The run layer then drives
``Algorithm.off_policy`` with the shared off-policy trainer, or calls ``train_external`` for
algorithms that bring their own loop (brax SAC / PPO, H-PPO).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs.base import CompositeEnv
from score_jax.core.spaces import CompositeSpace, pad_width

# act(env_state [E], key) -> agent actions [E, n_agents, width]; a learned policy reads
# env_state.obs, a scripted one (the greenhouse expert) may read the simulator state.
ActFn = Callable[[Any, jax.Array], jax.Array]

# How an algorithm's critic scores the agents: one joint Q (SCORE, MADDPG) or one Q_i per
# agent (ISAC, MAAC), each regressed on the team reward.
CriticKind = Literal["centralised", "per_agent"]


class OffPolicyAlgorithm(NamedTuple):
    """What the shared off-policy trainer needs from an algorithm.

    ``init(key, frozen=None) -> state`` (``frozen``: one seed's output of
    ``Algorithm.pretrain``; None: its template, e.g. a state to restore a checkpoint into);
    ``act(state, obs[B, obs], key, deterministic) -> action[B, n, w]``;
    ``update(state, batch: Transition[B], key, hyper) -> (state, metrics: dict[str, []])``;
    ``hyper`` is a pytree of arrays (fed to every epoch, so changing it never recompiles).
    Every entry of the update's metrics dict reaches ``metrics.csv`` under its own name.
    """

    name: str
    init: Callable[..., Any]
    act: Callable[..., jax.Array]
    update: Callable[..., tuple[Any, dict]] | None
    hyper: Any
    n_agents: int
    width: int


# train_external(total_steps, report, initial_agent, evaluate) -> agent state, where
# report(env_steps, metrics: dict, evaluated_agent | None) writes one metrics row and
# evaluate(agent) -> mean deterministic return (None when the run has no periodic evaluations).
ExternalTrainFn = Callable[..., Any]


@dataclasses.dataclass(frozen=True)
class Algorithm:
    """An algorithm plus how to read its deterministic policy out of a state.

    ``policy(agent_state) -> act_fn(env_state_batch, key) -> [E, n_agents, width]``.
    ``grow(source_agent_state, source_networks, template_agent_state, plan, key) -> agent_state``
    grows a trained run's agent axis by unseen sub-spaces (§4.3); None for an algorithm whose
    networks are tied to a fixed set of sub-spaces. ``embed_new(source_agent_state, env, plan,
    key)`` (SCORE) embeds the new sub-spaces before growing.
    ``pretrain(keys [K, 2]) -> frozen``: representation learning before training (SCORE's
    ASRL), for all K seeds at once (a leading K axis on every leaf of ``frozen``); None when
    the algorithm has none. ``frozen_template() -> frozen``: one seed's ``frozen`` shapes
    without computing it (restoring a checkpoint fills it in).
    ``train_external`` is set by algorithms that run their own training loop (brax SAC / PPO,
    H-PPO); then ``off_policy`` only supplies ``init`` (the saved state's template), ``act``,
    ``n_agents`` and ``width``. ``metric_names`` lists the metrics ``train_external`` reports.
    """

    name: str
    off_policy: OffPolicyAlgorithm
    policy: Callable[[Any], ActFn]
    networks: Any = None
    grow: Callable[..., Any] | None = None
    train_external: ExternalTrainFn | None = None
    metric_names: tuple[str, ...] = ()
    pretrain: Callable[[jax.Array], Any] | None = None
    frozen_template: Callable[[], Any] | None = None


@dataclasses.dataclass(frozen=True)
class BuildContext:
    """What every algorithm builder gets from the run (resolved once, at the start).

    Attributes:
      env: the environment the algorithm acts in (already action-repeated).
      agent_index: ``[n_agents]`` sub-space of ``env.space`` each agent controls.
      width: padded action width of the agents (>= ``env.space.max_dim``).
      seed: the run's seed.
      total_steps: the run's budget in decisions.
      eval_every: decisions between deterministic evaluations (0 = only at the end).
      eval_episodes: episodes per evaluation.
      num_envs: parallel environments of the off-policy trainer.
      updates_per_step: gradient updates per vectorised step of the off-policy trainer.
      trainable: in a transfer run (§4.3), ``[n_agents]`` True for the agents whose actors
        train (new sub-spaces, or all with ``finetune_old_actors``); None in an ordinary run.
      finetune_encoder: in a SCORE transfer run, the critic's own encoders fine-tune too
        (``TransferSpec.finetune_critic_encoder``; frozen otherwise, §4.3).
      prior: ``[n_agents]`` bool, the agents whose untrained policy starts at its sub-space's
        default (``TrainConfig.default_prior``; in a transfer run the new agents follow
        ``TransferSpec.new_actor_prior``); None = every agent. Without the prior a policy
        starts mid-range (continuous dims) with uniform choices (discrete dims).
      transfer_variant: ``plain`` | ``mask`` | ``penalty`` | None (``--single.transfer-variant``):
        how a baseline built for the full space treats the sub-spaces outside ``agent_index``
        (``agents.variants``); penalty_coef: the ``penalty`` variant's weight.
      log: where builders report progress.
    """

    env: CompositeEnv
    agent_index: np.ndarray
    width: int
    seed: int = 0
    total_steps: int = 0
    eval_every: int = 0
    eval_episodes: int = 10
    num_envs: int = 8
    updates_per_step: int = 1
    trainable: np.ndarray | None = None
    finetune_encoder: bool = False
    prior: np.ndarray | None = None
    transfer_variant: str | None = None
    penalty_coef: float = 1.0
    log: Callable[[str], None] = print

    @property
    def space(self) -> CompositeSpace:
        return self.env.space

    @property
    def n_agents(self) -> int:
        return len(self.agent_index)

    @property
    def prior_mask(self) -> np.ndarray:
        """``[n_agents]`` bool: ``prior``, every agent when None."""
        if self.prior is None:
            return np.ones(self.n_agents, bool)
        prior = np.asarray(self.prior, bool)
        if prior.shape != (self.n_agents,):
            raise ValueError(f"prior has shape {prior.shape}, expected ({self.n_agents},)")
        return prior


@struct.dataclass
class AgentConsts:
    """Per-agent arrays that describe the sub-spaces (no recompilation when they change).

    Attributes:
      dim_mask: ``[n, w]`` bool, real dimensions of each sub-space.
      n_choices: ``[n, w]`` int32, grid size of discrete dims (0 = continuous).
      valid: ``[n]`` bool, agents that exist (False for padding when the agent axis is grown).
      target_entropy: ``[n]`` per-agent entropy target for the temperature alpha.
      critic_inputs: algorithm-specific frozen inputs of the critic (SCORE: HVAE params, c_i).
      default_action: ``[n, w]`` normalised default sub-actions, the actors' prior (None = no
        agent has one: every actor starts mid-range with uniform logits).
      prior_agents: ``[n]`` bool, the agents that act around ``default_action`` (None = all);
        set only when some do and some do not (a transfer run's untrained new actors).
    """

    dim_mask: jax.Array
    n_choices: jax.Array
    valid: jax.Array
    target_entropy: jax.Array
    critic_inputs: Any = None
    default_action: Any = None
    prior_agents: Any = None


def target_entropy(
    dim_mask, n_choices, discrete_scale: float = 0.1, continuous: float = -1.0
) -> jax.Array:
    """``[n]`` entropy target: ``continuous`` per continuous dim,
    ``discrete_scale * log(n_choices)`` per discrete dim (the entropy of a uniform choice scaled
    down)."""
    per_dim = jnp.where(
        n_choices > 0, discrete_scale * jnp.log(jnp.maximum(n_choices, 1)), continuous
    )
    return jnp.sum(jnp.where(dim_mask, per_dim, 0.0), axis=-1)


def agent_consts(
    space: CompositeSpace,
    agent_index,
    width: int,
    critic_inputs=None,
    entropy: tuple[float, float] = (0.1, -1.0),
    prior=None,
) -> AgentConsts:
    """Per-agent arrays for the sub-spaces ``agent_index`` of ``space``, padded to ``width``.

    ``prior``: ``[n]`` bool, the agents whose actors act around their sub-space's default
    (``BuildContext.prior_mask``); None = all. The defaults are kept only when some agent
    uses them, and the mask only when it is mixed, so the state of a run where every actor
    has the prior has the same structure as before the mask existed.
    """
    idx = np.asarray(agent_index)
    prior = np.ones(len(idx), bool) if prior is None else np.asarray(prior, bool)
    if prior.shape != idx.shape:
        raise ValueError(f"prior has shape {prior.shape}, expected {idx.shape}")
    dim_mask = pad_width(jnp.asarray(space.dim_mask[idx]), width, False)
    n_choices = pad_width(jnp.asarray(space.n_choices[idx]), width, 0)
    default = pad_width(jnp.asarray(space.default_action())[idx], width, 0.0)
    return AgentConsts(
        dim_mask,
        n_choices,
        jnp.ones(len(idx), bool),
        target_entropy(dim_mask, n_choices, *entropy),
        critic_inputs,
        default if prior.any() else None,
        None if prior.all() else jnp.asarray(prior),
    )


def deterministic_policy(act: Callable) -> Callable[[Any], ActFn]:
    """``policy(agent) -> act_fn`` of an algorithm whose ``act(state, obs, key, deterministic)``
    reads only the observation."""
    return lambda agent: lambda env_state, key: act(agent, env_state.obs, key, True)


def resolve(value, default):
    """``value``, or ``default`` when it is None (the one spelling of "the environment's
    preset")."""
    return default if value is None else value
