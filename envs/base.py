"""The CompositeEnv protocol and the state every environment returns.

An environment is a pure-function object: ``reset(key) -> EnvState`` and
``step(state, action) -> EnvState`` with ``action`` the learner's normalised, padded
``[n, max_dim]`` array (see ``score_jax.spaces``). ``jax.jit(jax.vmap(env.step))`` works for
every environment. Simulator parameters (weather, crop and physics parameters) are pytree
fields of the environment object, so a batch of variants is ``jax.vmap`` over environments.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import jax
from flax import struct

from score_jax.spaces import CompositeSpace


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
    """

    sim: Any
    obs: jax.Array
    reward: jax.Array
    done: jax.Array
    truncated: jax.Array
    t: jax.Array
    metrics: Any


@runtime_checkable
class CompositeEnv(Protocol):
    """What the learner, the baselines and the evaluation protocols need from an environment."""

    @property
    def name(self) -> str: ...

    @property
    def space(self) -> CompositeSpace: ...

    @property
    def observation_size(self) -> int: ...

    @property
    def episode_length(self) -> int: ...

    def reset(self, key: jax.Array) -> EnvState: ...

    def step(self, state: EnvState, action: jax.Array) -> EnvState: ...


def build_config(config_cls, overrides: dict):
    """``config_cls(**overrides)`` with an error that lists the accepted fields."""
    import dataclasses

    fields = {f.name for f in dataclasses.fields(config_cls)}
    unknown = sorted(set(overrides) - fields)
    if unknown:
        raise ValueError(f"unknown option(s) {unknown} for {config_cls.__name__}; accepted: {sorted(fields)}")
    return config_cls(**overrides)
