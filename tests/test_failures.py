"""Failure modes and masks (§5.2.3): each mode does exactly what it says, without retracing."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from score_jax.core.failures import (
    FailureMode,
    apply_failures,
    check_active,
    dropnode_mask,
    failure_mask,
)
from tests.test_spaces import SPACE

ACTION = jnp.array([[0.1, 0.2, 0.3], [0.5, -0.5, 0.0], [0.9, 0.0, 0.0]])
LAST = jnp.array([[-0.3, -0.2, -0.1], [1.0, -1.0, 0.0], [-0.9, 0.0, 0.0]])
ACTIVE = jnp.array([True, False, False])


def test_default_mode():
    out = apply_failures(SPACE, ACTION, ACTIVE, FailureMode.DEFAULT, jax.random.PRNGKey(0), LAST)
    np.testing.assert_allclose(out[0], ACTION[0])
    np.testing.assert_allclose(out[1:], SPACE.default_action()[1:])


def test_last_mode():
    out = apply_failures(SPACE, ACTION, ACTIVE, FailureMode.LAST, jax.random.PRNGKey(0), LAST)
    np.testing.assert_allclose(out, jnp.where(ACTIVE[:, None], ACTION, LAST))


def test_random_mode_is_uniform_in_range_and_only_touches_failed():
    keys = jax.random.split(jax.random.PRNGKey(0), 2000)
    out = jax.vmap(lambda k: apply_failures(SPACE, ACTION, ACTIVE, FailureMode.RANDOM, k, LAST))(
        keys
    )
    np.testing.assert_allclose(out[:, 0], jnp.broadcast_to(ACTION[0], (2000, 3)))
    failed = out[:, 2, 0]
    assert (
        float(failed.min()) < -0.9 and float(failed.max()) > 0.9 and abs(float(failed.mean())) < 0.1
    )
    hours = SPACE.to_physical(out)[:, 1, :2]
    np.testing.assert_allclose(hours, jnp.round(hours), atol=1e-4)  # discrete stays on the grid
    assert bool(jnp.all(out[:, 1:, 2] == 0)) and bool(
        jnp.all(out[:, 2, 1:] == 0)
    )  # padding stays zero


def test_all_active_is_identity_for_every_mode():
    for mode in FailureMode:
        out = apply_failures(SPACE, ACTION, jnp.ones(3, bool), mode, jax.random.PRNGKey(0), LAST)
        np.testing.assert_allclose(out, ACTION)


def test_mask_and_mode_changes_do_not_retrace():
    traces = []

    @jax.jit
    def f(active, mode, key):
        traces.append(1)
        return apply_failures(SPACE, ACTION, active, mode, key, LAST)

    for mode in FailureMode:
        for active in ([True, False, True], [False, True, True], [True, True, True]):
            f(jnp.array(active), jnp.int32(mode), jax.random.PRNGKey(mode))
    assert len(traces) == 1


def test_failure_mask_counts():
    keys = jax.random.split(jax.random.PRNGKey(3), 500)
    for n_failed in range(4):
        masks = jax.vmap(lambda k, n_failed=n_failed: failure_mask(k, 3, n_failed))(keys)
        expected = min(n_failed, 2)  # at least one sub-space always stays active
        np.testing.assert_array_equal(jnp.sum(~masks, axis=1), expected)
    # failures are spread over all sub-spaces
    masks = jax.vmap(lambda k: failure_mask(k, 3, 1))(keys)
    assert float(jnp.min(jnp.mean(~masks, axis=0))) > 0.25
    # invalid (absent) agents are never active and never counted
    valid = jnp.array([True, True, False])
    masks = jax.vmap(lambda k: failure_mask(k, 3, 1, valid))(keys)
    assert not bool(jnp.any(masks[:, 2])) and bool(jnp.all(jnp.sum(masks, axis=1) == 1))


def test_dropnode_keeps_one_valid_agent():
    valid = jnp.array([True, True, True, False])
    keys = jax.random.split(jax.random.PRNGKey(4), 1000)
    masks = jax.vmap(lambda k: dropnode_mask(k, valid, 0.9))(keys)
    assert bool(jnp.all(jnp.sum(masks, axis=1) >= 1)) and not bool(jnp.any(masks[:, 3]))
    rate = float(jnp.mean(jax.vmap(lambda k: dropnode_mask(k, valid, 0.25))(keys)[:, :3]))
    assert rate == pytest.approx(0.75, abs=0.05)


def test_check_active_errors():
    with pytest.raises(ValueError, match="every sub-space failed"):
        check_active([False, False, False], 3)
    with pytest.raises(ValueError, match="shape"):
        check_active([True], 3)
    check_active([True, False, False], 3)


def test_parse_mode():
    assert FailureMode.parse("last") is FailureMode.LAST
    with pytest.raises(ValueError, match="choose one of"):
        FailureMode.parse("zeros")
