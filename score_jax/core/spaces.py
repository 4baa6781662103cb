"""Composite action spaces: the one place where padding, masks and units live.

A composite action is a tuple of heterogeneous sub-actions (paper §1, Fig. 1). Inside the
learner it is always ONE float32 array ``[n, max_dim]``: sub-space ``i`` uses its first
``dims[i]`` columns, normalised to [-1, 1]; padded columns are zero and never reach the
environment. A discrete dimension with ``n_choices`` values is carried as its normalised grid
value ``-1 + 2 k / (n_choices - 1)`` (the actor samples it with straight-through
Gumbel-softmax, paper footnote 3).

``CompositeSpace`` is a frozen, hashable dataclass: it is safe as a static argument of
``jax.jit`` and as a field of a Flax module. Everything that changes per step (which
sub-spaces work, which fail) is an array mask, never a new space.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np

Kind = Literal["continuous", "discrete"]


@dataclasses.dataclass(frozen=True)
class SubSpace:
    """One sub-action space (one agent of the SCORE graph).

    Attributes:
      name: unique name inside a composite space (e.g. ``"temperature"``).
      kind: ``"continuous"`` or ``"discrete"``.
      dim: number of dimensions.
      low, high: per-dimension physical bounds (tuples of length ``dim``).
      default: per-dimension physical value a failed controller falls back to (§5.2.3).
      n_choices: for discrete sub-spaces, the number of evenly spaced values between ``low``
        and ``high`` inclusive (e.g. 24 for the hours 0..23); ``0`` for continuous ones.
      units: the physical unit of the values (``"°C"``, ``"ppm"``, ``"h"``), for display only:
        it takes no part in equality or hashing, so a checkpoint written before units existed
        matches its environment.
    """

    name: str
    kind: Kind
    dim: int
    low: tuple[float, ...]
    high: tuple[float, ...]
    default: tuple[float, ...]
    n_choices: int = 0
    units: str = dataclasses.field(default="", compare=False)

    def __post_init__(self):
        if self.kind not in ("continuous", "discrete"):
            raise ValueError(
                f"SubSpace {self.name!r}: kind must be 'continuous' or 'discrete', "
                f"got {self.kind!r}"
            )
        if self.dim < 1:
            raise ValueError(f"SubSpace {self.name!r}: dim must be >= 1, got {self.dim}")
        for field in ("low", "high", "default"):
            if len(getattr(self, field)) != self.dim:
                raise ValueError(
                    f"SubSpace {self.name!r}: {field} has {len(getattr(self, field))} values, "
                    f"expected dim={self.dim}"
                )
        if any(hi <= lo for lo, hi in zip(self.low, self.high, strict=True)):
            raise ValueError(
                f"SubSpace {self.name!r}: every high must exceed its low, "
                f"got low={self.low} high={self.high}"
            )
        if any(
            not lo <= d <= hi for lo, d, hi in zip(self.low, self.default, self.high, strict=True)
        ):
            raise ValueError(
                f"SubSpace {self.name!r}: default {self.default} lies outside "
                f"[{self.low}, {self.high}]"
            )
        if self.kind == "discrete" and self.n_choices < 2:
            raise ValueError(
                f"SubSpace {self.name!r}: a discrete sub-space needs n_choices >= 2, "
                f"got {self.n_choices}"
            )
        if self.kind == "continuous" and self.n_choices != 0:
            raise ValueError(
                f"SubSpace {self.name!r}: a continuous sub-space must have n_choices=0"
            )

    @classmethod
    def continuous(
        cls, name: str, dim: int, low: float, high: float, default: float, units: str = ""
    ) -> SubSpace:
        """A continuous sub-space with the same bounds and default on every dimension."""
        return cls(
            name,
            "continuous",
            dim,
            (float(low),) * dim,
            (float(high),) * dim,
            (float(default),) * dim,
            units=units,
        )

    @classmethod
    def discrete(
        cls,
        name: str,
        dim: int,
        low: float,
        high: float,
        default: float,
        n_choices: int,
        units: str = "",
    ) -> SubSpace:
        """A discrete sub-space: ``n_choices`` evenly spaced values in [low, high] per dim."""
        return cls(
            name,
            "discrete",
            dim,
            (float(low),) * dim,
            (float(high),) * dim,
            (float(default),) * dim,
            int(n_choices),
            units=units,
        )


@dataclasses.dataclass(frozen=True)
class CompositeSpace:
    """An ordered tuple of sub-spaces, padded to ``[n, max_dim]``.

    Shapes: ``n`` sub-spaces, ``max_dim = max(dims)``; all per-dimension arrays are
    ``[n, max_dim]`` with padded entries set to neutral values (bounds -1/1, default 0).
    """

    subspaces: tuple[SubSpace, ...]

    def __post_init__(self):
        if not self.subspaces:
            raise ValueError("CompositeSpace needs at least one SubSpace")
        names = [s.name for s in self.subspaces]
        duplicates = sorted({x for x in names if names.count(x) > 1})
        if duplicates:
            raise ValueError(f"CompositeSpace: duplicate sub-space names {duplicates}")

    # --- static structure (numpy, usable at trace time) -------------------------------
    @property
    def n(self) -> int:
        return len(self.subspaces)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.subspaces)

    @property
    def dims(self) -> tuple[int, ...]:
        return tuple(s.dim for s in self.subspaces)

    @property
    def max_dim(self) -> int:
        return max(self.dims)

    @property
    def total_dim(self) -> int:
        return sum(self.dims)

    @property
    def discrete_width(self) -> int:
        """Most dims of any discrete sub-space (1 if there are none): the columns that can be
        discrete, since a discrete sub-space's dims are its first columns."""
        return max([s.dim for s in self.subspaces if s.kind == "discrete"] + [1])

    @property
    def max_choices(self) -> int:
        """Largest ``n_choices`` of any discrete sub-space (1 if there are none)."""
        return max([s.n_choices for s in self.subspaces] + [1])

    def _padded(self, attr: str, pad: float) -> np.ndarray:
        out = np.full((self.n, self.max_dim), pad, np.float32)
        for i, s in enumerate(self.subspaces):
            out[i, : s.dim] = getattr(s, attr)
        return out

    @functools.cached_property
    def dim_mask(self) -> np.ndarray:
        """``[n, max_dim]`` bool: True where a column is a real dimension."""
        return np.arange(self.max_dim)[None, :] < np.asarray(self.dims)[:, None]

    @functools.cached_property
    def low(self) -> np.ndarray:
        """``[n, max_dim]`` physical lower bounds (padded: -1)."""
        return self._padded("low", -1.0)

    @functools.cached_property
    def high(self) -> np.ndarray:
        """``[n, max_dim]`` physical upper bounds (padded: 1)."""
        return self._padded("high", 1.0)

    @functools.cached_property
    def n_choices(self) -> np.ndarray:
        """``[n, max_dim]`` int32: number of grid values of a discrete dim, 0 otherwise."""
        out = np.zeros((self.n, self.max_dim), np.int32)
        for i, s in enumerate(self.subspaces):
            out[i, : s.dim] = s.n_choices
        return out

    @functools.cached_property
    def discrete_mask(self) -> np.ndarray:
        """``[n, max_dim]`` bool: True on real dimensions of discrete sub-spaces."""
        return self.n_choices > 0

    @functools.cached_property
    def flat_index(self) -> np.ndarray:
        """``[total_dim]`` int: position in the flattened ``[n * max_dim]`` array of each real
        dim."""
        return np.flatnonzero(self.dim_mask.reshape(-1))

    def __hash__(self):  # cached_property fills __dict__; hash on the defining field only
        return hash(self.subspaces)

    def __eq__(self, other):
        return isinstance(other, CompositeSpace) and self.subspaces == other.subspaces

    def index(self, name: str) -> int:
        """Position of the sub-space called ``name``."""
        if name not in self.names:
            raise KeyError(f"unknown sub-space {name!r}; this space has {list(self.names)}")
        return self.names.index(name)

    # --- conversions (jax, jit/vmap friendly; leading batch axes allowed) -------------
    def to_physical(self, action: jax.Array) -> jax.Array:
        """Normalised ``[..., n, max_dim]`` -> physical ``[..., n, max_dim]``.

        Out-of-range inputs are clipped to [-1, 1] and NaN becomes the default, so the result
        is always inside the bounds; discrete dims snap to the nearest grid value; padded
        columns are zero.
        """
        a = jnp.asarray(action, jnp.float32)
        a = jnp.where(jnp.isnan(a), self.from_physical(self._padded("default", 0.0)), a)
        a = jnp.clip(a, -1.0, 1.0)
        a = self._snap(a)
        x = self.low + (a + 1.0) * 0.5 * (self.high - self.low)
        return jnp.where(self.dim_mask, x, 0.0)

    def from_physical(self, x: jax.Array) -> jax.Array:
        """Physical ``[..., n, max_dim]`` -> normalised ``[..., n, max_dim]`` in [-1, 1].

        Values outside the bounds are clipped; discrete dims snap to the grid; padded columns
        are zero.
        """
        x = jnp.asarray(x, jnp.float32)
        a = 2.0 * (x - self.low) / (self.high - self.low) - 1.0
        a = self._snap(jnp.clip(a, -1.0, 1.0))
        return jnp.where(self.dim_mask, a, 0.0)

    def _snap(self, a: jax.Array) -> jax.Array:
        steps = jnp.maximum(self.n_choices - 1, 1).astype(jnp.float32)
        snapped = jnp.round((a + 1.0) * 0.5 * steps) / steps * 2.0 - 1.0
        return jnp.where(self.discrete_mask, snapped, a)

    def choice_index(self, action: jax.Array) -> jax.Array:
        """Normalised ``[..., n, max_dim]`` -> int32 grid index (0 on continuous/padded dims)."""
        steps = jnp.maximum(self.n_choices - 1, 1).astype(jnp.float32)
        k = jnp.round((jnp.clip(action, -1.0, 1.0) + 1.0) * 0.5 * steps).astype(jnp.int32)
        return jnp.where(self.discrete_mask, k, 0)

    def choice_value(self, index: jax.Array) -> jax.Array:
        """int grid index ``[..., n, max_dim]`` -> normalised value (0 on continuous/padded
        dims)."""
        steps = jnp.maximum(self.n_choices - 1, 1).astype(jnp.float32)
        return jnp.where(self.discrete_mask, index.astype(jnp.float32) / steps * 2.0 - 1.0, 0.0)

    def default_action(self) -> jax.Array:
        """Normalised ``[n, max_dim]`` action of every sub-space at its physical default."""
        return self.from_physical(self._padded("default", 0.0))

    def sample(self, key: jax.Array, shape: Sequence[int] = ()) -> jax.Array:
        """Uniform random normalised actions ``[*shape, n, max_dim]`` (grid-uniform on discrete
        dims)."""
        a = jax.random.uniform(key, (*shape, self.n, self.max_dim), minval=-1.0, maxval=1.0)
        # Widen by half a grid step so the two end values are as likely as inner ones.
        steps = jnp.maximum(self.n_choices - 1, 1).astype(jnp.float32)
        a = jnp.where(self.discrete_mask, jnp.clip(a * (1.0 + 1.0 / steps), -1.0, 1.0), a)
        a = self._snap(a)
        return jnp.where(self.dim_mask, a, 0.0)

    def flatten(self, x: jax.Array) -> jax.Array:
        """``[..., n, max_dim]`` -> ``[..., total_dim]``: drop padded columns."""
        return x.reshape(*x.shape[:-2], self.n * self.max_dim)[..., self.flat_index]

    def unflatten(self, flat: jax.Array) -> jax.Array:
        """``[..., total_dim]`` -> ``[..., n, max_dim]`` with zero padding."""
        out = jnp.zeros((*flat.shape[:-1], self.n * self.max_dim), flat.dtype)
        out = out.at[..., self.flat_index].set(flat)
        return out.reshape(*flat.shape[:-1], self.n, self.max_dim)

    # --- transfer (§4.3) ----------------------------------------------------------------
    def subset(self, names: Sequence[str]) -> CompositeSpace:
        """The sub-spaces called ``names``, in this space's order."""
        unknown = [x for x in names if x not in self.names]
        if unknown:
            raise KeyError(f"unknown sub-spaces {unknown}; this space has {list(self.names)}")
        return CompositeSpace(tuple(s for s in self.subspaces if s.name in set(names)))

    def union(self, other: CompositeSpace) -> CompositeSpace:
        """This space followed by the sub-spaces of ``other`` it lacks (same name => must match)."""
        extra = []
        for s in other.subspaces:
            if s.name in self.names:
                if self.subspaces[self.index(s.name)] != s:
                    raise ValueError(f"sub-space {s.name!r} differs between the two spaces")
            else:
                extra.append(s)
        return CompositeSpace(self.subspaces + tuple(extra))

    def positions_in(self, other: CompositeSpace) -> np.ndarray:
        """``[n]`` int: index in ``other`` of each of this space's sub-spaces."""
        return np.asarray([other.index(x) for x in self.names], np.int32)

    # --- serialisation (stored with checkpoints) ----------------------------------------
    def to_dict(self) -> dict:
        return {"subspaces": [dataclasses.asdict(s) for s in self.subspaces]}

    @classmethod
    def from_dict(cls, d: dict) -> CompositeSpace:
        subs = []
        for s in d["subspaces"]:
            s = dict(s)
            for f in ("low", "high", "default"):
                s[f] = tuple(float(v) for v in s[f])
            subs.append(SubSpace(**s))
        return cls(tuple(subs))

    def describe(self) -> str:
        """A table, one row per sub-space: name, kind, dims, range, default and units (a
        per-dimension range or default is shown in full when its values differ)."""
        rows = [("name", "kind", "dims", "range", "default", "units")]
        for s in self.subspaces:
            kind = s.kind if s.kind == "continuous" else f"discrete({s.n_choices})"
            rows.append(
                (
                    s.name,
                    kind,
                    str(s.dim),
                    _describe_range(s.low, s.high),
                    _describe_values(s.default),
                    s.units or "-",
                )
            )
        widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
        return "\n".join(
            "  ".join(v.ljust(w) for v, w in zip(r, widths, strict=True)).rstrip() for r in rows
        )


