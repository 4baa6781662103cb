"""The one small MLP every SCORE network is built from."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp


class ConcatDense(nn.Module):
    """``nn.Dense`` of the concatenation of ``parts`` (the same params:
    ``kernel [sum d_i, features]``, ``bias``), computed as a sum of each part times its row block
    of the kernel.

    Parts broadcast against each other on their leading axes, so a part shared by every agent
    (the state embedding e_o next to per-agent sub-actions) is multiplied once per sample
    instead of once per agent, and is never copied into a concatenation.
    """

    features: int
    kernel_init: Callable = nn.initializers.lecun_normal()

    @nn.compact
    def __call__(self, parts: Sequence[jax.Array]) -> jax.Array:
        sizes = [p.shape[-1] for p in parts]
        kernel = self.param("kernel", self.kernel_init, (sum(sizes), self.features))
        out, i = self.param("bias", nn.initializers.zeros_init(), (self.features,)), 0
        for part, size in zip(parts, sizes, strict=True):
            out = out + part @ kernel[i : i + size]
            i += size
        return out


class MLP(nn.Module):
    """``[..., d_in] -> [..., out_dim]``: Dense layers with an activation between them.

    Works on any number of leading batch axes (Dense acts on the last axis), so one set of
    weights is shared by every agent / set element without a vmap. The input may also be a
    sequence of parts to concatenate on the last axis, broadcast on the leading ones
    (``ConcatDense``: same parameters as the concatenated input, less work).

    ``layer_norm``: a LayerNorm between every hidden Dense and its activation (the normalised
    critics of SimBa, BRO and CrossQ; params ``norm_<i>``).
    """

    hidden: Sequence[int]
    out_dim: int
    activation: Callable[[jax.Array], jax.Array] = nn.relu
    kernel_init: Callable = nn.initializers.lecun_normal()
    out_kernel_init: Callable | None = None
    layer_norm: bool = False

    @nn.compact
    def __call__(self, x: jax.Array | Sequence[jax.Array]) -> jax.Array:
        dense = lambda x: ConcatDense if isinstance(x, (tuple, list)) else nn.Dense
        for i, width in enumerate(self.hidden):
            x = dense(x)(width, kernel_init=self.kernel_init, name=f"dense_{i}")(x)
            if self.layer_norm:
                x = nn.LayerNorm(name=f"norm_{i}")(x)
            x = self.activation(x)
        out_init = self.out_kernel_init or self.kernel_init
        return dense(x)(self.out_dim, kernel_init=out_init, name="out")(x)


def gaussian_head(
    raw: jax.Array, log_std_min: float = -6.0, log_std_max: float = 2.0
) -> tuple[jax.Array, jax.Array]:
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
