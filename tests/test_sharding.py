"""With two forced host devices (in a subprocess): the data-parallel epoch equals the
single-device one, and so does the robustness sweep with its settings sharded (also for an
agent committed to one device); a one-seed view of seed-sharded leaves lives on one device."""

import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.slow  # scheduled first (conftest)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

SHARDED_SCRIPT = r"""
import dataclasses, jax, numpy as np
from score_jax.run.build import build
from score_jax.run.sharding import make_data_mesh
from score_jax.run.trainer import Trainer
from tests.tiny import tiny_config
assert jax.device_count() == 2, jax.devices()
cfg = tiny_config("/tmp/unused", total_steps=400)
run = build(cfg, jax.random.PRNGKey(0), "/tmp/unused", log=lambda *a: None)
single = Trainer(run.env, run.algo.off_policy, cfg.off_policy, run.agent_index)
sharded = Trainer(run.env, run.algo.off_policy, cfg.off_policy, run.agent_index, make_data_mesh())
a, b = single.init(jax.random.PRNGKey(1)), sharded.init(jax.random.PRNGKey(1))
assert len(b.env_state.obs.sharding.device_set) == 2
# one epoch: 25 vectorised steps of 8 envs (4 per device), the last one with a gradient update
a, _ = single.epoch(a, run.algo.off_policy.hyper)
b, _ = sharded.epoch(b, run.algo.off_policy.hyper)
assert int(a.updates) == 1
np.testing.assert_allclose(a.env_state.obs, b.env_state.obs, rtol=1e-5, atol=1e-5)
for x, y in zip(jax.tree.leaves(jax.device_get(a.agent)), jax.tree.leaves(jax.device_get(b.agent))):
    np.testing.assert_allclose(x, y, rtol=1e-4, atol=1e-5)
# the robustness sweep with its settings spread over both devices equals the one-device sweep
from score_jax.evaluation.robustness import make_sweep, settings_grid, shard_settings
settings = settings_grid(len(run.agent_index), 2)
sharded_settings = shard_settings(settings)
assert len(sharded_settings.n_failed.sharding.device_set) == 2
sweep = jax.jit(
    lambda agent, s, k: make_sweep(run.env, run.algo.policy(agent), run.agent_index)(s, k)
)
np.testing.assert_allclose(
    sweep(a.agent, settings, jax.random.PRNGKey(5)),
    sweep(a.agent, sharded_settings, jax.random.PRNGKey(5)),
    rtol=1e-5,
    atol=1e-5,
)
# an agent committed to one device (a restored checkpoint, brax's agents) is replicated over
# the settings' devices for the sweep, with the same returns
from score_jax.evaluation.robustness import on_devices_of
one_device = jax.device_put(a.agent, jax.devices()[0])
np.testing.assert_allclose(
    sweep(on_devices_of(sharded_settings, one_device), sharded_settings, jax.random.PRNGKey(5)),
    sweep(a.agent, settings, jax.random.PRNGKey(5)),
    rtol=1e-5,
    atol=1e-5,
)
# a one-seed view (Run.for_seed) of seed-sharded leaves lives on one device, uncommitted, so
# programs on it are not replicated over the mesh (and never wait in a cross-device rendezvous)
from jax.sharding import NamedSharding, PartitionSpec
from score_jax.run.build import _seed_of
stacked = np.arange(24.0).reshape(2, 3, 4)
for spec in (PartitionSpec("data"), PartitionSpec()):
    x = jax.device_put(stacked, NamedSharding(make_data_mesh(), spec))
    assert len(x.sharding.device_set) == 2
    for k in (0, 1):
        row = _seed_of(x, k)
        assert len(row.sharding.device_set) == 1 and not row.committed, row.sharding
        np.testing.assert_array_equal(row, stacked[k])
print("SHARDED_OK", int(a.updates))
"""


def test_sharded_epoch_equals_single_device():
    env = {
        **os.environ,
        "PYTHONPATH": ROOT,
        "XLA_FLAGS": (
            os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"
        ).strip(),
    }
    out = subprocess.run(
        [sys.executable, "-c", SHARDED_SCRIPT],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert "SHARDED_OK" in out.stdout, out.stderr[-3000:]
