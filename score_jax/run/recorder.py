"""What every run records, whichever loop trains it: the metrics rows (``metrics.csv`` through
the metric writers), a progress bar, and the best-evaluated policy. In a distributed run only
process 0 writes rows and shows the bar; every process keeps the best policies (process 0
saves them)."""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from score_jax.run import distributed
from score_jax.run.best_policy import BestPolicy
from score_jax.run.writers import NullWriter, make_writers, truncate_csv

METRICS_CSV = "metrics.csv"


def step_label(decisions: int, action_repeat: int = 1) -> str:
    """How a message names a point of a run: ``"env step N"``, or with decisions held
    ``action_repeat > 1`` env steps (the greenhouse's 8 days) ``"decision N (env step M)"``, so
    that a log line never passes decisions off as environment steps."""
    if action_repeat == 1:
        return f"env step {decisions}"
    return f"decision {decisions} (env step {decisions * action_repeat})"


class NonFiniteError(RuntimeError):
    """A loss or parameter became NaN/inf; the run stopped at the last good checkpoint."""


class Progress:
    """tqdm progress over decisions with the recent episode return; silent when quiet."""

    def __init__(self, total: int, start: int, quiet: bool, silent: bool = False):
        self.bar, self.silent = None, silent  # silent: nothing at all (distributed, not 0)
        quiet = quiet or silent
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
        elif not self.silent:
            log(message)

    def close(self):
        if self.bar is not None:
            self.bar.close()


class RunRecorder:
    """Writes metrics rows (one per seed, with a ``seed`` column), moves the progress bar,
    keeps each seed's best-evaluated policy.

    ``columns``: the metric names of every row, in order (a row's missing ones are NaN).
    ``seeds``: the run's seeds. ``total``: decisions the progress bar counts to.
    ``resume_from``: on resume, the decision count of the restored checkpoint (rows after it
    are produced again, so they are dropped); None for a new run (the file is started anew).
    ``meta``: the run's checkpoint metadata, saved with the best policies.
    ``action_repeat``: env steps per decision, for the messages (``step_label``).
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
        seeds: tuple[int, ...] = (0,),
        resume_from: int | None = None,
        log=print,
        on_row: Callable | None = None,
        track: tuple[str, ...] = ("csv",),
        wandb_project: str = "score-jax",
        wandb_mode: str | None = None,
        wandb_config: dict | None = None,
        action_repeat: int = 1,
    ):
        path = os.path.join(run_dir, METRICS_CSV)
        writes = distributed.is_primary()  # distributed: only process 0 writes
        if writes and resume_from is None:
            if os.path.exists(path):
                os.remove(path)
        elif writes:
            truncate_csv(path, resume_from)
        self.columns, self.seeds = list(columns), tuple(seeds)
        self.writer = NullWriter()
        if writes:
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
        self.progress = Progress(total, resume_from or 0, quiet, silent=not writes)
        self.best = (
            BestPolicy(run_dir, resume_from is None, len(self.seeds), log) if keep_best else None
        )
        self.meta, self.log, self.on_row = meta, log, on_row
        self.action_repeat = action_repeat
        self.t0 = time.time()
        self.done = resume_from or 0
        self.last_step = resume_from or 0
        self.recent: dict[int, float] = {}

    def record(
        self,
        env_steps: int,
        rows: Sequence[dict],
        agent: Any = None,
        live=None,
        progress_at: int | None = None,
    ) -> list[dict]:
        """Write one row per seed at ``env_steps`` (``rows[k]``: seed ``seeds[k]``; seeds where
        ``live`` is False are stopped and write nothing); ``agent``: the seed-stacked parameters
        the rows' ``eval_return`` evaluated (each seed's kept when its best so far);
        ``progress_at``: the progress bar's position (default ``env_steps``; seeds trained one
        after another count on). Returns the full rows."""
        live = [True] * len(rows) if live is None else [bool(x) for x in live]
        full_rows = []
        for k, row in enumerate(rows):
            full = {c: math.nan for c in self.columns}
            full.update(row, wall_s=round(time.time() - self.t0, 2))
            full_rows.append(full)
            if not live[k]:
                continue
            self.writer.write(int(env_steps), full, seed=self.seeds[k])
            if not math.isnan(full.get("episode_return", math.nan)):
                self.recent[k] = full["episode_return"]
            if self.on_row is not None:
                self.on_row({"env_steps": int(env_steps), "seed": self.seeds[k], **full})
        evaluations = np.asarray(
            [
                r.get("eval_return", math.nan) if ok else math.nan
                for r, ok in zip(full_rows, live, strict=True)
            ]
        )
        if not np.all(np.isnan(evaluations)):
            self._report_evaluation(int(env_steps), evaluations, agent)
        shown = float(np.mean(list(self.recent.values()))) if self.recent else None
        if shown is None and not np.all(np.isnan(evaluations)):
            shown = float(np.nanmean(evaluations))
        position = int(env_steps) if progress_at is None else int(progress_at)
        self.progress.update(max(0, position - self.done), shown)
        self.done = max(self.done, position)
        self.last_step = int(env_steps)
        return full_rows

    def _report_evaluation(self, env_steps: int, evaluations: np.ndarray, agent: Any) -> None:
        kept = np.zeros(len(evaluations), bool)
        if self.best is not None and agent is not None:
            kept = self.best.offer(env_steps, evaluations, agent, self.meta)
        done = ~np.isnan(evaluations)
        where = step_label(env_steps, self.action_repeat)
        if len(evaluations) == 1:
            note = f", the best so far (saved to {self.best.ckpt.directory})" if kept[0] else ""
            message = f"{where}: evaluation {evaluations[0]:.1f}{note}"
        else:
            per_seed = " ".join(
                f"{v:.1f}{'*' if b else ''}"
                for v, b, d in zip(evaluations, kept, done, strict=True)
                if d
            )
            message = (
                f"{where}: evaluation mean {np.nanmean(evaluations):.1f} over "
                f"{int(done.sum())} seeds ({per_seed}; * = that seed's best so far)"
            )
        self.progress.write(message, self.log)

    def close(self) -> None:
        self.progress.close()
        self.writer.close()
        if self.best is not None:
            self.best.close()
