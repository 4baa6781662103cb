"""``score-transfer``: grow a trained run by unseen sub-action spaces (§4.3) and fine-tune it.

    score-train --env greenhouse --subspaces co2,lighting --run-dir runs/gh-subset
    score-transfer --checkpoint runs/gh-subset --total-steps 60000 [--compare-scratch]

Reports the return before fine-tuning ("Initial") and after ("Converge") and plots the
fine-tuning curve (against training from scratch on the full space with --compare-scratch).
"""

from __future__ import annotations

import sys

import tyro

from score_jax.evaluation.transfer import TransferArgs, run_transfer
from score_jax.run.checkpoint import CheckpointError
from score_jax.run.compile_cache import enable_compile_cache
from score_jax.run.recorder import NonFiniteError


def main(args: TransferArgs) -> int:
    enable_compile_cache(enabled=args.compile_cache)
    try:
        run_transfer(args)
    except (CheckpointError, NonFiniteError, ValueError, KeyError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    return 0


def cli() -> int:
    return main(tyro.cli(TransferArgs))


if __name__ == "__main__":
    sys.exit(cli())
