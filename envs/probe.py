"""A tiny composite environment with an analytic optimum, for testing learners.

Three sub-spaces of different kinds and sizes: ``a`` (continuous, 2 dims), ``b`` (continuous,
3 dims) and ``c`` (discrete, 1 dim with 5 choices). The observation is a random context
vector ``x`` in [-1, 1]^4 drawn anew every step. The best sub-action of each sub-space is a
known function of ``x``:

  a* = 0.5 * x[:2],   b* = (0.6, -0.6, 0.0),   c* = grid value 1 (normalised -0.5).

Reward per step: ``1 - mean over the 6 real dims of (a - a*)^2``, so the optimum is 1 per
step, ``episode_length`` per episode. Failed sub-spaces score like any other action.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

from envs.base import CompositeEnv, EnvHints, EnvState, build_config
from score_jax.core.spaces import CompositeSpace, SubSpace


@dataclasses.dataclass(frozen=True)
class ProbeConfig:
    episode_length: int = 10

    def __post_init__(self):
        if self.episode_length < 1:
            raise ValueError(f"episode_length must be >= 1, got {self.episode_length}")


PROBE_SPACE = CompositeSpace(
    (
        SubSpace.continuous("a", 2, -1.0, 1.0, 0.0),
        SubSpace.continuous("b", 3, -1.0, 1.0, 0.0),
        SubSpace.discrete("c", 1, 0.0, 4.0, 2.0, n_choices=5),
    )
)


@struct.dataclass
class ProbeSim:
    key: jax.Array


@struct.dataclass
class ProbeMetrics:
    squared_error: jax.Array


class ProbeEnv(CompositeEnv):
    name = "probe"
    observation_size = 4
    hints = EnvHints(total_steps=4_000, eval_every=0)

    def __init__(self, config: ProbeConfig = ProbeConfig()):
        self.config = config
        self.space = PROBE_SPACE
        self.episode_length = config.episode_length

    def best_action(self, obs: jax.Array) -> jax.Array:
        """``[4]`` observation -> ``[n, max_dim]`` normalised optimal action."""
        best = jnp.zeros((self.space.n, self.space.max_dim))
        best = best.at[0, :2].set(0.5 * obs[:2])
        best = best.at[1, :3].set(jnp.array([0.6, -0.6, 0.0]))
        return best.at[2, 0].set(-0.5)

    def _obs(self, key):
        return jax.random.uniform(key, (4,), minval=-1.0, maxval=1.0)

    def reset(self, key: jax.Array) -> EnvState:
        key, key_obs = jax.random.split(key)
        zero = jnp.zeros((), jnp.float32)
        return EnvState(
            ProbeSim(key),
            self._obs(key_obs),
            zero,
            zero,
            zero,
            jnp.zeros((), jnp.int32),
            ProbeMetrics(zero),
        )

    def step(self, state: EnvState, action: jax.Array) -> EnvState:
        a = self.space.from_physical(self.space.to_physical(action))  # clip + snap like a real env
        err = (
            jnp.sum(jnp.where(self.space.dim_mask, (a - self.best_action(state.obs)) ** 2, 0.0))
            / self.space.total_dim
        )
        key, key_obs = jax.random.split(state.sim.key)
        t = state.t + 1
        done = (t >= self.episode_length).astype(jnp.float32)
        return EnvState(
            ProbeSim(key), self._obs(key_obs), 1.0 - err, done, done, t, ProbeMetrics(err)
        )


def make_probe(**overrides) -> ProbeEnv:
    return ProbeEnv(build_config(ProbeConfig, overrides))


make_probe.config_class = ProbeConfig  # typed --env-options (envs.option_types)
