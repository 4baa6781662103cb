"""Import before jax: split a CPU into one XLA host device per core.

XLA's CPU backend runs one fused program on one core; a batch of independent envs or sweep
settings sharded over one device per core uses them all. Does nothing when the flag is set
already or another platform is requested.
"""

import os

if (
    "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", "")
    and os.environ.get("JAX_PLATFORMS", "cpu") == "cpu"
):
    os.environ["XLA_FLAGS"] = (
        f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={os.cpu_count()}"
    ).strip()