def _describe_values(values: tuple[float, ...]) -> str:
    """``19`` when every dimension has the same value, else ``6, 18``."""
    if len(set(values)) == 1:
        return f"{values[0]:g}"
    return ", ".join(f"{v:g}" for v in values)


def _describe_range(low: tuple[float, ...], high: tuple[float, ...]) -> str:
    if len(set(low)) == 1 and len(set(high)) == 1:
        return f"[{low[0]:g}, {high[0]:g}]"
    return " ".join(f"[{lo:g}, {hi:g}]" for lo, hi in zip(low, high, strict=True))


def agents_to_env_action(space: CompositeSpace, agent_action: jax.Array, agent_index) -> jax.Array:
    """Learner action ``[..., n_agents, width]`` -> environment action
    ``[..., space.n, space.max_dim]``.

    Agent ``k`` controls sub-space ``agent_index[k]`` of ``space``; sub-spaces that no agent
    controls (training on a subset, §5.2.4 / §5.3.4) stay at their physical defaults.
    Columns beyond ``space.max_dim`` are padding and are dropped.
    """
    agent_index = np.asarray(agent_index)
    lead = agent_action.shape[:-2]
    base = jnp.broadcast_to(space.default_action(), (*lead, space.n, space.max_dim))
    return base.at[..., agent_index, :].set(agent_action[..., : space.max_dim])


def pad_width(x: jax.Array, width: int, value=0) -> jax.Array:
    """Pad the last axis of ``x`` to ``width`` with ``value``."""
    extra = width - x.shape[-1]
    if extra < 0:
        raise ValueError(f"cannot pad width {x.shape[-1]} down to {width}")
    return jnp.pad(x, [(0, 0)] * (x.ndim - 1) + [(0, extra)], constant_values=value)


def sample_agent_actions(
    space: CompositeSpace, agent_index, key: jax.Array, shape: Sequence[int], width: int
) -> jax.Array:
    """Uniform random learner actions ``[*shape, n_agents, width]`` for the agents controlling
    sub-spaces ``agent_index`` of ``space`` (the exploration and 'random' reference policy)."""
    agent_index = np.asarray(agent_index)
    sub = space.subset([space.names[i] for i in agent_index])  # keeps the space's order
    order = np.argsort(np.argsort(agent_index))  # back to the agents' order
    return pad_width(sub.sample(key, shape)[..., order, :], width)
