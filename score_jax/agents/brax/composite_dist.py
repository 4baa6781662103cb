"""A hybrid action distribution over a ``CompositeSpace`` for brax's PPO (H-PPO, Fan et al. 2019).

Flat layouts (no padded columns exist here, so every term counts a real dimension):
- distribution parameters ``[..., P]``, sub-space after sub-space in the space's order:
  a continuous sub-space of ``d`` dims owns ``d`` means then ``d`` raw scales; a discrete one
  owns ``d * n_choices`` logits (row-major ``[d, n_choices]``);
- raw actions ``[..., total_dim]``: pre-tanh Gaussian samples on continuous dims, the chosen
  grid index (as float32) on discrete dims;
- environment actions ``[..., total_dim]`` in [-1, 1]: ``tanh`` of the continuous raw values,
  the normalised grid value ``-1 + 2 k / (n - 1)`` of the discrete ones (``BraxFlatEnv``).

It implements the ``brax.training.distribution.ParametricDistribution`` interface that brax's
PPO calls (sample / log_prob / entropy / postprocess / mode / create_dist with ``loc``,
``scale`` and ``kl_divergence`` for its metrics), so brax's PPO loop trains it unchanged.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from brax.training.distribution import ParametricDistribution

from score_jax.core.spaces import CompositeSpace
from score_jax.networks.actor import default_choice, default_offset

_NEG = -1e9  # logit of a choice a dim does not have (finite: 0 * log p stays 0)


class CompositeDist:
    """Gaussians on the continuous dims, categoricals on the discrete dims."""

    def __init__(self, loc, scale, logits):
        self.gauss_loc, self.gauss_scale, self.logits = loc, scale, logits
        # brax's PPO loss reports mean/min/max of loc and scale: give it a non-empty array.
        self.loc = loc if loc.shape[-1] else jnp.zeros(loc.shape[:-1] + (1,))
        self.scale = scale if scale.shape[-1] else jnp.ones(scale.shape[:-1] + (1,))

    def kl_divergence(self, old: CompositeDist) -> jax.Array:
        """KL(old || self) summed over dims: ``[...]``."""
        gauss = jnp.sum(
            jnp.log(self.gauss_scale / old.gauss_scale)
            + (old.gauss_scale**2 + (old.gauss_loc - self.gauss_loc) ** 2)
            / (2 * self.gauss_scale**2)
            - 0.5,
            axis=-1,
        )
        logp_old, logp_new = jax.nn.log_softmax(old.logits), jax.nn.log_softmax(self.logits)
        cat = jnp.sum(jnp.exp(logp_old) * (logp_old - logp_new), axis=(-2, -1))
        return gauss + cat


class CompositeDistribution(ParametricDistribution):
    """Tanh-normal continuous dims x categorical discrete dims of one ``CompositeSpace``."""

    def __init__(self, space: CompositeSpace, min_std: float = 0.001):
        loc_idx, scale_idx, cont_flat, logit_idx, n_choices, disc_flat, head_sizes = (
            [],
            [],
            [],
            [],
            [],
            [],
            [],
        )
        p = f = 0
        max_c = max([s.n_choices for s in space.subspaces] + [1])
        for s in space.subspaces:
            if s.kind == "continuous":
                loc_idx += range(p, p + s.dim)
                scale_idx += range(p + s.dim, p + 2 * s.dim)
                cont_flat += range(f, f + s.dim)
                size = 2 * s.dim
            else:
                for d in range(s.dim):
                    row = p + d * s.n_choices + np.arange(max_c)
                    logit_idx.append(np.where(np.arange(max_c) < s.n_choices, row, -1))
                    n_choices.append(s.n_choices)
                disc_flat += range(f, f + s.dim)
                size = s.dim * s.n_choices
            head_sizes.append(size)
            p, f = p + size, f + s.dim
        self.space, self.min_std, self.head_sizes = space, min_std, tuple(head_sizes)
        self.loc_idx, self.scale_idx, self.cont_flat = (
            np.asarray(x, np.int32) for x in (loc_idx, scale_idx, cont_flat)
        )
        self.logit_idx = np.asarray(logit_idx, np.int32).reshape(
            -1, max_c
        )  # [Nd, C], -1 = no such choice
        self.n_choices = np.asarray(n_choices, np.int32)  # [Nd]
        self.disc_flat = np.asarray(disc_flat, np.int32)
        self.total_dim = f
        super().__init__(param_size=p, postprocessor=None, event_ndims=1, reparametrizable=False)

    def prior_bias(self, prior: np.ndarray, prior_logit: float) -> np.ndarray:
        """``[P]`` distribution parameters of the default prior (the offsets SCORE's actors add):
        ``atanh(default)`` on the means of continuous dims and ``prior_logit`` on the default
        choice's logit of discrete dims, for the sub-spaces marked in ``prior [n]``; 0
        elsewhere (raw scales, the other logits, sub-spaces without the prior)."""
        default = np.asarray(self.space.default_action())
        out, p = np.zeros(self.param_size, np.float32), 0
        for i, (s, size) in enumerate(zip(self.space.subspaces, self.head_sizes, strict=True)):
            if prior[i] and s.kind == "continuous":
                out[p : p + s.dim] = np.asarray(default_offset(default[i, : s.dim]))
            elif prior[i]:
                k = np.asarray(default_choice(default[i, : s.dim], s.n_choices)).astype(int)
                out[p + np.arange(s.dim) * s.n_choices + k] = prior_logit
            p += size
        return out

    # -- parameters -> distribution ---------------------------------------------------------
    def create_dist(self, parameters: jax.Array) -> CompositeDist:
        loc = parameters[..., self.loc_idx]
        scale = jax.nn.softplus(parameters[..., self.scale_idx]) + self.min_std
        logits = jnp.where(
            self.logit_idx >= 0, parameters[..., jnp.maximum(self.logit_idx, 0)], _NEG
        )
        return CompositeDist(loc, scale, logits)

    def _grid(self, k: jax.Array) -> jax.Array:
        return k.astype(jnp.float32) / (self.n_choices - 1) * 2.0 - 1.0

    def _assemble(self, cont: jax.Array, disc: jax.Array) -> jax.Array:
        out = jnp.zeros(cont.shape[:-1] + (self.total_dim,), jnp.float32)
        return out.at[..., self.cont_flat].set(cont).at[..., self.disc_flat].set(disc)

    # -- the ParametricDistribution interface brax's PPO uses ---------------------------------
    def sample_no_postprocessing(self, parameters, seed):
        """``[..., P] -> raw [..., total_dim]`` (pre-tanh values, choice indices)."""
        dist = self.create_dist(parameters)
        key_gauss, key_cat = jax.random.split(seed)
        u = dist.gauss_loc + dist.gauss_scale * jax.random.normal(key_gauss, dist.gauss_loc.shape)
        k = jax.random.categorical(key_cat, dist.logits)
        return self._assemble(u, k.astype(jnp.float32))

    def postprocess(self, event):
        """raw ``[..., total_dim]`` -> environment action in [-1, 1]."""
        k = jnp.round(event[..., self.disc_flat]).astype(jnp.int32)
        return self._assemble(jnp.tanh(event[..., self.cont_flat]), self._grid(k))

    def inverse_postprocess(self, event):
        raise NotImplementedError("the discrete part of a composite action has no inverse bijector")

    def mode(self, parameters):
        """Deterministic action ``[..., total_dim]``: tanh(mean), most likely choice."""
        dist = self.create_dist(parameters)
        return self._assemble(
            jnp.tanh(dist.gauss_loc), self._grid(jnp.argmax(dist.logits, axis=-1))
        )

    def log_prob(self, parameters, actions):
        """log-density of raw ``actions [..., total_dim]``: ``[...]``, one term per real dim
        (tanh-normal with the tanh Jacobian on continuous dims, log-softmax on discrete dims)."""
        dist = self.create_dist(parameters)
        u = actions[..., self.cont_flat]
        z = (u - dist.gauss_loc) / dist.gauss_scale
        gauss = (
            -0.5 * z**2 - 0.5 * jnp.log(2 * jnp.pi) - jnp.log(dist.gauss_scale) - _tanh_log_det(u)
        )
        k = jnp.round(actions[..., self.disc_flat]).astype(jnp.int32)
        cat = jnp.take_along_axis(jax.nn.log_softmax(dist.logits), k[..., None], axis=-1)[..., 0]
        return jnp.sum(gauss, axis=-1) + jnp.sum(cat, axis=-1)

    def entropy(self, parameters, seed):
        """``[...]``: Gaussian entropy + tanh Jacobian at one sample (as brax's tanh-normal) on
        continuous dims, exact categorical entropy on discrete dims."""
        dist = self.create_dist(parameters)
        u = dist.gauss_loc + dist.gauss_scale * jax.random.normal(seed, dist.gauss_loc.shape)
        gauss = 0.5 + 0.5 * jnp.log(2 * jnp.pi) + jnp.log(dist.gauss_scale) + _tanh_log_det(u)
        logp = jax.nn.log_softmax(dist.logits)
        cat = -jnp.sum(jnp.exp(logp) * logp, axis=-1)
        return jnp.sum(gauss, axis=-1) + jnp.sum(cat, axis=-1)

    def deviation(self, parameters, target: jax.Array) -> jax.Array:
        """Squared deviation per flat dim ``[..., total_dim]`` from ``target [total_dim]``
        (normalised units): ``(tanh(mean) - t)^2`` on continuous dims, ``E_k[(v_k - t)^2]`` on
        discrete dims (zero only when all the mass sits on the target choice)."""
        dist = self.create_dist(parameters)
        t = jnp.asarray(target, jnp.float32)
        cont = (jnp.tanh(dist.gauss_loc) - t[self.cont_flat]) ** 2
        values = (
            jnp.arange(self.logit_idx.shape[-1]) / (self.n_choices[:, None] - 1.0) * 2.0 - 1.0
        )  # [Nd, C]
        disc = jnp.sum(
            jax.nn.softmax(dist.logits) * (values - t[self.disc_flat][:, None]) ** 2, axis=-1
        )
        return self._assemble(cont, disc)


def _tanh_log_det(u: jax.Array) -> jax.Array:
    """log |d tanh(u) / du|, numerically stable."""
    return 2.0 * (jnp.log(2.0) - u - jax.nn.softplus(-2.0 * u))
