"""A preallocated ring replay buffer of JAX arrays, shared by SCORE and every off-policy baseline.

The buffer is a pytree (``flax.struct``), so adding and sampling live inside the jitted
training epoch: no host round trip per step. ``replay_sample_nstep`` turns stored one-step
transitions into n-step ones at sampling time, so the buffer is the same for every n.
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
      discount: ``[]`` extra factor on gamma for the bootstrap, or None (= 1). An m-step sample
        (``replay_sample_nstep``) carries gamma^(m-1), so every loss's target
        ``r + gamma * continuation(batch) * Q'`` bootstraps with gamma^m. Never stored: the
        buffer holds one-step transitions (None has no leaves).
    """

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    next_obs: jax.Array
    terminal: jax.Array
    active: jax.Array
    discount: jax.Array | None = None


def continuation(batch: Transition) -> jax.Array:
    """``[B]``: the factor of gamma * Q'(next_obs) in a TD target: ``1 - terminal``, times
    ``discount`` for n-step samples (one place for every algorithm's loss)."""
    not_done = 1.0 - batch.terminal
    return not_done if batch.discount is None else batch.discount * not_done


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


def replay_sample_nstep(
    buffer: ReplayBuffer,
    key: jax.Array,
    batch_size: int,
    n: int,
    stride: int,
    gamma: jax.Array,
) -> Transition:
    """``batch_size`` n-step transitions: ``reward`` = sum_{k<m} gamma^k r_{t+k}, ``next_obs`` and
    ``terminal`` of step t+m-1, ``discount`` = gamma^(m-1), where m <= n stops after a terminal
    step or at the end of the episode (the next stored step's ``obs`` is not this one's
    ``next_obs``: a reset came between; an environment whose reset observation can equal a
    final one would chain episodes). ``obs``, ``action`` and ``active`` are step t's.

    The buffer is written ``stride`` (the number of environments) transitions per vectorised
    step, so an environment's step t+k is ``k * stride`` slots after its step t. Starts are drawn
    uniformly from the filled slots whose n-1 later steps are written. The rewards in between
    come from the behaviour policy (no off-policy correction, as in common n-step SAC/TD3).
    ``n = 1`` is ``replay_sample`` (the same draws)."""
    if n == 1:
        return replay_sample(buffer, key, batch_size)
    cap = buffer.capacity
    span = (n - 1) * stride
    oldest = jnp.where(buffer.size == cap, buffer.position, 0)
    r = jax.random.randint(key, (batch_size,), 0, jnp.maximum(buffer.size - span, 1))
    idx = (oldest + r[:, None] + stride * jnp.arange(n)[None, :]) % cap  # [B, n]
    steps = jax.tree.map(lambda d: d[idx], buffer.data)  # every leaf [B, n, ...]
    # step k counts when steps 0..k-1 neither ended the episode by a terminal nor by a reset
    same_episode = jnp.all(
        steps.next_obs[:, :-1] == steps.obs[:, 1:], axis=tuple(range(2, steps.obs.ndim))
    )  # [B, n-1]
    goes_on = same_episode & (steps.terminal[:, :-1] == 0)
    counted = jnp.concatenate(
        [jnp.ones((batch_size, 1), bool), jnp.cumprod(goes_on, axis=1).astype(bool)], axis=1
    )  # [B, n]
    powers = gamma ** jnp.arange(n, dtype=jnp.float32)  # [n]
    reward = jnp.sum(jnp.where(counted, powers * steps.reward, 0.0), axis=1)
    last = jnp.sum(counted, axis=1) - 1  # [B], m - 1

    def at_last(x):  # [B, n, ...] -> [B, ...], each sample's step m-1
        return jnp.take_along_axis(x, last.reshape((-1, 1) + (1,) * (x.ndim - 2)), axis=1)[:, 0]

    first = jax.tree.map(lambda x: x[:, 0], steps)
    return first.replace(
        reward=reward,
        next_obs=at_last(steps.next_obs),
        terminal=at_last(steps.terminal),
        discount=gamma ** last.astype(jnp.float32),
    )
