"""The driver of algorithms that run their own training loop (brax SAC / PPO, H-PPO).

``score_jax.train_loop.train`` hands such a run (``Algorithm.train_external`` is set) to
``train_external``, which gives it what every run has:
- ``config.json`` and ``metrics.csv`` (one row per brax epoch, through brax's ``progress_fn``;
  ``eval_return`` is the deterministic evaluation when one ran), and the best-evaluated policy
  (``score_jax.best_policy``) when the algorithm hands its evaluated parameters over;
- a progress bar over env steps;
- an orbax checkpoint (``score_jax.checkpoint``) of the final policy parameters + meta, as an
  ``ExternalState`` whose ``agent`` is what ``Algorithm.policy`` reads, so
  ``restore_run``, the final evaluation, the robustness sweep and ``transfer.py`` treat the run
  like any other.

Exact resume is impossible: brax keeps its optimiser states, replay buffer, environment states
and PRNG inside ``train()`` and returns only the policy, so ``--resume`` on such a run is an
error that says so. ``transfer.py --checkpoint RUN`` warm-starts a new run from the policy.
"""

from __future__ import annotations

import csv
import dataclasses
import os
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from score_jax.best_policy import BestPolicy
from score_jax.checkpoint import Checkpointer, CheckpointError, dump_json
from score_jax.config import resolved_eval_every

RESUME_ERROR = (
    "--resume: {algo} trains inside brax.training, which keeps its optimiser states, replay buffer, "
    "environment states and PRNG to itself and returns only the final policy, so the run cannot be "
    "continued exactly. Its checkpoint holds that policy: evaluate it (python -m score_jax.robustness "
    "--run-dir {run_dir}), fine-tune it on more sub-spaces (python transfer.py --checkpoint {run_dir}), "
    "or start a new run with a larger --total-steps."
)


@struct.dataclass
class ExternalState:
    """What an externally trained run saves: ``agent`` (read by ``Algorithm.policy``) and its env steps."""

    agent: Any
    env_steps: jax.Array  # [] int32


class ExternalTrainer:
    """Stands in for ``trainer.Trainer`` in a ``Run``: builds the checkpoint template from the
    algorithm's ``init`` (for ``restore_run``); there is nothing to shard."""

    def __init__(self, algo):
        self.algo = algo

    def init(self, key: jax.Array) -> ExternalState:
        return ExternalState(_arrays(self.algo.init(key)), jnp.zeros((), jnp.int32))

    def place(self, state: ExternalState) -> ExternalState:
        return state


def _arrays(tree):
    return jax.tree.map(jnp.asarray, tree)


def _finite(tree) -> bool:
    return all(bool(np.all(np.isfinite(x))) for x in jax.tree.leaves(tree) if np.issubdtype(np.asarray(x).dtype, np.floating))


def train_external(run, total: int, key: jax.Array, log=print, on_epoch=None, initial_agent=None):
    """Train ``run`` (built by ``train_loop.build``) with ``run.algo.train_external``; returns the run.

    ``key`` initialises the parameters brax starts from; ``initial_agent(run, fresh_agent) -> agent``
    replaces them (transfer.py warm-starts); ``on_epoch(run, row)`` is called for every metrics row.
    """
    from score_jax import train_loop  # train_loop imports this module

    cfg = run.config
    if cfg.resume:
        raise CheckpointError(RESUME_ERROR.format(algo=cfg.algo, run_dir=run.run_dir))
    ckpt = Checkpointer(run.run_dir)
    if ckpt.latest_step() is not None:
        raise CheckpointError(f"{run.run_dir} already holds a run; choose another --run-dir")
    dump_json(os.path.join(run.run_dir, "config.json"), dataclasses.asdict(cfg))
    # brax always starts from these parameters (not its own initialisation), so a run's
    # initial parameters are ``algo.off_policy.init(key)``, reproducible from the seed.
    initial = run.trainer.init(key).agent
    initial = _arrays(initial_agent(run, initial) if initial_agent is not None else initial)
    progress = train_loop._progress(total, 0, cfg.quiet)
    best = BestPolicy(run.run_dir, fresh=True) if cfg.keep_best and resolved_eval_every(cfg) else None
    t0, done = time.time(), [0]

    with open(os.path.join(run.run_dir, "metrics.csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, train_loop.METRIC_COLUMNS)
        writer.writeheader()

        def report(env_steps: int, columns: dict, agent=None) -> None:
            """One metrics row; ``agent``: the parameters ``columns["eval_return"]`` evaluated (kept if the best)."""
            row = {c: float("nan") for c in train_loop.METRIC_COLUMNS}
            row.update(columns, env_steps=int(env_steps), wall_s=round(time.time() - t0, 2))
            writer.writerow(row)
            f.flush()
            progress.update(max(0, int(env_steps) - done[0]), None if np.isnan(row["eval_return"]) else row["eval_return"])
            done[0] = max(done[0], int(env_steps))
            if best is not None and agent is not None:
                best.offer(int(env_steps), row["eval_return"], _arrays(agent), train_loop._meta(run))
            if on_epoch is not None:
                on_epoch(run, row)

        agent = _arrays(run.algo.train_external(run, total, report, initial))
    progress.close()
    if best is not None:
        best.close()
    if not _finite(agent):
        ckpt.close()
        raise train_loop.NonFiniteError(f"{cfg.algo} ended with non-finite parameters after {done[0]} env steps; nothing was saved")
    run.state = ExternalState(agent, jnp.asarray(done[0], jnp.int32))
    ckpt.save(done[0], run.state, train_loop._meta(run))
    ckpt.close()
    log(f"{cfg.algo}: trained {done[0]} env steps in {time.time() - t0:.1f} s; checkpoint in {ckpt.directory}")
    return run
