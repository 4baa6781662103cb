"""SCORE solves the probe env (its own file so the test runner can balance it against the rest)."""

import dataclasses

import jax.numpy as jnp
import pytest

from score_jax.run.driver import train
from tests.tiny import TINY_OFF_POLICY, tiny_config

pytestmark = pytest.mark.slow  # scheduled first (conftest)


def test_score_solves_the_probe(tmp_path):
    """The probe's optimum is 10 per episode; the default action gets ~8.1 and random ~4.2."""
    cfg = tiny_config(
        tmp_path / "solve",
        total_steps=4000,
        checkpoint_every=4000,
        off_policy=dataclasses.replace(TINY_OFF_POLICY, updates_per_step=4),
    )
    run = train(cfg, log=lambda *a: None)
    returns = run.evaluate(run.state.agent, n_episodes=16).returns
    assert float(jnp.mean(returns)) > 9.0, float(jnp.mean(returns))
