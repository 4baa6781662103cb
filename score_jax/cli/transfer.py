"""``score-transfer``: grow a trained run by unseen sub-action spaces (§4.3) and fine-tune it.

    score-train --env greenhouse --subspaces co2,lighting --run-dir runs/gh-subset
    score-transfer --checkpoint runs/gh-subset --total-steps 60000 [--compare-scratch]

Reports the return before fine-tuning ("Initial") and after ("Converge") and plots the
fine-tuning curve (against training from scratch on the full space with --compare-scratch).
"""

from __future__ import annotations

import sys

import tyro

from score_jax.cli.devices import split_cpu_like_saved_run
from score_jax.cli.errors import guarded
from score_jax.evaluation.transfer import TransferArgs, run_transfer
from score_jax.run.compile_cache import enable_compile_cache


def main(args: TransferArgs) -> int:
    """Transfer; errors as ``error:`` lines, exit status 2 (usage) or 1 (run) (``cli.errors``)."""
    split_cpu_like_saved_run(args.checkpoint)  # the devices its training used: the same programs
    enable_compile_cache(enabled=args.compile_cache)
    return guarded(lambda: run_transfer(args))


def cli() -> int:
    return main(tyro.cli(TransferArgs))


if __name__ == "__main__":
    sys.exit(cli())
