"""Split a CPU into one XLA host device per core for a run of several seeds.

XLA's CPU backend runs a compiled program on about one core, and SCORE's update is
compute-bound there, so batching seeds on one device adds little; the seed axis sharded over
one device per core runs whole seeds side by side (``SeedTrainer``). The split has to be set
before JAX initialises its CPU backend (``--xla_force_host_platform_device_count``), so the
commands call ``split_cpu_for_seeds`` first thing.
"""

from __future__ import annotations

import os

FLAG = "--xla_force_host_platform_device_count"


def devices_for(num_seeds: int, cores: int) -> int:
    """The most devices (at most ``cores``) over which ``num_seeds`` seeds divide evenly."""
    return max(d for d in range(1, max(cores, 1) + 1) if num_seeds % d == 0)


def split_cpu_for_seeds(num_seeds: int, requested: int | None = None) -> int:
    """Ask for one XLA host device per core (``requested`` devices if given) when the run has
    several seeds, the platform is the CPU and nobody chose a split already; returns the number
    of devices asked for (1 when nothing was changed). A no-op once JAX's backend is up."""
    from jax._src import xla_bridge  # deferred: only to see whether the backend is up

    if FLAG in os.environ.get("XLA_FLAGS", "") or xla_bridge._backends:
        return 1
    if os.environ.get("JAX_PLATFORMS", "cpu").split(",")[0] not in ("", "cpu"):
        return 1
    count = requested if requested is not None else devices_for(num_seeds, os.cpu_count() or 1)
    if count <= 1:
        return 1
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {FLAG}={count}".strip()
    return count
