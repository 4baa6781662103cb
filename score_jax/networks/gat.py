"""The masked graph attention layer of the SCORE critic (§3.2, §4.2), and its weight layout.

One pure function, ``gat_layer``, is used whether the weights are plain parameters or come
from the state hypernetwork (``Theta^(l) = MLP(s^t)``, §4.2): the weights are an argument.

Attention (§4.2), for agent i over the active agents j (i included, the graph is complete):

    alpha_ij = exp(LeakyReLU(a^T [theta x_i || theta x_j]))
               / sum_k exp(LeakyReLU(a^T [theta x_i || theta x_k]))
    x'_i     = ELU( sum_j alpha_ij theta x_j )                  (the paper's update)
    x'_i     = ELU( theta x_i + sum_j alpha_ij theta x_j )      (``self_term=True``, ours)

On a complete graph this attention is static (Brody et al. 2022): wherever the LeakyReLU keeps
its sign over the senders j, the receiver's term ``a_1 . theta x_i`` is a constant of row i and
cancels in the softmax, so every receiver gets the same weights and, without a self term, the
same output: after the paper's update all agents of a state share one embedding. The self term
keeps each agent's own features inside the nonlinearity (as GraphSAGE / GIN do), at no extra
weights, so the outputs differ per agent and the pooled mean holds products of one agent's
features with the others' message. That is what the layer allows, not what training does with
it: trained critics with the term still gave the agents of a state near-identical embeddings
and no higher return (``docs/learning.md``), so it is a switch (``CriticConfig.self_term``),
off by default.

Masked (failed, dropped or padded) agents are removed with ``where``, never with large
negative additions: they get exactly zero attention, send nothing, and their outputs are
exactly zero, so whatever values they carry (even NaN) cannot change an active agent's output.
The ELU after every layer is ours (the paper writes the linear GAT update); without a
nonlinearity stacked layers would collapse into one linear map of the agent features.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

Aggregation = Literal["attention", "mean", "sum"]
AGGREGATIONS = ("attention", "mean", "sum")
LEAKY_RELU_SLOPE = 0.2  # as in the GAT paper (Velickovic et al. 2018)


@struct.dataclass
class GATWeights:
    """Weights Theta^(l) = {theta^(l), a^(l)} of one GAT layer.

    Attributes:
      theta: ``[d_in, d_out]`` shared linear map.
      attn: ``[2 * d_out]`` attention vector a^(l) (first half scores the receiver i,
        second half the sender j).
    """

    theta: jax.Array
    attn: jax.Array


def gat_layer(
    w: GATWeights,
    x: jax.Array,
    mask: jax.Array,
    aggregation: Aggregation = "attention",
    self_term: bool = False,
) -> tuple[jax.Array, jax.Array]:
    """One masked GAT layer over a complete graph of ``n`` agents.

    Args:
      w: the layer's weights (``theta [d_in, d_out]``, ``attn [2 d_out]``).
      x: ``[n, d_in]`` agent features.
      mask: ``[n]`` bool, True for active agents.
      aggregation: ``"attention"`` (softmax weights above), ``"mean"`` (alpha_ij = 1 / #active)
        or ``"sum"`` (alpha_ij = 1) over the active j.
      self_term: add the receiver's own ``theta x_i`` inside the ELU (see the module docstring).

    Returns:
      ``(x_out [n, d_out], alpha [n, n])``; rows and columns of inactive agents are exactly 0
      in ``alpha``, rows of inactive agents are exactly 0 in ``x_out``.
    """
    if aggregation not in AGGREGATIONS:
        raise ValueError(f"unknown aggregation {aggregation!r}; choose one of {AGGREGATIONS}")
    mask = jnp.asarray(mask, bool)
    # Zero inactive inputs first: 0 * NaN would otherwise leak NaN through alpha_ij = 0.
    h = jnp.where(mask[:, None], x, 0.0) @ w.theta  # [n, d_out]
    edge = mask[:, None] & mask[None, :]  # [n, n] receiver i, sender j
    if aggregation == "attention":
        d = h.shape[-1]
        score = jax.nn.leaky_relu(
            (h @ w.attn[:d])[:, None] + (h @ w.attn[d:])[None, :], LEAKY_RELU_SLOPE
        )
        top = jnp.max(jnp.where(edge, score, -jnp.inf), axis=1, keepdims=True)
        top = jax.lax.stop_gradient(jnp.where(jnp.isfinite(top), top, 0.0))
        # Double where: the exponent of a masked edge is 0 (finite), then the weight is 0.
        weight = jnp.where(edge, jnp.exp(jnp.where(edge, score - top, 0.0)), 0.0)
        total = jnp.sum(weight, axis=1, keepdims=True)
        alpha = weight / jnp.where(total > 0, total, 1.0)
    elif aggregation == "mean":
        count = jnp.sum(edge, axis=1, keepdims=True)
        alpha = edge / jnp.maximum(count, 1).astype(h.dtype)
    else:
        alpha = edge.astype(h.dtype)
    message = alpha @ h
    out = jax.nn.elu(message + h if self_term else message)
    return jnp.where(mask[:, None], out, 0.0), alpha


def gat_stack(
    weights: Sequence[GATWeights],
    x: jax.Array,
    mask: jax.Array,
    aggregation: Aggregation = "attention",
    self_term: bool = False,
) -> tuple[jax.Array, jax.Array]:
    """``m`` GAT layers in a row: ``[n, d_0] -> ([n, d_m], alpha [m, n, n])``."""
    alphas = []
    for w in weights:
        x, alpha = gat_layer(w, x, mask, aggregation, self_term)
        alphas.append(alpha)
    return x, jnp.stack(alphas)


# --- flat vector <-> list of GATWeights (the hypernetwork emits one flat vector) ----------
def gat_shapes(dims: Sequence[int]) -> list[tuple[tuple[int, int], tuple[int]]]:
    """Per layer ``((d_in, d_out), (2 d_out,))`` for layer widths ``dims = [d_0, ..., d_m]``."""
    if len(dims) < 2:
        raise ValueError(f"dims needs at least an input and an output width, got {list(dims)}")
    return [((int(a), int(b)), (2 * int(b),)) for a, b in zip(dims[:-1], dims[1:], strict=True)]


def gat_num_params(dims: Sequence[int]) -> int:
    """Total number of GAT weights of ``len(dims) - 1`` layers (the hypernetwork's output size)."""
    return sum(int(np.prod(t)) + a[0] for t, a in gat_shapes(dims))


def unflatten_gat_weights(flat: jax.Array, dims: Sequence[int]) -> list[GATWeights]:
    """``[gat_num_params(dims)]`` -> list of ``m`` GATWeights (layer by layer, theta then attn)."""
    if flat.shape[-1] != gat_num_params(dims):
        raise ValueError(
            f"flat GAT vector has {flat.shape[-1]} entries, "
            f"layers {list(dims)} need {gat_num_params(dims)}"
        )
    out, i = [], 0
    for theta_shape, attn_shape in gat_shapes(dims):
        size = theta_shape[0] * theta_shape[1]
        theta = flat[..., i : i + size].reshape(*flat.shape[:-1], *theta_shape)
        i += size
        attn = flat[..., i : i + attn_shape[0]]
        i += attn_shape[0]
        out.append(GATWeights(theta, attn))
    return out


def flatten_gat_weights(weights: Sequence[GATWeights]) -> jax.Array:
    """Inverse of ``unflatten_gat_weights``: list of GATWeights -> one flat vector."""
    parts = []
    for w in weights:
        parts += [w.theta.reshape(*w.theta.shape[:-2], -1), w.attn]
    return jnp.concatenate(parts, axis=-1)


def init_gat_weights(key: jax.Array, dims: Sequence[int]) -> list[GATWeights]:
    """Glorot-uniform theta and attention vectors for ``len(dims) - 1`` layers."""
    init = jax.nn.initializers.glorot_uniform()
    out = []
    for (theta_shape, attn_shape), k in zip(
        gat_shapes(dims), jax.random.split(key, len(dims) - 1), strict=True
    ):
        k_theta, k_attn = jax.random.split(k)
        attn = init(k_attn, (2, theta_shape[1])).reshape(attn_shape)
        out.append(GATWeights(init(k_theta, theta_shape), attn))
    return out
