"""Transfer variants of the fixed-width baselines (§5.2.4, §5.4, Table 3), implemented once.

A fixed-width baseline (PPO, SAC, H-PPO, MADDPG) cannot grow: its network is built for ALL
sub-spaces of the full space. In a subset run (``--subspaces``) the heads of the unseen
sub-spaces exist but their sub-actions never reach the environment, which gets the
sub-spaces' defaults instead (``replace_unseen``, through ``score_jax.core.failures``). The
variant says what those heads do meanwhile:

- ``plain``:   frozen (``freeze``: exactly zero gradient, so Adam never moves them);
- ``mask``:    trained like the rest (they only see noise and the entropy bonus);
- ``penalty``: ``mask`` plus ``penalty_coef * mean_batch sum_dims (a_unseen - a_default)^2``
  on their deterministic sub-actions (``penalize``).

``transfer.py --checkpoint RUN`` then fine-tunes the same network on the full space, where
nothing is replaced (``Algorithm.grow`` keeps the parameters as they are). An algorithm uses
this module by (1) routing its environment actions through ``replace_unseen`` (brax agents:
``agents.brax.flat_env.BraxFlatEnv(controlled=...)``) and (2) wrapping its policy's forward pass
with ``variant_apply``, given a ``head_mask`` of its unseen heads (brax's MLP: output
columns, ``brax_agents.mlp_head_mask``; H-PPO: whole heads, ``hppo.hppo_head_mask``). PPO,
SAC and H-PPO do; MADDPG (``maddpg.py``) builds its actors and critic on the controlled
sub-spaces only, so it would first need building on the full space (its unseen actor rows
then masked the same way, or frozen with ``agents.growth.freeze_agent_rows``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

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
    """``[..., n, max_dim]`` -> the same with every unseen sub-space at its default.

    The replacement is the DEFAULT failure mode of ``score_jax.core.failures.apply_failures`` with
    the unseen sub-spaces marked failed, so it is the same code path as a failed controller.
    """
    lead = action.shape[:-2]
    flat = action.reshape((-1,) + action.shape[-2:])
    key = jax.random.PRNGKey(0)  # unused by the DEFAULT mode
    out = jax.vmap(
        lambda a: apply_failures(space, a, jnp.asarray(seen), FailureMode.DEFAULT, key, a)
    )(flat)
    return out.reshape(lead + action.shape[-2:])


def freeze(params: Any, frozen: Any) -> Any:
    """Stop the gradient of every parameter entry where ``frozen`` (a matching pytree of bool
    arrays, broadcastable to each leaf) is True; the forward value is unchanged."""
    return jax.tree.map(lambda p, m: jnp.where(m, jax.lax.stop_gradient(p), p), params, frozen)


def penalize(x: jax.Array, penalty: Callable[[jax.Array], jax.Array]) -> jax.Array:
    """Identity on ``x`` whose backward pass adds ``grad(penalty)(x)``.

    Placed on a policy network's output it adds ``penalty(output)`` to whatever loss the
    output feeds (once per forward pass), without touching that loss's code: this is how the
    ``penalty`` variant reaches into brax's PPO and SAC actor losses.
    """

    @jax.custom_vjp
    def ident(y):
        return y

    def fwd(y):
        return y, y

    def bwd(y, g):
        return (g + jax.grad(penalty)(y),)

    ident.defvjp(fwd, bwd)
    return ident(x)


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
        if variant == "plain":
            params = freeze(params, head_mask(params))
        out = apply(processor_params, params, obs)
        if variant == "penalty":
            out = penalize(out, lambda y: coef * jnp.mean(deviation(y)))
        return out

    return wrapped
