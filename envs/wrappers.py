"""Wrappers around a CompositeEnv.

- ``AutoReset``: restarts an episode in place when it ends, so a ``lax.scan`` rollout of a
  vmapped batch never stops (the learner's rollout and every baseline use it).
- ``BraxFlatEnv``: exposes a CompositeEnv to ``brax.training.agents`` (PPO, SAC) as a flat
  ``[total_dim]`` action in [-1, 1]; padded columns never exist on that side.
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
        fresh = self.env.reset(key_reset)
        done = inner.done > 0
        merged = jax.tree.map(lambda f, s: jnp.where(done, f, s), fresh, inner)
        merged = merged.replace(reward=inner.reward, done=inner.done, truncated=inner.truncated, metrics=inner.metrics)
        return merged.replace(sim=AutoResetSim(merged.sim, key)), inner.obs


def _brax_env_base():
    from brax.envs.base import Env

    return Env


class BraxFlatEnv(_brax_env_base()):
    """A CompositeEnv seen by brax: ``action [total_dim]`` in [-1, 1] -> ``[n, max_dim]``."""

    def __init__(self, env: CompositeEnv):
        self.env = env

    def reset(self, rng: jax.Array):
        from brax.envs.base import State

        s = self.env.reset(rng)
        return State(pipeline_state=s, obs=s.obs, reward=s.reward, done=s.done, metrics={}, info={})

    def step(self, state, action: jax.Array):
        s = self.env.step(state.pipeline_state, self.env.space.unflatten(action))
        return state.replace(pipeline_state=s, obs=s.obs, reward=s.reward, done=s.done)

    @property
    def observation_size(self) -> int:
        return self.env.observation_size

    @property
    def action_size(self) -> int:
        return self.env.space.total_dim

    @property
    def backend(self) -> str:
        return "jax"
