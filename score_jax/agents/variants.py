"""Transfer variants of the baselines built for the full space (§5.2.4, §5.4, Table 3), implemented
once for the brax baselines and the multi-agent ones.

A fixed-width baseline (PPO, SAC, H-PPO, MADDPG) cannot grow: its network is built for ALL
sub-spaces of the full space. QMIX and MAAC can grow (``agents.growth``), and can also be built
that way when a variant is asked for (``--single.transfer-variant``). In a subset run
(``--subspaces``) the heads of the unseen sub-spaces exist but their sub-actions never reach the
environment, which gets the sub-spaces' defaults instead (``replace_unseen``, through
``score_jax.core.failures``). The variant says what those heads do meanwhile:

- ``plain``:   frozen (``freeze``: exactly zero gradient, so Adam never moves them);
- ``mask``:    trained like the rest (they only see noise, the entropy bonus, or a critic's
  gradient at the default they were replaced by);
- ``penalty``: ``mask`` plus ``penalty_coef * mean_batch sum_dims (a_unseen - a_default)^2``
  on their deterministic sub-actions (``penalty``, added to the losses by ``penalize``).

``score-transfer --checkpoint RUN`` then fine-tunes the same network on the full space, where
nothing is replaced (``Algorithm.grow`` keeps the parameters as they are). An algorithm uses
this module by (1) routing its environment actions through ``replace_unseen`` (brax agents:
``agents.brax.flat_env.BraxFlatEnv(controlled=...)``; multi-agent baselines: the critic sees
``lift_batch`` and ``pass_unseen``, ``agents.marl.common.MarlVariant``) and (2) wrapping its
policy's forward pass with ``variant_params`` and ``variant_output`` (``variant_apply`` for
brax's signature), given a ``head_mask`` of its unseen heads (brax's MLP: output columns,
``brax_agents.mlp_head_mask``; H-PPO: whole heads, ``hppo.hppo_head_mask``; stacked per-agent
networks: their rows, ``agent_rows``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from score_jax.agents.growth import is_per_agent
from score_jax.agents.replay import Transition
from score_jax.core.failures import FailureMode, apply_failures
from score_jax.core.spaces import CompositeSpace

VARIANTS = ("plain", "mask", "penalty")


def check_variant(variant: str) -> None:
    if variant not in VARIANTS:
        raise ValueError(f"unknown transfer variant {variant!r}; choose one of {list(VARIANTS)}")


def seen_mask(space: CompositeSpace, agent_index) -> np.ndarray:
    """``[n]`` bool: True for the sub-spaces a run controls (``agent_index``)."""
    seen = np.zeros(space.n, bool)
    seen[np.asarray(agent_index)] = True
    return seen


def flat_columns(space: CompositeSpace, subspaces: np.ndarray) -> np.ndarray:
    """``[total_dim]`` bool: the flat action columns that belong to the sub-spaces marked in
    ``subspaces [n]``."""
    return np.repeat(np.asarray(subspaces, bool), space.dims)


def replace_unseen(space: CompositeSpace, action: jax.Array, seen: np.ndarray) -> jax.Array:
    """``[..., n, w]`` (``w >= max_dim``) -> the same with every unseen sub-space at its default
    (padding columns of unseen rows 0).

    The replacement is the DEFAULT failure mode of ``score_jax.core.failures.apply_failures`` with
    the unseen sub-spaces marked failed, so it is the same code path as a failed controller.
    """
    d = space.max_dim
    lead = action.shape[:-2]
    flat = action[..., :d].reshape((-1, space.n, d))
    key = jax.random.PRNGKey(0)  # unused by the DEFAULT mode
    out = jax.vmap(
        lambda a: apply_failures(space, a, jnp.asarray(seen), FailureMode.DEFAULT, key, a)
    )(flat).reshape(lead + (space.n, d))
    pad = jnp.where(jnp.asarray(seen)[:, None], action[..., d:], 0.0)
    return jnp.concatenate([out, pad], -1)


def pass_unseen(space: CompositeSpace, action: jax.Array, seen: np.ndarray) -> jax.Array:
    """``replace_unseen`` in value, identity in gradient: a critic evaluated on it sees what the
    environment receives, while the unseen agents' actors still get its gradient (the ``mask``
    variant of a multi-agent baseline trains them through it)."""
    replaced = replace_unseen(space, action, seen)
    straight = replaced + (action - jax.lax.stop_gradient(action))  # value: exactly replaced
    return jnp.where(jnp.asarray(seen)[:, None], action, straight)


def lift_batch(space: CompositeSpace, batch: Transition, agent_index, seen) -> Transition:
    """A replay batch of the run's agents (``action [B, k, w]``, ``active [B, k]``) -> the same
    for every sub-space of the space (``[B, n, w]``, ``[B, n]``): the unseen ones at the
    defaults the environment received, and always active."""
    idx = np.asarray(agent_index)
    b, _, w = batch.action.shape
    action = jnp.zeros((b, space.n, w), batch.action.dtype).at[:, idx].set(batch.action)
    active = jnp.ones((b, space.n), bool).at[:, idx].set(batch.active)
    return batch.replace(action=replace_unseen(space, action, seen), active=active)


def freeze(params: Any, frozen: Any) -> Any:
    """Stop the gradient of every parameter entry where ``frozen`` (a matching pytree of bool
    arrays, broadcastable to each leaf) is True; the forward value is unchanged."""
    return jax.tree.map(lambda p, m: jnp.where(m, jax.lax.stop_gradient(p), p), params, frozen)


def agent_rows(params: Any, rows) -> Any:
    """``freeze``'s mask of the rows ``rows [n]`` (bool) of every per-agent leaf (under an
    ``agents`` key, ``agents.growth.is_per_agent``); shared leaves are not marked."""
    rows = np.asarray(rows, bool)
    mark = lambda path, x: (
        rows.reshape((-1,) + (1,) * (x.ndim - 1)) if is_per_agent(path) else np.zeros((), bool)
    )
    return jax.tree_util.tree_map_with_path(mark, params)


def penalty(deviation: jax.Array, coef) -> jax.Array:
    """The ``penalty`` variant's term: ``coef * mean_batch deviation`` (``deviation [B]``: the
    summed squared deviation of the unseen heads' deterministic sub-actions from the defaults)."""
    return coef * jnp.mean(deviation)


