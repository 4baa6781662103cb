"""Composite action spaces: padding, units, discrete grids, subset/union."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from score_jax.core.spaces import CompositeSpace, SubSpace

SPACE = CompositeSpace(
    (
        SubSpace.continuous("temp", 3, 13.0, 25.0, 19.0),
        SubSpace.discrete("hours", 2, 0.0, 23.0, 6.0, n_choices=24),
        SubSpace.continuous("leg", 1, -1.0, 1.0, 0.0),
    )
)


def test_structure():
    assert SPACE.n == 3 and SPACE.max_dim == 3 and SPACE.dims == (3, 2, 1) and SPACE.total_dim == 6
    np.testing.assert_array_equal(SPACE.dim_mask, [[1, 1, 1], [1, 1, 0], [1, 0, 0]])
    assert SPACE.max_choices == 24
    assert SPACE.names == ("temp", "hours", "leg")
    assert hash(SPACE) == hash(CompositeSpace(SPACE.subspaces)) and SPACE == CompositeSpace(
        SPACE.subspaces
    )


def test_round_trip_continuous_and_discrete():
    x = jax.random.uniform(jax.random.PRNGKey(0), (100, 3, 3))
    phys = SPACE.to_physical(SPACE.from_physical(SPACE.to_physical(x * 2 - 1)))
    np.testing.assert_allclose(SPACE.to_physical(SPACE.from_physical(phys)), phys, atol=1e-4)
    # every discrete physical value is an integer hour in 0..23
    hours = np.asarray(phys[:, 1, :2])
    np.testing.assert_allclose(hours, np.round(hours), atol=1e-4)
    assert hours.min() >= 0 and hours.max() <= 23


def test_discrete_grid_maps_both_ways():
    idx = jnp.arange(24)
    a = jnp.zeros((24, 3, 3)).at[:, 1, 0].set(-1 + 2 * idx / 23)
    phys = SPACE.to_physical(a)
    np.testing.assert_allclose(phys[:, 1, 0], idx, atol=1e-4)
    np.testing.assert_array_equal(SPACE.choice_index(a)[:, 1, 0], idx)
    np.testing.assert_allclose(
        SPACE.choice_value(SPACE.choice_index(a))[:, 1, 0], a[:, 1, 0], atol=1e-6
    )
    # a value between two grid points snaps to the nearest hour
    mid = jnp.zeros((3, 3)).at[1, 0].set(-1 + 2 * 4.4 / 23)
    assert float(SPACE.to_physical(mid)[1, 0]) == pytest.approx(4.0, abs=1e-4)


def test_padded_dims_never_reach_physical_action():
    a = jnp.full((3, 3), 0.7)  # garbage in padded columns
    phys = SPACE.to_physical(a)
    assert float(phys[1, 2]) == 0.0 and float(phys[2, 1]) == 0.0 and float(phys[2, 2]) == 0.0
    flat = SPACE.flatten(phys)
    assert flat.shape == (6,)
    np.testing.assert_allclose(SPACE.unflatten(flat), phys)


def test_out_of_range_and_nan_are_clipped():
    a = jnp.array([[5.0, -7.0, jnp.nan], [3.0, jnp.nan, 0.0], [-9.0, 0.0, 0.0]])
    phys = SPACE.to_physical(a)
    assert bool(jnp.all(jnp.isfinite(phys)))
    np.testing.assert_allclose(phys[0], [25.0, 13.0, 19.0], atol=1e-4)  # NaN -> default
    np.testing.assert_allclose(phys[1, :2], [23.0, 6.0], atol=1e-4)
    assert float(phys[2, 0]) == -1.0


def test_default_action_is_physical_default():
    phys = SPACE.to_physical(SPACE.default_action())
    np.testing.assert_allclose(phys, [[19, 19, 19], [6, 6, 0], [0, 0, 0]], atol=1e-4)


def test_sample_in_range_and_covers_grid_ends():
    a = SPACE.sample(jax.random.PRNGKey(1), (4000,))
    assert a.shape == (4000, 3, 3)
    assert float(jnp.abs(a).max()) <= 1.0
    assert bool(jnp.all(jnp.where(SPACE.dim_mask, True, a == 0)))
    counts = np.bincount(np.asarray(SPACE.choice_index(a)[:, 1, 0]), minlength=24)
    assert counts.min() > 4000 / 24 * 0.6  # the end hours are not under-sampled


def test_subset_union_and_serialisation():
    sub = SPACE.subset(["leg", "temp"])
    assert sub.names == ("temp", "leg")  # keeps the original order
    assert sub.union(SPACE).names == ("temp", "leg", "hours")
    np.testing.assert_array_equal(sub.positions_in(SPACE), [0, 2])
    assert CompositeSpace.from_dict(SPACE.to_dict()) == SPACE
    with pytest.raises(KeyError, match="unknown sub-spaces"):
        SPACE.subset(["nope"])
    other = CompositeSpace((SubSpace.continuous("leg", 2, -1, 1, 0),))
    with pytest.raises(ValueError, match="differs"):
        SPACE.union(other)


def test_invalid_subspaces_are_rejected():
    with pytest.raises(ValueError, match="default"):
        SubSpace.continuous("x", 2, 0.0, 1.0, 3.0)
    with pytest.raises(ValueError, match="n_choices"):
        SubSpace.discrete("x", 1, 0.0, 1.0, 0.0, n_choices=1)
    with pytest.raises(ValueError, match="duplicate"):
        CompositeSpace((SubSpace.continuous("x", 1, 0, 1, 0), SubSpace.continuous("x", 1, 0, 1, 0)))
