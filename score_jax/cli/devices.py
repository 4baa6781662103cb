"""The CPU split of the commands: one XLA host device per core, decided before JAX starts.

``score-train`` splits the CPU for a run of several seeds (``run.cpu_split``). A command that
reads a saved run (``score-transfer``, ``score-eval``, ``score-robustness``) splits it the way
that run's training had it, read from its ``config.json`` (the device count of its
provenance): a different device count compiles a different program (the seeds sharded, or
batched on one device), which rounds differently, so the same saved run would otherwise
fine-tune or evaluate to other numbers from the command line than inside the benchmarks
(``benchmarks/compare.py`` and ``paper.py`` split the CPU for every run).
"""

from __future__ import annotations

import json
import os

from score_jax import registry
from score_jax.run.cpu_split import devices_for, split_cpu_for_seeds


def splits_cpu(algo: str) -> bool:
    """Whether runs of ``algo`` train in this process over a seed axis (SCORE and the
    multi-agent baselines), rather than in brax's own loops, which use every device
    themselves."""
    return algo not in registry.algorithm_names() or registry.entry(algo).in_process


def _saved_config(run_dir: str) -> dict:
    """The run's ``config.json``; empty when it cannot be read (the command's validation
    reports that)."""
    try:
        with open(os.path.join(run_dir, "config.json")) as f:
            saved = json.load(f)
    except (OSError, ValueError):
        return {}
    return saved if isinstance(saved, dict) else {}


def saved_run_seeds(run_dir: str) -> int:
    """The number of seeds of the run saved in ``run_dir`` (1 when it cannot be read)."""
    try:
        return int(_saved_config(run_dir).get("num_seeds", 1))
    except (TypeError, ValueError):
        return 1


def saved_run_devices(run_dir: str) -> int | None:
    """The CPU devices the training of the run in ``run_dir`` had: the device count its
    provenance recorded, when it trained on the CPU in one process; else what ``score-train``
    would ask for it (its algorithm, seeds and ``--cpu-devices``); None when the run cannot be
    read."""
    saved = _saved_config(run_dir)
    if not saved:
        return None
    prov = saved.get("provenance") or {}
    if prov.get("backend") == "cpu" and prov.get("process_count", 1) == 1:
        try:
            return int(prov["device_count"])
        except (KeyError, TypeError, ValueError):
            pass
    algo = saved.get("algo")
    if not isinstance(algo, str) or not splits_cpu(algo):
        return 1
    if isinstance(saved.get("cpu_devices"), int):
        return saved["cpu_devices"]  # the run's --cpu-devices
    return devices_for(saved_run_seeds(run_dir), os.cpu_count() or 1)


def split_cpu_like_saved_run(run_dir: str) -> int:
    """Split the CPU as the training of the run in ``run_dir`` had it; returns the number of
    devices asked for (1 when nothing changed; a no-op once JAX's backend is up or when the
    user chose a split in ``XLA_FLAGS``)."""
    devices = saved_run_devices(run_dir)
    if devices is None or devices <= 1:
        return 1
    return split_cpu_for_seeds(saved_run_seeds(run_dir), devices)
