"""The CompositeEnv protocol, the state every environment returns, and the environment's hints.

An environment is a pure-function object: ``reset(key) -> EnvState`` and
``step(state, action) -> EnvState`` with ``action`` the learner's normalised, padded
``[n, max_dim]`` array (see ``score_jax.core.spaces``). ``jax.jit(jax.vmap(env.step))`` works
for every environment. Simulator parameters (weather, crop and physics parameters) are pytree
fields of the environment object, so a batch of variants is ``jax.vmap`` over environments.

Subclass ``CompositeEnv`` to inherit the defaults of its optional members (``hints``,
``reference_policies``); ``envs.make`` refuses an object that lacks a member of the protocol.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any, Protocol, runtime_checkable

import jax
from flax import struct

from score_jax.core.spaces import CompositeSpace


@struct.dataclass
class EnvState:
    """State of one environment (add leading axes for batches).

    Attributes:
      sim: the simulator's own state (an environment-specific pytree).
      obs: ``[observation_size]`` float32 observation, shared by all sub-spaces.
      reward: ``[]`` float32 reward of the last step (0 after reset).
      done: ``[]`` float32, 1.0 when the episode ended at the last step (terminal or time limit).
      truncated: ``[]`` float32, 1.0 when it ended by the time limit only (bootstrap through it).
      t: ``[]`` int32 steps taken in this episode.
      metrics: an environment-specific pytree of per-step diagnostics (e.g. yield, energy).
      info: extras of wrappers, as brax keeps them in ``state.info`` (``AutoReset`` puts the
        observation its step reached, before any reset, under ``"final_obs"``).
    """

    sim: Any
    obs: jax.Array
    reward: jax.Array
    done: jax.Array
    truncated: jax.Array
    t: jax.Array
    metrics: Any
    info: dict = struct.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class EnvHints:
    """What an environment suggests to the learners, and its training presets.

    Attributes:
      reward_scale: rewards are multiplied by this in the learners' targets (keeps Q-values of
        order 100 whatever the reward's units).
      action_repeat: environment steps a learner's decision is held for (``ActionRepeat``).
      exploration_hold: environment steps an exploration draw is held for (gSDE-style).
      total_steps: preset training budget, in decisions (steps of the action-repeated env).
      eval_every: preset interval of deterministic evaluations, in decisions (0 = at the end).
    """

    reward_scale: float = 1.0
    action_repeat: int = 1
    exploration_hold: int = 1
    total_steps: int = 100_000
    eval_every: int = 0


# act(state) -> normalised [n, max_dim] action for ONE (unbatched) state: a scripted policy.
ReferencePolicy = Callable[["EnvState"], jax.Array]


@runtime_checkable
class CompositeEnv(Protocol):
    """What the learner, the baselines and the evaluation protocols need from an environment.

    Attributes (plain attributes or properties):
      name: the registry name; space: the composite action space; observation_size: the
      length of ``EnvState.obs``; episode_length: steps of a full episode.
    """

    name: str
    space: CompositeSpace
    observation_size: int
    episode_length: int

    def reset(self, key: jax.Array) -> EnvState: ...

    def step(self, state: EnvState, action: jax.Array) -> EnvState: ...

    @property
    def hints(self) -> EnvHints:
        """Reward scale, action repeat, exploration hold and presets (defaults: ``EnvHints()``)."""
        return EnvHints()

    def reference_policies(self) -> Mapping[str, ReferencePolicy]:
        """Scripted policies the end-of-run report compares with (e.g. a grower heuristic)."""
        return {}


def missing_members(env: object) -> list[str]:
    """Members of the ``CompositeEnv`` protocol that ``env`` lacks (empty if it satisfies it)."""
    members = (
        "name",
        "space",
        "observation_size",
        "episode_length",
        "reset",
        "step",
        "hints",
        "reference_policies",
    )
    return [m for m in members if not hasattr(env, m)]


def config_fields(config_cls, prefix: str = "") -> dict[str, dataclasses.Field]:
    """Every option of a (nested) config dataclass by its dotted name (``physics.timestep``)."""
    out = {}
    for f in dataclasses.fields(config_cls):
        if dataclasses.is_dataclass(f.default):
            out.update(config_fields(type(f.default), f"{prefix}{f.name}."))
        else:
            out[prefix + f.name] = f
    return out


def build_config(config_cls, overrides: dict, base=None):
    """``config_cls(**overrides)`` (or ``base`` with them replaced); a dotted key
    (``physics.timestep``) sets a field of a nested config. Unknown keys raise a ValueError
    that lists the accepted ones."""
    fields = {f.name: f for f in dataclasses.fields(config_cls)}
    flat, nested = {}, {}
    for key, value in overrides.items():
        head, dot, rest = key.partition(".")
        if dot:
            nested.setdefault(head, {})[rest] = value
        else:
            flat[key] = value
    unknown = sorted(
        {k for k in flat if k not in fields}
        | {k for k in nested if k not in fields or not dataclasses.is_dataclass(fields[k].default)}
    )
    if unknown:
        raise ValueError(
            f"unknown option(s) {unknown} for {config_cls.__name__}; "
            f"accepted: {sorted(config_fields(config_cls))}"
        )
    for head, sub in nested.items():
        inner = flat.get(head, getattr(base, head) if base is not None else fields[head].default)
        flat[head] = build_config(type(inner), sub, base=inner)
    return dataclasses.replace(base, **flat) if base is not None else config_cls(**flat)
