"""The one small MLP every SCORE network is built from."""

from __future__ import annotations

from typing import Callable, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp


class MLP(nn.Module):
    """``[..., d_in] -> [..., out_dim]``: Dense layers with an activation between them.

    Works on any number of leading batch axes (Dense acts on the last axis), so one set of
    weights is shared by every agent / set element without a vmap.
    """

    hidden: Sequence[int]
    out_dim: int
    activation: Callable[[jax.Array], jax.Array] = nn.relu
    kernel_init: Callable = nn.initializers.lecun_normal()
    out_kernel_init: Callable | None = None

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for i, width in enumerate(self.hidden):
            x = self.activation(nn.Dense(width, kernel_init=self.kernel_init, name=f"dense_{i}")(x))
        out_init = self.out_kernel_init or self.kernel_init
        return nn.Dense(self.out_dim, kernel_init=out_init, name="out")(x)


def gaussian_head(raw: jax.Array, log_std_min: float = -6.0, log_std_max: float = 2.0) -> tuple[jax.Array, jax.Array]:
    """Split ``[..., 2 d]`` into ``(mean [..., d], log_std [..., d])``.

    ``log_std`` is soft-clipped into ``[log_std_min, log_std_max]`` with two softplus
    (identity near 0, so a fresh head starts at unit std; a hard clip would kill the
    gradient at the bounds).
    """
    mean, raw_log_std = jnp.split(raw, 2, axis=-1)
    return mean, soft_clip(raw_log_std, log_std_min, log_std_max)


def soft_clip(x: jax.Array, low: float, high: float) -> jax.Array:
    """Smooth clip of ``x`` into ``[low, high]`` (about the identity well inside)."""
    x = high - jax.nn.softplus(high - x)
    return low + jax.nn.softplus(x - low)
