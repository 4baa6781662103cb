"""Train SCORE (or a baseline) on a composite-action environment.

    python train.py                                  # SCORE on the greenhouse, laptop-sized defaults
    python train.py --env spider --total-steps 200000
    python train.py --resume runs/greenhouse-score-s0
    python train.py --help                           # every option
"""

from __future__ import annotations

import os
import sys

import tyro

from score_jax.checkpoint import CheckpointError
from score_jax.config import TrainConfig
from score_jax.report import final_evaluation, plot_learning_curve, render_policy
from score_jax.robustness import run_sweep
from score_jax.train_loop import NonFiniteError, train, with_best_policy


def main(cfg: TrainConfig) -> int:
    try:
        run = train(cfg)
    except (NonFiniteError, CheckpointError, ValueError, KeyError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(f"\nrun directory: {run.run_dir}")
    plot_learning_curve(os.path.join(run.run_dir, "metrics.csv"), os.path.join(run.run_dir, "learning_curve.png"), f"{run.config.algo} on {run.config.env}")
    print(f"learning curve: {os.path.join(run.run_dir, 'learning_curve.png')}")
    final_evaluation(run, run.config.eval_episodes)
    run = with_best_policy(run)  # the sweep and the render show the best-evaluated policy, if kept
    if run.config.robustness_seeds:
        run_sweep(run, run.config.robustness_seeds)
    if run.config.render:
        render_policy(run, run.config.render_steps, os.path.join(run.run_dir, "render"))
    return 0


if __name__ == "__main__":
    sys.exit(main(tyro.cli(TrainConfig)))
