"""Wrappers around a CompositeEnv.

- ``AutoReset``: restarts an episode in place when it ends, so a ``lax.scan`` rollout of a
  vmapped batch never stops (the learner's rollout and every baseline use it).
- ``ActionRepeat``: one decision holds for ``k`` steps of the wrapped environment (brax's
  ``action_repeat``, the frame skip of Atari agents); ``with_action_repeat`` applies it.

Both satisfy the ``CompositeEnv`` protocol (wrappers subclass it); a wrapper's extras live in
``EnvState.info``, as brax keeps them in ``state.info``. The flat-action view for brax's agents
lives next to the brax adapters (``score_jax.agents.brax.flat_env``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import jax
import jax.numpy as jnp
from flax import struct

from envs.base import CompositeEnv, EnvHints, EnvState, ReferencePolicy

FINAL_OBS = "final_obs"


@struct.dataclass
class AutoResetSim:
    inner: object
    key: jax.Array


class AutoReset(CompositeEnv):
    """Reset an environment in ``step`` when it is done; ``reward``/``done`` report the last step.

    The returned state after a terminal step carries the *new* episode's observation in
    ``obs``, like brax's AutoResetWrapper. ``info["final_obs"]`` holds the observation the
    step produced (before any reset), which is what a replay buffer must store as the next
    observation.
    """

    def __init__(self, env: CompositeEnv):
        self.env = env
        self.name, self.space = env.name, env.space
        self.observation_size, self.episode_length = env.observation_size, env.episode_length

    @property
    def hints(self) -> EnvHints:
        return self.env.hints

    def reference_policies(self) -> Mapping[str, ReferencePolicy]:
        return self.env.reference_policies()

    def planned_references(self, action_repeat: int = 1) -> Mapping[str, ReferencePolicy]:
        return self.env.planned_references(action_repeat)

    def reset(self, key: jax.Array) -> EnvState:
        key, key_env = jax.random.split(key)
        state = self.env.reset(key_env)
        return state.replace(
            sim=AutoResetSim(state.sim, key), info={**state.info, FINAL_OBS: state.obs}
        )

    def step(self, state: EnvState, action: jax.Array) -> EnvState:
        """One step; a finished episode restarts in place (see the class docstring)."""
        own = {k: v for k, v in state.info.items() if k != FINAL_OBS}
        inner = self.env.step(state.replace(sim=state.sim.inner, info=own), action)
        key, key_reset = jax.random.split(state.sim.key)
        # A fresh random reset every step (selected where done) keeps start states diverse;
        # brax instead reuses each env's first state. It costs one reset per step: cheap for
        # the greenhouse, about one extra MJX forward pass for the Spider.
        fresh = self.env.reset(key_reset)
        done = inner.done > 0
        merged = jax.tree.map(lambda f, s: jnp.where(done, f, s), fresh, inner)
        merged = merged.replace(
            reward=inner.reward, done=inner.done, truncated=inner.truncated, metrics=inner.metrics
        )
        return merged.replace(
            sim=AutoResetSim(merged.sim, key), info={**inner.info, FINAL_OBS: inner.obs}
        )


class ActionRepeat(CompositeEnv):
    """Apply each action for ``repeat`` consecutive steps of ``env``; one decision = ``repeat``
    steps.

    ``reward`` is the sum of the inner rewards up to the end of the episode, ``done`` /
    ``truncated`` / ``metrics`` are those of the last inner step taken; once the episode ends
    inside a decision the remaining inner steps are skipped (the state stays terminal). The
    episode is ``ceil(episode_length / repeat)`` decisions long, and the return of an episode
    is exactly the wrapped environment's return, so policies of any decision interval compare
    on one scale. ``obs`` is the observation after the last inner step; ``t`` counts inner
    steps (the wrapped environment reads it).

    Why: on the greenhouse a day's sub-action barely moves a 160-day season (see the README's
    design notes), so a critic of daily decisions has to
    resolve differences far below its own error; a decision held for a week has a k-fold
    larger effect and the season has k-fold fewer decisions to propagate values over.
    Other attributes (``mj_model``, ``weather`` ...) are the wrapped environment's; its
    ``hints`` are too, except ``reward_scale``, divided by ``repeat`` (a decision's reward sums
    ``repeat`` rewards), and ``action_repeat``, 1 (the repeat is applied).
    """

    def __init__(self, env: CompositeEnv, repeat: int):
        if repeat < 1:
            raise ValueError(f"action repeat must be >= 1, got {repeat}")
        self.env, self.repeat = env, int(repeat)
        self.name, self.space, self.observation_size = env.name, env.space, env.observation_size
        self.episode_length = -(-env.episode_length // self.repeat)

    def __getattr__(self, name):  # mj_model, weather ...: the wrapped env's
        if name == "env" or name.startswith("__"):  # not set yet (copy, pickle): no recursion
            raise AttributeError(name)
        return getattr(self.env, name)

    @property
    def unwrapped(self) -> CompositeEnv:
        return self.env

    @property
    def hints(self) -> EnvHints:
        inner = self.env.hints
        return dataclasses.replace(
            inner, reward_scale=inner.reward_scale / self.repeat, action_repeat=1
        )

    def reference_policies(self) -> Mapping[str, ReferencePolicy]:
        return self.env.reference_policies()

    def planned_references(self, action_repeat: int = 1) -> Mapping[str, ReferencePolicy]:
        return self.env.planned_references(action_repeat * self.repeat)

    def reset(self, key: jax.Array) -> EnvState:
        return self.env.reset(key)

    def step(self, state: EnvState, action: jax.Array) -> EnvState:
        def inner(carry, _):
            s, total, ended = carry
            nxt = self.env.step(s, action)
            s = jax.tree.map(lambda old, new: jnp.where(ended > 0, old, new), s, nxt)
            total = total + (1.0 - ended) * nxt.reward
            return (s, total, jnp.maximum(ended, nxt.done)), None

        zero = jnp.zeros((), jnp.float32)
        (last, total, ended), _ = jax.lax.scan(inner, (state, zero, zero), None, self.repeat)
        return last.replace(reward=total, done=ended)


def with_action_repeat(env: CompositeEnv, repeat: int) -> CompositeEnv:
    """``env`` itself for ``repeat == 1``, else ``ActionRepeat(env, repeat)``."""
    return env if repeat == 1 else ActionRepeat(env, repeat)


def unwrapped(env) -> CompositeEnv:
    """The innermost environment below any ``ActionRepeat``."""
    while isinstance(env, ActionRepeat):
        env = env.env
    return env
