"""SCORE runs end to end on the Spider (MJX): ASRL over 8 legs, training epochs, checkpoint,
restore."""

import jax
import numpy as np
import pytest

from score_jax.run.build import restore_run
from score_jax.run.driver import train
from tests.tiny import tiny_config

pytestmark = pytest.mark.slow  # scheduled first (conftest)


def test_score_trains_on_the_spider(tmp_path):
    cfg = tiny_config(
        tmp_path / "spider",
        env="spider",
        env_options=("episode_length=50",),
        total_steps=400,
        checkpoint_every=400,
    )
    run = train(cfg, log=lambda *a: None).for_seed(0)
    assert run.algo.off_policy.n_agents == 8 and run.algo.off_policy.width == 3
    assert int(run.state.updates) > 0
    assert all(
        np.all(np.isfinite(x)) for x in jax.tree.leaves(jax.device_get(run.state.agent.actor))
    )
    hvae_c = run.state.agent.consts.critic_inputs.c
    assert hvae_c.shape[0] == 8 and np.all(np.isfinite(np.asarray(hvae_c)))
    restored = restore_run(str(tmp_path / "spider"), log=lambda *a: None).for_seed(0)
    jax.tree.map(
        np.testing.assert_array_equal,
        jax.device_get(restored.state.agent.actor),
        jax.device_get(run.state.agent.actor),
    )
