"""The data-parallel mesh: one ``data`` axis over all devices (on a CPU split into one XLA host
device per core with ``--xla_force_host_platform_device_count``, every core)."""

from __future__ import annotations

import jax
import numpy as np
from jax.sharding import Mesh


def make_data_mesh(devices=None) -> Mesh:
    """A 1-D ``data`` mesh over ``devices`` (default: all devices JAX sees)."""
    devices = jax.devices() if devices is None else devices
    return Mesh(np.asarray(devices), ("data",))
