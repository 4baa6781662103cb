"""A preallocated ring replay buffer of JAX arrays, shared by SCORE and every off-policy baseline.

The buffer is a pytree (``flax.struct``), so adding and sampling live inside the jitted
training epoch: no host round trip per step.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class Transition:
    """One step of experience (add leading axes for batches).

    Attributes:
      obs: ``[obs_size]`` observation o_t (shared by all sub-spaces).
      action: ``[n, width]`` normalised action the environment received (after failures).
      reward: ``[]`` team reward r_t.
      next_obs: ``[obs_size]`` observation o_{t+1} reached by the step (before any reset).
      terminal: ``[]`` 1.0 if o_{t+1} is terminal (no bootstrap); time-limit ends are not.
      active: ``[n]`` bool, sub-spaces that worked at this step.
    """

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    next_obs: jax.Array
    terminal: jax.Array
    active: jax.Array


@struct.dataclass
class ReplayBuffer:
    data: Transition  # every leaf has a leading [capacity] axis
    position: jax.Array  # [] int32, next slot to write
    size: jax.Array  # [] int32, number of valid slots

    @property
    def capacity(self) -> int:
        return jax.tree.leaves(self.data)[0].shape[0]


def replay_init(example: Transition, capacity: int) -> ReplayBuffer:
    """An empty buffer of ``capacity`` slots shaped like ``example`` (one unbatched transition)."""
    data = jax.tree.map(
        lambda x: jnp.zeros((capacity, *jnp.shape(x)), jnp.asarray(x).dtype), example
    )
    return ReplayBuffer(data, jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32))


def replay_add(buffer: ReplayBuffer, batch: Transition) -> ReplayBuffer:
    """Write a batch ``[B, ...]`` of transitions, overwriting the oldest when full."""
    b = jax.tree.leaves(batch)[0].shape[0]
    idx = (buffer.position + jnp.arange(b)) % buffer.capacity
    data = jax.tree.map(lambda d, x: d.at[idx].set(x), buffer.data, batch)
    return ReplayBuffer(
        data, (buffer.position + b) % buffer.capacity, jnp.minimum(buffer.size + b, buffer.capacity)
    )


def replay_sample(buffer: ReplayBuffer, key: jax.Array, batch_size: int) -> Transition:
    """``batch_size`` transitions drawn uniformly (with replacement) from the filled slots."""
    idx = jax.random.randint(key, (batch_size,), 0, jnp.maximum(buffer.size, 1))
    return jax.tree.map(lambda d: d[idx], buffer.data)
