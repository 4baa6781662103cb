"""Time-varying action spaces: which sub-spaces work, and what a failed one does (§5.2.3).

The single implementation of failure masks and failure modes. Training (DropNode),
evaluation, the robustness sweep and every baseline call these functions, so a failed
sub-space behaves identically everywhere.

Masks and modes are arrays, not Python values: changing them never retraces a jitted
function, and the robustness sweep vmaps over them.
"""

from __future__ import annotations

import enum

import jax
import jax.numpy as jnp
import numpy as np

from score_jax.core.spaces import CompositeSpace


class FailureMode(enum.IntEnum):
    """What a failed sub-space outputs instead of the policy's sub-action (§5.2.3, §5.3.3)."""

    DEFAULT = 0  # its physical default (0 for the Spider's legs, 19 °C for temperature, ...)
    RANDOM = 1  # a uniformly random sub-action
    LAST = 2  # the sub-action that was applied at the previous step

    @classmethod
    def parse(cls, name: str) -> FailureMode:
        try:
            return cls[name.upper()]
        except KeyError:
            raise ValueError(
                f"unknown failure mode {name!r}; choose one of {[m.name.lower() for m in cls]}"
            ) from None


def apply_failures(
    space: CompositeSpace,
    action: jax.Array,
    active: jax.Array,
    mode: jax.Array | int,
    key: jax.Array,
    last_action: jax.Array,
) -> jax.Array:
    """Replace the sub-actions of failed sub-spaces.

    Args:
      space: the composite space (static).
      action: ``[n, max_dim]`` normalised policy action.
      active: ``[n]`` bool, True where the sub-space works this step.
      mode: int scalar (a ``FailureMode``), may be a traced array.
      key: PRNG key for the ``RANDOM`` mode.
      last_action: ``[n, max_dim]`` the action applied at the previous step (``LAST`` mode).

    Returns:
      ``[n, max_dim]`` the action the environment receives; padded columns zero.
    """
    mode = jnp.asarray(mode, jnp.int32)
    replacement = jnp.select(
        [mode == FailureMode.DEFAULT, mode == FailureMode.RANDOM],
        [space.default_action(), space.sample(key)],
        last_action,
    )
    out = jnp.where(active[:, None], action, replacement)
    return jnp.where(space.dim_mask, out, 0.0)


def failure_mask(
    key: jax.Array, n: int, n_failed: jax.Array | int, valid: jax.Array | None = None
) -> jax.Array:
    """``[n]`` bool mask with exactly ``min(n_failed, n_valid - 1)`` valid agents failed, drawn
    uniformly.

    At least one valid sub-space always stays active (an all-failed step has no policy to
    evaluate). ``valid`` (``[n]`` bool, default all True) marks agents that exist at all:
    invalid ones are always False in the result.
    """
    valid = jnp.ones((n,), bool) if valid is None else valid
    n_valid = jnp.sum(valid)
    n_failed = jnp.clip(jnp.asarray(n_failed, jnp.int32), 0, n_valid - 1)
    # Rank valid agents in a random order; the first n_failed of them fail.
    scores = jnp.where(valid, jax.random.uniform(key, (n,)), 2.0)
    rank = jnp.argsort(jnp.argsort(scores))
    return valid & (rank >= n_failed)


def dropnode_mask(key: jax.Array, valid: jax.Array, drop_prob: jax.Array | float) -> jax.Array:
    """DropNode (§4.2 end): drop each valid agent independently with ``drop_prob``.

    Returns ``[n]`` bool; if every valid agent would drop, one random valid agent is kept.
    """
    key_drop, key_keep = jax.random.split(key)
    keep = valid & (jax.random.uniform(key_drop, valid.shape) >= drop_prob)
    rescue = jax.nn.one_hot(
        jax.random.categorical(key_keep, jnp.where(valid, 0.0, -jnp.inf)),
        valid.shape[0],
        dtype=bool,
    )
    return jnp.where(jnp.any(keep), keep, rescue)


def check_active(active, n: int) -> None:
    """Host-side check of a user-given mask: right length and at least one active sub-space."""
    active = np.asarray(active)
    if active.shape != (n,):
        raise ValueError(f"active mask must have shape ({n},), got {active.shape}")
    if not active.any():
        raise ValueError("active mask has every sub-space failed; at least one must stay active")


def fail_batch(
    space: CompositeSpace, action, last_action, key, n_failed, mode, controlled
) -> tuple[jax.Array, jax.Array]:
    """Failures for a batch of environments, as every rollout applies them.

    Args:
      action: ``[B, n, max_dim]`` environment actions; ``last_action`` the same shape.
      n_failed: how many of the ``controlled`` sub-spaces fail in each environment (redrawn per
        call).
      mode: a ``FailureMode`` value; ``controlled``: ``[n]`` bool (numpy), sub-spaces agents drive
        (the others are already at their defaults and never count as failed).

    Returns:
      ``(applied [B, n, max_dim], active [B, n])``.
    """
    b = action.shape[0]
    controlled = jnp.asarray(controlled, bool)
    key_mask, key_fill = jax.random.split(key)
    active = (
        jax.vmap(lambda k: failure_mask(k, space.n, n_failed, controlled))(
            jax.random.split(key_mask, b)
        )
        | ~controlled
    )
    applied = jax.vmap(apply_failures, in_axes=(None, 0, 0, None, 0, 0))(
        space, action, active, mode, jax.random.split(key_fill, b), last_action
    )
    return applied, active