def agent_deviation(action: jax.Array, default, dim_mask, unseen) -> jax.Array:
    """``action [..., n, w] -> [...]``: sum over the ``unseen [n]`` agents' real dims
    (``dim_mask [n, w]``) of ``(a - default)^2`` (``default [n, w]``)."""
    keep = jnp.asarray(dim_mask) & jnp.asarray(unseen)[:, None]
    return jnp.sum(jnp.where(keep, (action - default) ** 2, 0.0), axis=(-2, -1))


def penalize(x: jax.Array, penalty: Callable[[jax.Array], jax.Array], on=None) -> jax.Array:
    """Identity on ``x`` whose backward pass adds ``grad(penalty)(on)`` to ``on``'s cotangent
    (``on`` defaults to ``x``).

    Placed on a policy network's output it adds ``penalty(on)`` to whatever loss the output
    feeds (once per differentiated forward pass), without touching that loss's code: this is
    how the ``penalty`` variant reaches into brax's PPO and SAC actor losses and the shared
    SAC, DDPG and QMIX losses. ``on`` lets a sampled output carry the penalty of the
    deterministic one it was drawn around.
    """

    @jax.custom_vjp
    def ident(y, z):
        return y

    def fwd(y, z):
        return y, z

    def bwd(z, g):
        extra = jax.grad(penalty)(z)
        return (g + extra, jnp.zeros_like(z)) if on is None else (g, extra)

    ident.defvjp(fwd, bwd)
    return ident(x, x if on is None else on)


def variant_params(params: Any, variant: str, head_mask: Callable[[Any], Any]) -> Any:
    """The parameters a policy's forward pass uses: ``plain`` freezes the unseen heads
    (``head_mask(params)``), the others leave them."""
    return freeze(params, head_mask(params)) if variant == "plain" else params


def variant_output(
    out: jax.Array, variant: str, deviation: Callable, coef: float, on=None
) -> jax.Array:
    """A policy's output; under ``penalty`` it carries the gradient of
    ``penalty(deviation(on or out), coef)`` (``penalize``)."""
    if variant != "penalty":
        return out
    return penalize(out, lambda y: penalty(deviation(y), coef), on)


def variant_apply(
    apply: Callable, variant: str, head_mask: Callable[[Any], Any], deviation: Callable, coef: float
) -> Callable:
    """Wrap a brax-style policy forward pass
    ``apply(processor_params, params, obs) -> dist_params``.

    Args:
      apply: the network's forward pass.
      variant: ``plain`` | ``mask`` | ``penalty``.
      head_mask: ``params -> pytree of bool`` marking the unseen heads' parameters.
      deviation: ``dist_params [..., P] -> [...]`` summed squared deviation of the unseen
        heads' deterministic sub-actions from their defaults.
      coef: weight of the penalty.

    The forward value is always ``apply``'s; only gradients differ between variants.
    """
    check_variant(variant)

    def wrapped(processor_params, params, obs):
        out = apply(processor_params, variant_params(params, variant, head_mask), obs)
        return variant_output(out, variant, deviation, coef)

    return wrapped
