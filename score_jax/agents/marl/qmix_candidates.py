"""How QMIX discretises a composite action space (§5.1): K candidate sub-actions per sub-space.

The paper divides "a reasonable range in each sub-action space" into a grid. Here, for a
sub-space with ``dim`` dims (normalised units) and a centre ``d`` (with the default prior, the
sub-space's default, what a failed controller falls back to; without it the mid-range point 0,
a discrete dim's grid value nearest 0), the candidates are, in order:

1. the centre ``d``;
2. a product grid: every dim takes L levels evenly spaced over
   ``[max(-1, d_j - radius), min(1, d_j + radius)]`` (a discrete dim takes L of its own grid
   values in that range, evenly picked, or all of them if there are at most L), with L the
   largest level count such that the grid has at most K - 1 points;
3. if even L = 2 is too many (2^dim > K - 1, e.g. the greenhouse's 24-hour schedules), K - 1
   shared offsets instead: ``d + t * 1`` for t evenly spaced in [-radius, radius] (clipped,
   discrete dims snapped to their grid), which moves the whole sub-action up or down together.

Duplicates are dropped (the default usually lies on the grid), and the table is padded to K
with invalid rows. Examples with K = 32, radius 1: a 1-dim continuous leg gets 31 levels, a
2-dim sub-space 5 x 5, a 3-dim one 3 x 3 x 3, a 1-dim discrete hour all 24 hours, two discrete
hours 5 x 5 of them; the probe's ``a``/``b``/``c`` get 25 / 27 / 5 candidates.
"""

from __future__ import annotations

import itertools

import numpy as np

from score_jax.core.spaces import CompositeSpace, SubSpace


def _discrete_grid(n_choices: int) -> np.ndarray:
    return -1.0 + 2.0 * np.arange(n_choices) / (n_choices - 1)


def _levels(sub: SubSpace, d: float, count: int, radius: float) -> np.ndarray:
    """At most ``count`` values of one dim in ``[d - radius, d + radius]`` (clipped to [-1, 1])."""
    lo, hi = max(-1.0, d - radius), min(1.0, d + radius)
    if sub.kind == "continuous":
        return np.linspace(lo, hi, count)
    grid = _discrete_grid(sub.n_choices)
    inside = grid[(grid >= lo - 1e-6) & (grid <= hi + 1e-6)]
    if len(inside) <= count:
        return inside
    return inside[np.round(np.linspace(0, len(inside) - 1, count)).astype(int)]


def subspace_candidates(
    sub: SubSpace, k: int, radius: float, at_default: bool = True
) -> np.ndarray:
    """``[m, dim]`` normalised candidates of one sub-space (m <= k), row 0 the centre: the
    default (``at_default``) or the mid-range point."""
    if at_default:
        centre = np.asarray(CompositeSpace((sub,)).default_action())[0, : sub.dim]
    elif sub.kind == "discrete":  # the grid value nearest 0
        steps = sub.n_choices - 1
        centre = np.full(sub.dim, np.round(0.5 * steps) / steps * 2.0 - 1.0)
    else:
        centre = np.zeros(sub.dim)
    centre = centre.astype(np.float64)
    grid = None
    for count in range(k - 1, 1, -1):
        levels = [_levels(sub, centre[j], count, radius) for j in range(sub.dim)]
        if np.prod([float(len(x)) for x in levels]) <= k - 1:
            grid = np.asarray(list(itertools.product(*levels)), np.float64).reshape(-1, sub.dim)
            break
    if grid is None:  # too many dims for a product grid: shared offsets of the whole sub-action
        grid = np.clip(centre[None, :] + np.linspace(-radius, radius, k - 1)[:, None], -1.0, 1.0)
        if sub.kind == "discrete":
            steps = sub.n_choices - 1
            grid = np.round((grid + 1.0) * 0.5 * steps) / steps * 2.0 - 1.0
    rows = np.concatenate([centre[None, :], grid]).astype(np.float32)
    _, first = np.unique(np.round(rows, 5), axis=0, return_index=True)
    return rows[np.sort(first)]


def candidate_table(
    space: CompositeSpace, agent_index, width: int, k: int, radius: float, prior=None
) -> tuple[np.ndarray, np.ndarray]:
    """Candidates of the agents' sub-spaces: ``(actions [n, k, width] float32, valid [n, k] bool)``.

    ``actions[i, c]`` is a normalised sub-action of sub-space ``agent_index[i]`` padded with
    zeros to ``width``; invalid rows (past the sub-space's m candidates) are zero. ``prior``
    (``[n]`` bool, None = all): the agents whose grid is centred on the default (else on the
    mid-range point).
    """
    idx = np.asarray(agent_index)
    prior = np.ones(len(idx), bool) if prior is None else np.asarray(prior, bool)
    actions = np.zeros((len(idx), k, width), np.float32)
    valid = np.zeros((len(idx), k), bool)
    for row, i in enumerate(idx):
        sub = space.subspaces[int(i)]
        c = subspace_candidates(sub, k, radius, bool(prior[row]))
        actions[row, : len(c), : sub.dim] = c
        valid[row, : len(c)] = True
    return actions, valid
