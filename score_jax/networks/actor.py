"""Decentralised SAC actors, one per sub-action space (Alg. 1 lines 2 and 14, footnote 3).

All actors share one architecture; their parameters are stacked on a leading agent axis
(``nn.vmap``), so adding sub-spaces for transfer (§4.3) is a concatenation (``grow_agents``).
Each actor emits, for every column of the padded ``[width]`` action, a Gaussian (used by
continuous dims, squashed with tanh) and ``max_choices`` logits (used by discrete dims,
straight-through Gumbel-softmax). Which head a column uses, and which columns exist, are
ARRAY inputs (``dim_mask``, ``n_choices``) of ``sample_actions``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct

from score_jax.networks.mlp import MLP
from score_jax.networks.stacked import stacked


@dataclasses.dataclass(frozen=True)
class ActorConfig:
    """Actor sizes.

    Attributes:
      hidden: hidden widths of each agent's MLP.
      log_std_min: lower end of the Gaussian log-std (smooth squash).
      log_std_max: upper end of the Gaussian log-std.
      gumbel_temperature: tau of the Gumbel-softmax relaxation (gradient path only).

    With the default prior (``TrainConfig.default_prior``, the agents' ``AgentConsts``)
    actors act around the sub-space's ``default`` (the safe physical value a failed
    controller falls back to): the default is a fixed offset of the Gaussian mean and of the
    logits (``sample_actions(..., default=...)``), and the output layer starts near zero, so an
    untrained deterministic actor plays the default action and exploration starts around it.
    Without it there is no offset: an untrained actor plays ``tanh(~0)`` (mid-range) on
    continuous dims and samples discrete dims from ~uniform logits.
    """

    hidden: tuple[int, ...] = (128, 128)
    log_std_min: float = -5.0
    log_std_max: float = 2.0
    gumbel_temperature: float = 1.0
    head_init_scale: float = 0.01
    """Scale of the output layer's initial kernel: a fresh actor's output is ~0, so it starts
    at the prior of ``sample_actions`` (the sub-space's default, see ``prior_logit``)."""
    prior_logit: float = 3.0
    """Logit bonus of a discrete dim's default choice (added to the actor's logits); with
    ``head_init_scale`` small, a fresh actor picks the default with probability
    ``e^b / (e^b + n_choices - 1)`` (0.47 for 24 hours at b = 3). 0 = uniform start."""


@struct.dataclass
class ActorOutput:
    """Policy parameters of all agents.

    Attributes:
      mean: ``[n, width]`` Gaussian mean (pre-tanh).
      log_std: ``[n, width]`` Gaussian log-std in [log_std_min, log_std_max].
      logits: ``[n, discrete_width, max_choices]`` categorical logits of the first
        ``discrete_width`` columns (a discrete sub-space's dims are its first columns, so
        only those can be discrete; columns past them never need logits).
    """

    mean: jax.Array
    log_std: jax.Array
    logits: jax.Array


class AgentActor(nn.Module):
    """One sub-space's actor:
    ``obs [obs_size] -> (mean [width], log_std [width], logits [dw, C])``."""

    config: ActorConfig
    action_width: int
    max_choices: int
    discrete_width: int

    @nn.compact
    def __call__(self, obs: jax.Array):
        w, C, dw = self.action_width, self.max_choices, self.discrete_width
        head_init = nn.initializers.variance_scaling(
            self.config.head_init_scale**2, "fan_in", "truncated_normal"
        )
        raw = MLP(tuple(self.config.hidden), 2 * w + dw * C, out_kernel_init=head_init, name="mlp")(
            obs
        )
        mean, raw_log_std, logits = raw[:w], raw[w : 2 * w], raw[2 * w :].reshape(dw, C)
        lo, hi = self.config.log_std_min, self.config.log_std_max
        log_std = lo + 0.5 * (hi - lo) * (jnp.tanh(raw_log_std) + 1.0)
        return mean, log_std, logits


class Actors(nn.Module):
    """All n actors, params stacked on axis 0 under ``params["agents"]``.

    ``__call__(obs [obs_size]) -> ActorOutput`` (every agent sees the shared observation).
    ``discrete_width``: the most dims of any discrete sub-space (0 = ``action_width``); it
    sizes the logits head, which otherwise dominates the actor's cost.
    """

    config: ActorConfig
    n_agents: int
    action_width: int
    max_choices: int
    discrete_width: int = 0

    @nn.compact
    def __call__(self, obs: jax.Array) -> ActorOutput:
        dw = min(self.discrete_width or self.action_width, self.action_width)
        mean, log_std, logits = stacked(AgentActor, self.n_agents)(
            self.config, self.action_width, max(self.max_choices, 1), dw, name="agents"
        )(obs)
        return ActorOutput(mean, log_std, logits)


def default_offset(default: jax.Array) -> jax.Array:
    """``atanh(default)``, clipped inside (-1, 1): the pre-tanh mean at which a tanh-Gaussian
    plays the normalised ``default`` (the continuous part of the default prior)."""
    return jnp.arctanh(jnp.clip(default, -0.995, 0.995))


def default_choice(default: jax.Array, n_choices: jax.Array) -> jax.Array:
    """The grid index (float) nearest the normalised ``default`` of a dim with ``n_choices``
    values (the choice the default prior's logit bonus goes to)."""
    return jnp.round((default + 1.0) * 0.5 * jnp.maximum(n_choices - 1, 1))


def _grid(n_choices: jax.Array, max_choices: int) -> tuple[jax.Array, jax.Array]:
    """Normalised grid values ``[..., C]`` (index/steps*2-1, as ``CompositeSpace``) and validity."""
    idx = jnp.arange(max_choices, dtype=jnp.float32)
    steps = jnp.maximum(n_choices - 1, 1).astype(jnp.float32)[..., None]
    return idx / steps * 2.0 - 1.0, idx < n_choices[..., None]


def sample_actions(
    out: ActorOutput,
    dim_mask: jax.Array,
    n_choices: jax.Array,
    key: jax.Array,
    deterministic: bool = False,
    temperature: float = 1.0,
    default: jax.Array | None = None,
    prior_logit: float = 0.0,
    prior: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array]:
    """Sample all agents' actions and their log-probs (reparameterised, differentiable).

    Continuous dims: ``a = tanh(u), u ~ N(mean, std)``, log-prob
    ``log N(u) - log(1 - tanh(u)^2)`` (the tanh change of variables).
    Discrete dims: Gumbel-max picks a grid index k exactly (forward value
    ``-1 + 2k/(n_choices-1)``); the gradient flows through the Gumbel-softmax relaxation
    (straight-through); its log-prob term is the exact ``sum_k p_k log p_k`` over the
    ``n_choices`` valid values (choices >= n_choices excluded), i.e. minus its entropy.
    ``deterministic``: ``tanh(mean)`` and ``argmax(logits)`` (log-probs of those actions).

    Args:
      out: ActorOutput with ``[n, width]`` / ``[n, dw, C]`` leaves.
      dim_mask: ``[n, width]`` bool, real columns.
      n_choices: ``[n, width]`` int, number of grid values of a discrete column, 0 otherwise.
      key: PRNG key.
      temperature: Gumbel-softmax tau (``ActorConfig.gumbel_temperature``).
      default: optional ``[n, width]`` normalised default action: the Gaussian mean is offset
        by ``atanh(default)`` and the default grid choice of a discrete dim gets ``prior_logit``
        extra logit, so a zero actor output plays the default (``ActorConfig``).
      prior_logit: logit bonus of the default choice of discrete dims.
      prior: optional ``[n]`` bool, the agents that act around ``default`` (None = all); the
        others get neither offset (an untrained transfer run's new actors, §4.3).

    Returns:
      ``(action [n, width], log_prob [n])``: padded columns exactly 0, log-probs summed over
      each agent's valid columns.
    """
    dim_mask = jnp.asarray(dim_mask, bool)
    n_choices = jnp.asarray(n_choices, jnp.int32)
    discrete = dim_mask & (n_choices > 0)
    continuous = dim_mask & (n_choices <= 0)
    key_normal, key_gumbel = jax.random.split(key)

    mean = out.mean
    on = 1.0 if prior is None else jnp.asarray(prior, mean.dtype)[:, None]  # [n, 1] or scalar
    if default is not None:
        mean = mean + on * default_offset(default)

    # Continuous: tanh-Gaussian.
    std = jnp.exp(out.log_std)
    noise = jnp.zeros_like(mean) if deterministic else jax.random.normal(key_normal, mean.shape)
    u = mean + std * noise
    log_normal = -0.5 * jnp.square(noise) - out.log_std - 0.5 * math.log(2.0 * math.pi)
    log_det = 2.0 * (math.log(2.0) - u - jax.nn.softplus(-2.0 * u))  # log(1 - tanh(u)^2), stable
    cont_value, cont_logp = jnp.tanh(u), log_normal - log_det

    # Discrete: straight-through Gumbel-softmax over the valid grid values, on the first
    # ``dw`` columns only (columns past discrete_width are never discrete): the Gumbel noise
    # of [n, dw, C] instead of [n, width, C] is most of the actor's cost on a CPU.
    C, dw = out.logits.shape[-1], out.logits.shape[-2]
    grid, valid = _grid(n_choices[..., :dw], C)
    out_logits = out.logits
    if default is not None:  # the grid index nearest the default gets the prior bonus
        default_index = default_choice(default[..., :dw], n_choices[..., :dw])
        bonus = prior_logit * (jnp.arange(C) == default_index[..., None])
        out_logits = out_logits + (bonus if prior is None else on[..., None] * bonus)
    logits = jnp.where(valid, out_logits, -1e9)  # exp underflows to exactly 0 in float32
    log_p = jax.nn.log_softmax(logits, -1)
    # One grid value per column (no discrete dims in the space, C == 1): the choice is certain,
    # so the noise would change nothing; skipping it saves a random draw per update.
    gumbel = (
        jnp.zeros_like(logits)
        if (deterministic or C == 1)
        else jax.random.gumbel(key_gumbel, logits.shape)
    )
    k = jnp.argmax(jnp.where(valid, logits + gumbel, -jnp.inf), -1)
    hard_value = jnp.take_along_axis(grid, k[..., None], -1)[..., 0]
    soft_value = jnp.sum(jax.nn.softmax((logits + gumbel) / temperature, -1) * grid, -1)
    # Straight-through: forward exactly the grid value (x - x is exactly 0, whereas
    # (hard + soft) - soft is not), gradient of the relaxed value.
    disc_value = hard_value + (soft_value - jax.lax.stop_gradient(soft_value))
    # The log-prob of a discrete dim is its exact expectation sum_k p_k log p_k (minus the
    # entropy), as in discrete SAC: the sampled log p(k) has zero expected gradient under a
    # straight-through sample, so the entropy bonus would never act and the choice collapses.
    disc_logp = jnp.sum(jnp.where(valid, jnp.exp(log_p) * log_p, 0.0), -1)
    pad = [(0, 0)] * (disc_value.ndim - 1) + [(0, mean.shape[-1] - dw)]
    disc_value, disc_logp = jnp.pad(disc_value, pad), jnp.pad(disc_logp, pad)

    action = jnp.where(discrete, disc_value, jnp.where(continuous, cont_value, 0.0))
    log_prob = jnp.sum(
        jnp.where(discrete, disc_logp, 0.0) + jnp.where(continuous, cont_logp, 0.0), -1
    )
    return action, log_prob


def actor_policy(
    actors: Actors,
    params: Any,
    consts: Any,
    obs: jax.Array,
    key: jax.Array,
    deterministic: bool = False,
) -> tuple[jax.Array, jax.Array]:
    """All agents' sub-actions for a batch of observations (Alg. 1 line 2).

    ``obs [B, obs] -> (action [B, n, w], log_prob [B, n])``: the stacked ``actors`` applied to
    every observation, then ``sample_actions`` with ``consts`` (``sac.AgentConsts``: dim_mask,
    n_choices, default_action, prior_agents, valid); agents that are not ``valid`` get action
    0, log-prob 0.
    """
    out = jax.vmap(lambda o: actors.apply({"params": params}, o))(obs)
    keys = jax.random.split(key, obs.shape[0])
    cfg = actors.config
    sample = lambda o, k: sample_actions(
        o,
        consts.dim_mask,
        consts.n_choices,
        k,
        deterministic,
        cfg.gumbel_temperature,
        consts.default_action,
        cfg.prior_logit,
        consts.prior_agents,
    )
    action, logp = jax.vmap(sample)(out, keys)
    valid = consts.valid[None, :]
    return jnp.where(valid[..., None], action, 0.0), jnp.where(valid, logp, 0.0)


def grow_agents(params: Any, new_params: Any) -> Any:
    """Concatenate stacked agent params along axis 0: ``n`` old + ``n_new`` new actors.

    ``params`` and ``new_params`` are ``Actors`` params (same config / width / max_choices)
    for n and n_new agents, e.g. ``Actors(cfg, n_new, ...).init(key, obs)["params"]``; the
    result is the params of ``Actors(cfg, n + n_new, ...)`` with the old agents first (§4.3).
    """
    old_shapes = jax.tree_util.tree_map(lambda x: x.shape[1:], params)
    new_shapes = jax.tree_util.tree_map(lambda x: x.shape[1:], new_params)
    if old_shapes != new_shapes:
        raise ValueError(
            "grow_agents: the new actors' params differ in shape from the old ones "
            "(check hidden sizes, action_width, max_choices)"
        )
    return jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b], 0), params, new_params)


def select_agents(params: Any, index: Any) -> Any:
    """The stacked params of the agents at ``index`` (int array), e.g. to reorder or drop."""
    return jax.tree_util.tree_map(lambda x: x[jnp.asarray(index)], params)
