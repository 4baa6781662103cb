"""Several processes (hosts) training one run: ``score-train --distributed``.

Every process runs the same Python program (SPMD, JAX's multi-controller model): the same
configuration, the same control flow and the same calls into compiled programs, whose inputs
are global arrays over all processes' devices. What differs is which process writes:

- ``initialize(cfg)``: joins the processes through ``jax.distributed.initialize`` before JAX
  starts its backend (CPU: with gloo collectives); idempotent;
- ``is_primary()``: process 0, the only one that writes files (metrics, ``config.json``,
  checkpoints, plots, evaluation and robustness JSON) and prints the run's log lines;
- ``to_host(tree)``: arrays as numpy on every process, gathering global arrays whose shards
  live on other processes (a collective: every process must call it at the same point);
- ``place(x, sharding)``: a value onto a (possibly global) sharding, from the host copy every
  process holds;
- ``barrier``, ``all_true``, ``broadcast``: small collectives for the points where the
  processes must agree (a directory created, a save done).

With one process every function is the plain single-process operation.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from jax.sharding import NamedSharding
from jax.sharding import PartitionSpec as P

# jax.distributed.initialize reads the coordinator address from here itself (and detects
# Slurm, Open MPI, Kubernetes and Cloud TPU jobs); the process count and id are read here.
ENV_COORDINATOR = "JAX_COORDINATOR_ADDRESS"
ENV_NUM_PROCESSES = "JAX_NUM_PROCESSES"
ENV_PROCESS_ID = "JAX_PROCESS_ID"
INIT_TIMEOUT_S = 300  # how long a process waits for the others to join


def _env_int(name: str) -> int | None:
    text = os.environ.get(name, "").strip()
    if not text:
        return None
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"${name}={text!r} is not an integer") from None


def launch_settings(cfg) -> tuple[str | None, int | None, int | None]:
    """``(coordinator address, process count, process id)`` of ``cfg`` (a ``TrainConfig``):
    each from its flag, else from ``$JAX_COORDINATOR_ADDRESS`` / ``$JAX_NUM_PROCESSES`` /
    ``$JAX_PROCESS_ID``, else None (``jax.distributed.initialize`` then detects a cluster
    scheduler's own variables)."""
    address = cfg.coordinator_address or os.environ.get(ENV_COORDINATOR) or None
    count = cfg.num_processes if cfg.num_processes is not None else _env_int(ENV_NUM_PROCESSES)
    pid = cfg.process_id if cfg.process_id is not None else _env_int(ENV_PROCESS_ID)
    if count is not None and count < 1:
        raise ValueError(f"--distributed: the process count must be >= 1, got {count}")
    if pid is not None and (pid < 0 or (count is not None and pid >= count)):
        within = f"0 .. {count - 1}" if count is not None else ">= 0"
        raise ValueError(f"--distributed: the process id must be {within}, got {pid}")
    return address, count, pid


def initialize(cfg) -> bool:
    """Join the run's processes when ``cfg.distributed`` (``cfg``: a ``TrainConfig``); returns
    whether this process is part of a distributed run. Call it before anything starts JAX's
    backend. Idempotent. ValueError (with the flags and variables to set) when the coordinator,
    the process count or the process id cannot be found."""
    if not cfg.distributed:
        return False
    if jax.distributed.is_initialized():
        return True
    address, count, pid = launch_settings(cfg)
    if jax.config.jax_cpu_collectives_implementation is None:
        # cross-process collectives of the CPU backend (the default in recent jax)
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
    try:
        jax.distributed.initialize(
            coordinator_address=address,
            num_processes=count,
            process_id=pid,
            initialization_timeout=INIT_TIMEOUT_S,
        )
    except ValueError as e:
        raise ValueError(
            f"--distributed: {e} Pass --coordinator-address HOST:PORT (process 0's), "
            "--num-processes N and --process-id I, or set $JAX_COORDINATOR_ADDRESS, "
            "$JAX_NUM_PROCESSES and $JAX_PROCESS_ID (under Slurm, Open MPI, Kubernetes or on "
            "Cloud TPU jax finds them itself)"
        ) from None
    return True


def multiprocess() -> bool:
    """Whether this run spans several processes."""
    return jax.process_count() > 1


def is_primary() -> bool:
    """Whether this is process 0, the one that writes files and prints the log."""
    return jax.process_index() == 0


def _silent(*args, **kwargs) -> None:
    return None


def primary_only(log: Callable) -> Callable:
    """``log`` on process 0, a no-op on the others."""
    return log if is_primary() else _silent


def _identity(tree):
    return tree


def _global(x) -> bool:
    return isinstance(x, jax.Array) and not x.is_fully_addressable


def to_host(tree: Any) -> Any:
    """``tree`` with every array as numpy, on every process. Arrays with shards on other
    processes are gathered (all of them in one compiled all-gather), so in a distributed run
    every process must call this at the same point."""
    leaves, treedef = jax.tree.flatten(tree)
    spread = [i for i, x in enumerate(leaves) if _global(x)]
    if spread:
        parts = [leaves[i] for i in spread]
        if all(isinstance(x.sharding, NamedSharding) for x in parts):
            replicated = [NamedSharding(x.sharding.mesh, P()) for x in parts]
            gathered = jax.jit(_identity, out_shardings=replicated)(parts)
            gathered = [g.addressable_data(0) for g in gathered]
        else:
            from jax.experimental import multihost_utils

            gathered = [multihost_utils.process_allgather(x, tiled=True) for x in parts]
        for i, g in zip(spread, gathered, strict=True):
            leaves[i] = g
    return treedef.unflatten([np.asarray(x) for x in leaves])


def place(x: Any, sharding) -> jax.Array:
    """``x`` on ``sharding``. In a distributed run a value every process holds in full (numpy,
    or an array computed on this process's own devices) becomes a global array from the
    process's shards of it; a global array is resharded."""
    if _global(x) or not multiprocess():
        return jax.device_put(x, sharding)
    host = np.asarray(x)
    return jax.make_array_from_callback(host.shape, sharding, lambda index: host[index])


def place_tree(tree: Any, sharding) -> Any:
    """Every leaf of ``tree`` on ``sharding`` (``place``); with one process in one
    ``jax.device_put`` of the whole tree (leaf by leaf, a greenhouse SCORE state's hundreds of
    leaves took seconds to place)."""
    if not multiprocess():
        return jax.device_put(tree, sharding)
    return jax.tree.map(lambda x: place(x, sharding), tree)


def barrier(name: str) -> None:
    """Wait until every process got here (a no-op with one process); ``name`` must be the
    same on every process."""
    if multiprocess():
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices(f"score-jax: {name}")


def all_true(flag: bool) -> bool:
    """Whether ``flag`` holds on every process."""
    if not multiprocess():
        return bool(flag)
    from jax.experimental import multihost_utils

    return bool(np.all(multihost_utils.process_allgather(np.asarray(bool(flag)))))


def broadcast(value: int) -> int:
    """Process 0's ``value`` (an integer) on every process."""
    if not multiprocess():
        return int(value)
    from jax.experimental import multihost_utils

    return int(multihost_utils.broadcast_one_to_all(np.asarray(value, np.int32)))
