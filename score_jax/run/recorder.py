"""What every run records, whichever loop trains it: the metrics rows (``metrics.csv`` through
the metric writers), a progress bar, and the best-evaluated policy."""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable
from typing import Any

from score_jax.run.best_policy import BestPolicy
from score_jax.run.writers import make_writers, truncate_csv

METRICS_CSV = "metrics.csv"


class NonFiniteError(RuntimeError):
    """A loss or parameter became NaN/inf; the run stopped at the last good checkpoint."""


class Progress:
    """tqdm progress over decisions with the recent episode return; silent when quiet."""

    def __init__(self, total: int, start: int, quiet: bool):
        self.bar = None
        if not quiet:
            from tqdm.auto import tqdm  # deferred: tqdm.auto probes for notebooks on import

            self.bar = tqdm(
                total=total,
                initial=start,
                unit="step",
                dynamic_ncols=True,
                file=sys.stderr,
                mininterval=1.0,
            )

    def update(self, n: int, recent_return: float | None):
        if self.bar is not None:
            if recent_return is not None:
                self.bar.set_postfix_str(f"return {recent_return:.1f}", refresh=False)
            self.bar.update(n)

    def write(self, message: str, log=print):
        """A line above the bar (or through ``log`` when quiet)."""
        if self.bar is not None:
            self.bar.write(message, file=sys.stderr)
        else:
            log(message)

    def close(self):
        if self.bar is not None:
            self.bar.close()


class RunRecorder:
    """Writes metrics rows, moves the progress bar, keeps the best-evaluated policy.

    ``columns``: the metric names of every row, in order (a row's missing ones are NaN).
    ``resume_from``: on resume, the decision count of the restored checkpoint (rows after it
    are produced again, so they are dropped); None for a new run (the file is started anew).
    ``meta``: the run's checkpoint metadata, saved with the best policy.
    ``track``: metric writers besides the CSV file (``tensorboard``, ``wandb``; see
    ``run.writers.make_writers``); ``wandb_project``, ``wandb_mode``, ``wandb_config``: the W&B
    run's project, mode and config.
    """

    def __init__(
        self,
        run_dir: str,
        columns: list[str],
        total: int,
        quiet: bool,
        meta: dict,
        keep_best: bool,
        resume_from: int | None = None,
        log=print,
        on_row: Callable | None = None,
        track: tuple[str, ...] = ("csv",),
        wandb_project: str = "score-jax",
        wandb_mode: str | None = None,
        wandb_config: dict | None = None,
    ):
        path = os.path.join(run_dir, METRICS_CSV)
        if resume_from is None:
            if os.path.exists(path):
                os.remove(path)
        else:
            truncate_csv(path, resume_from)
        self.columns = list(columns)
        self.writer = make_writers(
            track,
            run_dir,
            csv_name=METRICS_CSV,
            csv_columns=self.columns,
            project=wandb_project,
            config=wandb_config,
            wandb_mode=wandb_mode,
            name=os.path.basename(os.path.abspath(run_dir)),
        )
        self.progress = Progress(total, resume_from or 0, quiet)
        self.best = BestPolicy(run_dir, fresh=resume_from is None) if keep_best else None
        self.meta, self.log, self.on_row = meta, log, on_row
        self.t0 = time.time()
        self.done = resume_from or 0
        self.recent: list[float] = []

    def record(self, env_steps: int, row: dict, agent: Any = None) -> dict:
        """Write one row at ``env_steps``; ``agent``: the parameters ``row["eval_return"]``
        evaluated (kept when the best so far). Returns the full row."""
        full = {c: math.nan for c in self.columns}
        full.update(row, wall_s=round(time.time() - self.t0, 2))
        self.writer.write(int(env_steps), full)
        episode = full.get("episode_return", math.nan)
        if not math.isnan(episode):
            self.recent = (self.recent + [episode])[-10:]
        evaluation = full.get("eval_return", math.nan)
        if not math.isnan(evaluation):
            kept = (
                self.best is not None
                and agent is not None
                and self.best.offer(int(env_steps), evaluation, agent, self.meta)
            )
            note = f", the best so far (saved to {self.best.ckpt.directory})" if kept else ""
            self.progress.write(
                f"env step {int(env_steps)}: evaluation {evaluation:.1f}{note}", self.log
            )
        shown = self.recent[-1] if self.recent else (None if math.isnan(evaluation) else evaluation)
        self.progress.update(max(0, int(env_steps) - self.done), shown)
        self.done = max(self.done, int(env_steps))
        if self.on_row is not None:
            self.on_row({"env_steps": int(env_steps), **full})
        return full

    def close(self) -> None:
        self.progress.close()
        self.writer.close()
        if self.best is not None:
            self.best.close()
