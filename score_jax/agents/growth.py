"""Growing the agent axis for transfer to unseen sub-action spaces (§4.3), for every algorithm
that can grow (SCORE, ISAC, MAAC, QMIX).

A ``TransferPlan`` says which agents of the grown run were seen before and where they come
from; ``grow_stacked`` builds a grown parameter tree from a trained one and a fresh template
(per-agent leaves are rows of a leading agent axis under an ``agents`` key); and
``freeze_agent_rows`` zeroes the updates of the agents that stay frozen, so their parameters
stay bitwise unchanged.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax


def freeze_agent_rows(trainable) -> optax.GradientTransformation:
    """Zero the updates of the agents (leading axis of stacked params) where ``trainable`` is
    False."""
    trainable = np.asarray(trainable, bool)

    def init(params):
        return optax.EmptyState()

    def update(updates, state, params=None):
        scale = lambda u: u * jnp.asarray(trainable, u.dtype).reshape((-1,) + (1,) * (u.ndim - 1))
        return jax.tree.map(scale, updates), state

    return optax.GradientTransformation(init, update)


@dataclasses.dataclass(frozen=True)
class TransferPlan:
    """Which agents of the grown run were seen before, and where they come from."""

    agent_index: np.ndarray  # [n_new_total] sub-spaces of the env, in the space's order
    is_new: np.ndarray  # [n_new_total] bool
    source_row: np.ndarray  # [n_new_total] row in the source run's agents (-1 for new ones)

    @property
    def new_positions(self) -> np.ndarray:
        return np.flatnonzero(self.is_new)


def plan(source_agent_index, target_agent_index) -> TransferPlan:
    source = [int(i) for i in source_agent_index]
    target = sorted(int(i) for i in target_agent_index)
    missing = [i for i in source if i not in target]
    if missing:
        raise ValueError(
            f"the target sub-spaces must include every trained one; missing indices {missing}"
        )
    if len(target) == len(source):
        raise ValueError("the target has no new sub-space: nothing to transfer")
    row = np.asarray([source.index(i) if i in source else -1 for i in target])
    return TransferPlan(np.asarray(target), row < 0, row)


def agent_rows(p: TransferPlan, n_src: int) -> np.ndarray:
    """``[n_grown]`` row of every grown agent in ``[source agents; template agents]``: the source
    row of an old sub-space, the fresh template row of a new one."""
    return np.where(p.is_new, n_src + np.arange(len(p.agent_index)), p.source_row)


def is_per_agent(path) -> bool:
    """Whether a leaf at ``path`` (``jax.tree_util`` key path) is per-agent: it sits under an
    ``agents`` key (``networks.stacked``) and has a leading agent axis."""
    return any(getattr(k, "key", None) == "agents" for k in path)


def identity_plan(n: int) -> TransferPlan:
    """The plan that keeps all ``n`` agents where they are (a network already built for every
    sub-space: the transfer variants, ``agents.variants``)."""
    return TransferPlan(np.arange(n), np.zeros(n, bool), np.arange(n))


def grow_stacked(source, template, p: TransferPlan):
    """Grow a parameter tree whose per-agent leaves sit under an ``agents`` key (stacked on a
    leading agent axis, ``nn.vmap``): those rows come from ``source`` (old sub-spaces) or
    ``template`` (new ones, fresh); every other leaf (shared across agents) from ``source``."""
    n_src = {
        x.shape[0] for path, x in jax.tree_util.tree_leaves_with_path(source) if is_per_agent(path)
    }
    if len(n_src) != 1:
        raise ValueError(
            "grow_stacked: expected one agent count in the source's 'agents' leaves, "
            f"found {sorted(n_src)}"
        )
    rows = agent_rows(p, n_src.pop())
    grow = lambda path, s, t: jnp.concatenate([s, t], 0)[rows] if is_per_agent(path) else s
    return jax.tree_util.tree_map_with_path(grow, source, template)
