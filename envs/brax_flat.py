"""``BraxFlatEnv``: a CompositeEnv seen by ``brax.training.agents`` (PPO, SAC).

Brax sees a flat ``[total_dim]`` action in [-1, 1]; padded columns never exist on that side.
Importing this module imports brax (and MuJoCo), so it is kept apart from ``envs.wrappers``.
"""

from __future__ import annotations

import jax
from brax.envs.base import Env, State

from envs.base import CompositeEnv


class BraxFlatEnv(Env):
    """A CompositeEnv seen by brax: ``action [total_dim]`` in [-1, 1] -> ``[n, max_dim]``."""

    def __init__(self, env: CompositeEnv):
        self.env = env

    def reset(self, rng: jax.Array) -> State:
        s = self.env.reset(rng)
        return State(pipeline_state=s, obs=s.obs, reward=s.reward, done=s.done, metrics={}, info={})

    def step(self, state: State, action: jax.Array) -> State:
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
