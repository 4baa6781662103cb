"""Transfer a trained SCORE (or ISAC / MAAC / QMIX) run to unseen sub-action spaces (§4.3) and fine-tune it.

    python train.py --env greenhouse --subspaces co2,lighting --run-dir runs/gh-subset
    python transfer.py --checkpoint runs/gh-subset --total-steps 60000 [--compare-scratch]

Reports the return before fine-tuning ("Initial") and after ("Converge") and plots the
fine-tuning curve (against training from scratch on the full space with --compare-scratch).
"""

from __future__ import annotations

import dataclasses
import os
import sys
import types

import jax
import numpy as np
import tyro

from score_jax import transfer as tr
from score_jax.checkpoint import CheckpointError, dump_json
from score_jax.config import resolved_total_steps
from score_jax.report import plot_curves
from score_jax.train_loop import NonFiniteError, resolve_agent_index, restore_run, train


@dataclasses.dataclass(frozen=True)
class TransferArgs:
    """Grow a trained run (score, isac, maac, qmix) by unseen sub-spaces and fine-tune it (§4.3)."""

    checkpoint: str
    """Run directory of the trained (subset) run."""
    env: str = ""
    """Environment to transfer to; must be the checkpoint's (empty = the checkpoint's)."""
    subspaces: str = ""
    """Comma-separated target sub-spaces (must include the trained ones); empty = all."""
    total_steps: int = 0
    """Fine-tuning environment steps; 0 = the source run's budget."""
    run_dir: str = ""
    """Where the fine-tuning run goes; empty = <checkpoint>-transfer."""
    finetune_old_actors: bool = False
    """Also fine-tune the actors of the sub-spaces seen in training (default: frozen)."""
    compare_scratch: bool = False
    """Also train the same algorithm from scratch on the target space with the same budget, and plot both."""
    eval_episodes: int = 10
    """Evaluation episodes for the Initial and Converge returns."""
    quiet: bool = False
    """No progress bar."""


def _mean_std(x) -> dict:
    x = np.asarray(x)
    return {"mean": float(x.mean()), "std": float(x.std())}


def run_transfer(args: TransferArgs, log=print) -> dict:
    src = restore_run(args.checkpoint, log=log)
    if src.algo.grow is None:
        raise ValueError(
            f"{args.checkpoint} was trained with {src.config.algo!r}, whose networks are tied to the sub-spaces it was "
            "trained on, so it cannot grow by unseen ones (transfer.py grows score, isac, maac and qmix runs)"
        )
    if args.env and args.env != src.config.env:
        raise CheckpointError(f"checkpoint {args.checkpoint} was trained on env {src.config.env!r}, not {args.env!r}")
    space = src.env.space
    target = resolve_agent_index(space, tuple(x.strip() for x in args.subspaces.split(",") if x.strip()))
    p = tr.plan(src.agent_index, target)
    new_names = [space.names[i] for i in p.agent_index[p.is_new]]
    log(f"transfer: {[space.names[i] for i in src.agent_index]} + new {new_names}")
    key_embed, _ = jax.random.split(jax.random.PRNGKey(src.config.seed + 40_000))
    run_dir = args.run_dir or args.checkpoint.rstrip("/") + "-transfer"
    total = args.total_steps or resolved_total_steps(src.config)
    cfg = dataclasses.replace(
        src.config, subspaces=",".join(space.names[i] for i in p.agent_index), transfer_from=os.path.abspath(args.checkpoint),
        transfer_new=",".join(new_names), finetune_old_actors=args.finetune_old_actors, run_dir=run_dir, resume="",
        total_steps=total, quiet=args.quiet, eval_episodes=args.eval_episodes,
    )
    initial = {}

    def grow(run, template):
        agent = src.algo.grow(src, template, p, key_embed)
        initial["returns"] = run.algo.evaluate(run, types.SimpleNamespace(agent=agent), args.eval_episodes).returns
        log(f"Initial (before fine-tuning): {float(np.mean(initial['returns'])):.2f}")
        return agent

    run = train(cfg, log=log, initial_agent=grow)
    final = run.algo.evaluate(run, run.state, args.eval_episodes).returns
    result = {"source": args.checkpoint, "new_subspaces": new_names, "total_steps": total,
              "initial": _mean_std(initial["returns"]), "converge": _mean_std(final)}
    label = "SCORE" if src.config.algo == "score" else src.config.algo.upper()
    curves = {f"{label} transfer (fine-tuning)": os.path.join(run_dir, "metrics.csv")}
    if args.compare_scratch:
        scratch_cfg = dataclasses.replace(cfg, transfer_from="", transfer_new="", run_dir=run_dir + "-scratch")
        scratch = train(scratch_cfg, log=log)
        result["scratch_converge"] = _mean_std(scratch.algo.evaluate(scratch, scratch.state, args.eval_episodes).returns)
        curves[f"{label} from scratch (full space)"] = os.path.join(run_dir + "-scratch", "metrics.csv")
    dump_json(os.path.join(run_dir, "transfer.json"), result)
    plot_curves(curves, os.path.join(run_dir, "transfer.png"), f"transfer on {cfg.env}: + {', '.join(new_names)}")
    log(f"{'':12s}{'Initial':>18s}{'Converge':>18s}")
    log(f"{label:12s}{result['initial']['mean']:>11.2f} ± {result['initial']['std']:<5.1f}{result['converge']['mean']:>11.2f} ± {result['converge']['std']:<5.1f}")
    if "scratch_converge" in result:
        log(f"{'scratch':12s}{'':>18s}{result['scratch_converge']['mean']:>11.2f} ± {result['scratch_converge']['std']:<5.1f}")
    log(f"wrote {os.path.join(run_dir, 'transfer.json')} and transfer.png")
    return result


def main(args: TransferArgs) -> int:
    try:
        run_transfer(args)
    except (CheckpointError, NonFiniteError, ValueError, KeyError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(tyro.cli(TransferArgs)))
