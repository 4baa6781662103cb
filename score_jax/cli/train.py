"""``score-train``: train SCORE (or a baseline) on a composite-action environment.

score-train                                  # SCORE on the greenhouse, laptop-sized defaults
score-train --env spider --total-steps 200000
score-train --resume runs/greenhouse-score-s0
score-train --env spider --describe          # the sub-spaces --subspaces accepts, and presets
score-train --track tensorboard wandb        # metrics.csv + TensorBoard + W&B (offline)
score-train --num-seeds 4 --distributed --coordinator-address host0:1234 \
            --num-processes 2 --process-id 0  # on host0; --process-id 1 on the other host
score-train --help                           # every option
"""

from __future__ import annotations

import os
import sys

import tyro

from score_jax.cli.devices import saved_run_seeds, splits_cpu
from score_jax.cli.errors import guarded
from score_jax.evaluation.curves import REFERENCE_LINES, plot_learning_curve
from score_jax.evaluation.report import final_evaluation, render_policy
from score_jax.evaluation.robustness import run_sweep
from score_jax.run import distributed
from score_jax.run.build import with_best_policy
from score_jax.run.compile_cache import enable_compile_cache
from score_jax.run.config import TrainConfig
from score_jax.run.cpu_split import split_cpu_for_seeds
from score_jax.run.driver import train
from score_jax.run.summary import describe_environment
from score_jax.run.validate import UsageError


def main(cfg: TrainConfig) -> int:
    """Train, then report; every error a user can cause is one ``error:`` line per problem and
    exit status 2 (usage) or 1 (run), never a traceback (``cli.errors``).

    ``--distributed``: every process runs this same command; they join (``run.distributed``)
    before anything starts JAX's backend, and only process 0 writes and prints."""
    if splits_cpu(cfg.algo):  # brax's own loops use every device themselves
        split_cpu_for_seeds(_seeds_per_process(cfg), cfg.cpu_devices)
    return guarded(lambda: _start(cfg))


def _start(cfg: TrainConfig) -> None:
    if cfg.distributed:
        try:
            distributed.initialize(cfg)
        except ValueError as e:
            raise UsageError([str(e)]) from None
    enable_compile_cache(enabled=cfg.compile_cache)
    _train_and_report(cfg)


def _seeds_per_process(cfg: TrainConfig) -> int:
    """The seeds each process trains (the CPU split is per process): all of them, or with
    ``--distributed`` their share when the process count is known before JAX starts."""
    seeds = _num_seeds(cfg)
    if not cfg.distributed:
        return seeds
    try:
        count = distributed.launch_settings(cfg)[1]
    except ValueError:
        return 1  # joining reports it
    return seeds // count if count and seeds % count == 0 else 1


def _num_seeds(cfg: TrainConfig) -> int:
    """The run's seeds: a resumed run's from its config.json (read before JAX starts)."""
    return saved_run_seeds(cfg.resume) if cfg.resume else cfg.num_seeds


def _train_and_report(cfg: TrainConfig) -> None:
    if cfg.describe:
        print(describe_environment(cfg.env, cfg.env_overrides()))
        return
    run = train(cfg)
    say = distributed.primary_only(print)  # distributed: every process evaluates, 0 writes
    say(f"\nrun directory: {run.run_dir}")
    rows = final_evaluation(run, run.config.eval_episodes)
    curve = os.path.join(run.run_dir, "learning_curve.png")
    if distributed.is_primary():
        plot_learning_curve(
            os.path.join(run.run_dir, "metrics.csv"),
            curve,
            f"{run.config.algo} on {run.config.env}",
            references={name: rows[name]["mean"] for name in REFERENCE_LINES if name in rows},
        )
    say(f"learning curve: {curve}")
    run = with_best_policy(run, log=say)  # the sweep and the render show the best policy, if kept
    if run.config.robustness_seeds:
        run_sweep(run, run.config.robustness_seeds)
    if run.config.render:
        render_policy(run, run.config.render_steps, os.path.join(run.run_dir, "render"))


def cli() -> int:
    return main(tyro.cli(TrainConfig))


if __name__ == "__main__":
    sys.exit(cli())
