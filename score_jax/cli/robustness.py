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

from score_jax.evaluation.robustness import run_sweep
from score_jax.run.build import restore_run
from score_jax.run.checkpoint import CheckpointError
from score_jax.run.compile_cache import enable_compile_cache


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
    enable_compile_cache(enabled=args.compile_cache)
    try:
        run = restore_run(args.run_dir, policy=args.policy)
    except CheckpointError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    run_sweep(run, args.seeds)
    print(f"wrote {os.path.join(run.run_dir, 'robustness.json')} and robustness.png")
    return 0


def cli() -> int:
    return main(tyro.cli(RobustnessArgs))


if __name__ == "__main__":
    sys.exit(cli())
