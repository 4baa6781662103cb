"""Keep the best-evaluated policy of a run (``<run_dir>/best``), next to the last one.

SAC's deterministic policy can swing between evaluations long before training has settled
(on the greenhouse a season's return can fall several-fold from one evaluation to the next in
runs whose stochastic returns keep improving: a few days of too-short irrigation compound over
the season). Like stable-baselines' ``EvalCallback(best_model_save_path=...)``,
the run saves the agent state whenever a periodic deterministic evaluation beats every earlier
one; the final report shows both the last and the best policy, and ``restore_run(...,
policy="best")`` loads it. Resuming a run keeps the best found before the interruption.
"""

from __future__ import annotations

import os
import shutil
import time
from typing import Any

from score_jax.run.checkpoint import Checkpointer, CheckpointError, checkpoint_dir

BEST = "best"


class BestPolicy:
    """The best agent state so far and its evaluation return (``-inf`` before the first)."""

    def __init__(self, run_dir: str, fresh: bool, log=print):
        if fresh and os.path.isdir(
            checkpoint_dir(run_dir, BEST)
        ):  # a new run never inherits a best
            shutil.rmtree(checkpoint_dir(run_dir, BEST))
        self.ckpt = Checkpointer(run_dir, max_to_keep=1, name=BEST)
        self.step, self.eval_return = None, float("-inf")
        if self.ckpt.latest_step() is not None:
            try:
                meta = self.ckpt.read_meta()
            except CheckpointError as e:  # a damaged best policy never stops the run
                log(f"warning: {e}; the run keeps a new best policy from here on")
                self.ckpt.close()
                shutil.move(
                    self.ckpt.directory, f"{self.ckpt.directory}.unusable-{time.time():.0f}"
                )
                self.ckpt = Checkpointer(run_dir, max_to_keep=1, name=BEST)
            else:
                self.step, self.eval_return = int(meta["step"]), float(meta["eval_return"])

    def offer(self, step: int, eval_return: float, agent_state: Any, meta: dict) -> bool:
        """Save ``agent_state`` if ``eval_return`` beats the best so far; True if it did."""
        if not eval_return > self.eval_return:  # also refuses NaN
            return False
        self.ckpt.save(step, agent_state, {**meta, "eval_return": float(eval_return)})
        self.step, self.eval_return = step, float(eval_return)
        return True

    def close(self) -> None:
        self.ckpt.close()


def has_best(run_dir: str) -> bool:
    path = checkpoint_dir(run_dir, BEST)
    return (
        os.path.isdir(path)
        and Checkpointer(run_dir, max_to_keep=1, name=BEST).latest_step() is not None
    )


def restore_best(run_dir: str, template_agent: Any) -> tuple[Any, dict]:
    """``(agent_state, meta)`` of the best policy (``meta["step"]``, ``meta["eval_return"]``)."""
    ckpt = Checkpointer(run_dir, max_to_keep=1, name=BEST)
    try:
        return ckpt.restore(template_agent)
    finally:
        ckpt.close()
