"""Behaviour-only exploration added to the stochastic policy's actions while collecting data."""

from __future__ import annotations

import jax
import jax.numpy as jnp

# Keeps atanh finite at the tanh-squashed bounds (an action of exactly +-1).
_EDGE = 1.0 - 1e-6


def shift_continuous(
    action: jax.Array, continuous: jax.Array, key: jax.Array, std: float
) -> jax.Array:
    """One shared shift per sub-space on its continuous dims, applied before the tanh.

    ``a'_d = tanh(atanh(a_d) + std * eps)`` for every continuous column ``d`` of an agent, with
    ONE ``eps ~ N(0, 1)`` per agent (drawn from ``key``); discrete and padded columns keep
    their value. A diagonal Gaussian moves the mean of a sub-space's d dims by about
    ``std / sqrt(d)``; this moves it by ``std`` (in pre-tanh units), so a sub-space whose dims
    act together (the greenhouse's 24 hourly setpoints) explores its level as a whole.

    Args:
      action: ``[n, w]`` normalised actions of one environment, in [-1, 1].
      continuous: ``[n, w]`` bool, the real continuous columns.
      key: the environment's (held) exploration key.
      std: the shift's standard deviation.

    Returns:
      ``[n, w]`` shifted actions, still in [-1, 1].
    """
    eps = jax.random.normal(key, (action.shape[0], 1), action.dtype)
    pre = jnp.arctanh(jnp.clip(action, -_EDGE, _EDGE))
    return jnp.where(continuous, jnp.tanh(pre + std * eps), action)
