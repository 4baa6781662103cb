"""``score-eval``: evaluate a saved run's policy against the reference policies and watch it.

    score-eval --run-dir runs/greenhouse-score-s0                 # table + season plot
    score-eval --run-dir runs/spider-score-s0 --render            # table + GIF / MP4
    score-eval --run-dir DIR --policy last --episodes 20

Writes ``evaluation.json`` and ``evaluation.md`` (and ``season.png`` on the greenhouse,
``render/rollout.{gif,mp4}`` on the Spider with ``--render``) into ``<run-dir>/eval-<policy>``
(``score_jax.evaluation.saved_run``).
"""

from __future__ import annotations

import dataclasses
import sys
from typing import Literal

import tyro

from score_jax.cli.devices import split_cpu_like_saved_run
from score_jax.cli.errors import guarded
from score_jax.evaluation.saved_run import evaluate_saved_run
from score_jax.run.compile_cache import enable_compile_cache


@dataclasses.dataclass(frozen=True)
class EvalArgs:
    """Evaluate a saved run's policy against the reference policies; plot or render it."""

    run_dir: str
    """A run directory written by score-train."""
    policy: Literal["best", "last"] = "best"
    """The run's best-evaluated policy (when it kept one; else the last) or its last one."""
    episodes: int | None = None
    """Evaluation episodes per policy; None = the run's --eval-episodes."""
    render: bool = False
    """Spider: render one deterministic episode to render/rollout.gif and rollout.mp4 (MP4
    needs imageio-ffmpeg: pip install -e .[render]). The greenhouse's season plot is always
    written."""
    render_steps: int | None = None
    """Steps of the rendered episode; None = the run's --render-steps."""
    out: str | None = None
    """Where the files go; None = <run-dir>/eval-<policy>."""
    planned_references: bool | None = None
    """Also evaluate (and plot) the references found by planning on the simulator (greenhouse:
    best constant and open-loop schedules; see score-train --help); None = as the run did."""
    compile_cache: bool = True
    """JAX's persistent compilation cache (see score-train --help)."""


def main(args: EvalArgs) -> int:
    """Evaluate; errors end as every command's do (``cli.errors``: ``error:`` lines, exit 1)."""
    split_cpu_like_saved_run(args.run_dir)  # the devices its training used: the same programs
    enable_compile_cache(enabled=args.compile_cache)
    return guarded(
        lambda: evaluate_saved_run(
            args.run_dir,
            policy=args.policy,
            episodes=args.episodes,
            render=args.render,
            render_steps=args.render_steps,
            out_dir=args.out,
            planned_references=args.planned_references,
        )
    )


def cli() -> int:
    return main(tyro.cli(EvalArgs))


if __name__ == "__main__":
    sys.exit(cli())
