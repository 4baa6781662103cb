"""Keep the best-evaluated policy of a run (``<run_dir>/best``), next to the last one.

SAC's deterministic policy can swing between evaluations long before training has settled
(on the greenhouse a season's return can fall several-fold from one evaluation to the next in
runs whose stochastic returns keep improving: a few days of too-short irrigation compound over
the season). Like stable-baselines' ``EvalCallback(best_model_save_path=...)``,
the run saves the agent state whenever a periodic deterministic evaluation beats every earlier
one; the final report shows both the last and the best policy, and ``restore_run(...,
policy="best")`` loads it. Resuming a run keeps the best found before the interruption.
In a distributed run every process keeps the same bests; process 0 writes them.
"""

from __future__ import annotations

import os
import shutil
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from score_jax.run import distributed
from score_jax.run.checkpoint import Checkpointer, CheckpointError, checkpoint_dir

BEST = "best"


class BestPolicy:
    """The best agent state of every seed so far and its evaluation return (``-inf`` before the
    first): one checkpoint of the seed-stacked agent state, each seed's slot its own best.

    ``meta["best_steps"]`` / ``meta["best_returns"]`` (lists over seeds) say when each seed's
    best was evaluated and what it scored (None / -inf for a seed without one yet). A damaged
    best-policy checkpoint never stops the run: it is set aside and a new best is kept.

    The checkpoint's step number is the env step of the save, or one past the previous save's
    when that is not larger: seeds trained one after another (brax-driven algorithms) evaluate
    from step 0 again, and a checkpoint's steps must grow.
    """

    def __init__(self, run_dir: str, fresh: bool, num_seeds: int = 1, log=print):
        writes = distributed.is_primary()
        if fresh and writes and os.path.isdir(checkpoint_dir(run_dir, BEST)):  # never inherited
            shutil.rmtree(checkpoint_dir(run_dir, BEST))
        self.ckpt = Checkpointer(run_dir, max_to_keep=1, name=BEST)  # (distributed: waits for 0)
        self.steps: list[int | None] = [None] * num_seeds
        self.returns = np.full(num_seeds, -np.inf)
        self._agent: Any = None
        self._saved = self.ckpt.latest_step() is not None
        self._last_id = self.ckpt.latest_step() if self._saved else -1
        if self._saved:
            try:
                meta = self.ckpt.read_meta()
            except CheckpointError as e:  # a damaged best policy never stops the run
                log(f"warning: {e}; the run keeps a new best policy from here on")
                self.ckpt.close()
                if writes:
                    shutil.move(
                        self.ckpt.directory, f"{self.ckpt.directory}.unusable-{time.time():.0f}"
                    )
                self.ckpt = Checkpointer(run_dir, max_to_keep=1, name=BEST)
                self._saved, self._last_id = False, -1
            else:
                self.steps = [None if x is None else int(x) for x in meta["best_steps"]]
                self.returns = np.asarray(meta["best_returns"], float)

    def offer(self, step: int, eval_returns, agent_state: Any, meta: dict) -> np.ndarray:
        """Keep each seed's slot of ``agent_state`` (seed-stacked) whose return in
        ``eval_returns [K]`` beats that seed's best so far; ``[K]`` bool: which did. NaN never
        does."""
        returns = np.atleast_1d(np.asarray(eval_returns, float))
        better = returns > self.returns
        if not better.any():
            return better
        if self._agent is None:  # the bests saved before a resume are the other seeds' slots
            self._agent = self.ckpt.restore(agent_state)[0] if self._saved else agent_state
        self._agent = pick_seeds(jnp.asarray(better), agent_state, self._agent)
        self.steps = [int(step) if b else s for b, s in zip(better, self.steps, strict=True)]
        self.returns = np.where(better, returns, self.returns)
        best_meta = {**meta, "best_steps": self.steps, "best_returns": self.returns.tolist()}
        self._last_id = max(int(step), self._last_id + 1)
        self.ckpt.save(self._last_id, self._agent, best_meta)
        self._saved = True
        return better

    def close(self) -> None:
        self.ckpt.close()


@jax.jit
def pick_seeds(mask: jax.Array, new: Any, old: Any) -> Any:
    """Seed k's slot of every leaf from ``new`` where ``mask [K]``, else from ``old``: one
    program for the whole agent (leaf by leaf, each shape compiled its own ``where``)."""
    pick = lambda a, b: jnp.where(mask.reshape((-1,) + (1,) * (jnp.ndim(a) - 1)), a, b)
    return jax.tree.map(pick, new, old)


def has_best(run_dir: str) -> bool:
    if not os.path.isdir(checkpoint_dir(run_dir, BEST)):
        return False
    ckpt = Checkpointer(run_dir, max_to_keep=1, name=BEST, create=False)  # reads only
    try:
        return ckpt.latest_step() is not None
    finally:
        ckpt.close()


def restore_best(run_dir: str, template_agent: Any) -> tuple[Any, dict]:
    """``(agent_state, meta)`` of the best policies (seed-stacked; ``meta["best_steps"]``,
    ``meta["best_returns"]`` per seed)."""
    ckpt = Checkpointer(run_dir, max_to_keep=1, name=BEST, create=False)  # reads only
    try:
        return ckpt.restore(template_agent)
    finally:
        ckpt.close()
