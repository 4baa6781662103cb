"""``score-robustness``: sweep failed sub-spaces x failure modes x seeds for a trained run, in
one compiled call (§5.2.3, Figs. 7/9).

    score-robustness --run-dir runs/greenhouse-score-s0 [--seeds 10] [--policy best|last]
"""

from __future__ import annotations

import dataclasses
import os
import sys
from typing import Literal

import tyro

from score_jax.cli.devices import split_cpu_like_saved_run
from score_jax.cli.errors import guarded
from score_jax.evaluation.robustness import run_sweep
from score_jax.run.build import restore_run
from score_jax.run.compile_cache import enable_compile_cache
from score_jax.run.validate import UsageError, validate_robustness_args


@dataclasses.dataclass(frozen=True)
class RobustnessArgs:
    """Sweep failed sub-spaces x failure modes x seeds for a trained run, in one compiled call."""

    run_dir: str
    """A run directory written by score-train (train.py)."""
    seeds: int = 10
    """Seeds per (count, mode) setting."""
    policy: Literal["best", "last"] = "best"
    """Sweep the run's best-evaluated policy (when it kept one) or its last one."""
    compile_cache: bool = True
    """JAX's persistent compilation cache (see score-train --help)."""


def main(args: RobustnessArgs) -> int:
    """Sweep; errors as ``error:`` lines, exit status 2 (usage) or 1 (run) (``cli.errors``)."""
    split_cpu_like_saved_run(args.run_dir)  # the devices its training used: the same programs
    enable_compile_cache(enabled=args.compile_cache)
    return guarded(lambda: _sweep(args))


def _sweep(args: RobustnessArgs) -> None:
    problems = validate_robustness_args(args)  # before anything is built; creates nothing
    if problems:
        raise UsageError(problems)
    run = restore_run(args.run_dir, policy=args.policy)
    run_sweep(run, args.seeds)
    print(f"wrote {os.path.join(run.run_dir, 'robustness.json')} and robustness.png")


def cli() -> int:
    return main(tyro.cli(RobustnessArgs))


if __name__ == "__main__":
    sys.exit(cli())
