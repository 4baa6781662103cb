"""Wrappers around a CompositeEnv.

- ``AutoReset``: restarts an episode in place when it ends, so a ``lax.scan`` rollout of a
  vmapped batch never stops (the learner's rollout and every baseline use it).

``envs.brax_flat.BraxFlatEnv`` (its own module, so that importing this one never imports brax
and MuJoCo) exposes a CompositeEnv to ``brax.training.agents``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from envs.base import CompositeEnv, EnvState


@struct.dataclass
class AutoResetSim:
    inner: object
    key: jax.Array


class AutoReset:
    """Reset an environment in ``step`` when it is done; ``reward``/``done`` report the last step.

    The returned state after a terminal step carries the *new* episode's observation in
    ``obs``, and the terminal observation in ``metrics`` is not kept: the learner stores
    ``next_obs`` before calling ``step`` again, exactly like brax's AutoResetWrapper.
    ``final_obs`` holds the observation the last step produced (before any reset), which is
    what a replay buffer must store as the next observation.
    """

    def __init__(self, env: CompositeEnv):
        self.env = env
        self.name, self.space = env.name, env.space
        self.observation_size, self.episode_length = env.observation_size, env.episode_length

    def reset(self, key: jax.Array) -> EnvState:
        key, key_env = jax.random.split(key)
        state = self.env.reset(key_env)
        return state.replace(sim=AutoResetSim(state.sim, key))

    def step(self, state: EnvState, action: jax.Array) -> tuple[EnvState, jax.Array]:
        """Returns ``(state, final_obs)``: ``final_obs`` is the observation reached by this step."""
        inner = self.env.step(state.replace(sim=state.sim.inner), action)
        key, key_reset = jax.random.split(state.sim.key)
        # A fresh random reset every step (selected where done) keeps start states diverse;
        # brax instead reuses each env's first state. It costs one reset per step: cheap for
        # the greenhouse, about one extra MJX forward pass for the Spider.
        fresh = self.env.reset(key_reset)
        done = inner.done > 0
        merged = jax.tree.map(lambda f, s: jnp.where(done, f, s), fresh, inner)
        merged = merged.replace(reward=inner.reward, done=inner.done, truncated=inner.truncated, metrics=inner.metrics)
        return merged.replace(sim=AutoResetSim(merged.sim, key)), inner.obs
