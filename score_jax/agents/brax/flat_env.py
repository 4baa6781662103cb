"""``BraxFlatEnv``: a CompositeEnv seen by ``brax.training.agents`` (PPO, SAC).

Brax sees a flat ``[total_dim]`` action in [-1, 1]; padded columns never exist on that side.
It lives next to the brax adapters (importing it imports brax and MuJoCo), not in ``envs``.
"""

from __future__ import annotations

import jax
import numpy as np
from brax.envs.base import Env, State

from envs.base import CompositeEnv
from score_jax.agents.variants import replace_unseen


class BraxFlatEnv(Env):
    """A CompositeEnv seen by brax: ``action [total_dim]`` in [-1, 1] -> ``[n, max_dim]``.

    ``controlled`` (``[n]`` bool, default all): sub-spaces whose sub-actions reach the
    environment; the others get their defaults through the shared failure function (a
    fixed-width baseline trained on a subset, ``agents.variants``).

    ``done`` is reported for true terminations only: brax's ``EpisodeWrapper`` (with
    ``episode_length = env.episode_length``) ends episodes at the time limit and marks them
    truncated, so brax bootstraps through time limits as the shared trainer does.
    """

    def __init__(self, env: CompositeEnv, controlled=None):
        self.env = env
        self.controlled = (
            None if controlled is None or np.all(controlled) else np.asarray(controlled, bool)
        )

    def reset(self, rng: jax.Array) -> State:
        s = self.env.reset(rng)
        return State(pipeline_state=s, obs=s.obs, reward=s.reward, done=s.done, metrics={}, info={})

    def step(self, state: State, action: jax.Array) -> State:
        a = self.env.space.unflatten(action)
        if self.controlled is not None:
            a = replace_unseen(self.env.space, a, self.controlled)
        s = self.env.step(state.pipeline_state, a)
        return state.replace(
            pipeline_state=s, obs=s.obs, reward=s.reward, done=s.done * (1.0 - s.truncated)
        )

    @property
    def observation_size(self) -> int:
        return self.env.observation_size

    @property
    def action_size(self) -> int:
        return self.env.space.total_dim

    @property
    def backend(self) -> str:
        return "jax"
