"""Transfer of a trained (subset) run to unseen sub-action spaces (§4.3, §5.2.4), and its
Initial / Converge report.

``run_transfer`` restores a run, grows its agent axis by the unseen sub-spaces
(``Algorithm.grow``: SCORE embeds them with its frozen HVAE first), reports the grown policy's
return before fine-tuning (Initial), fine-tunes it on the target space (Converge), and can also
train the same algorithm from scratch on the target space for comparison.
"""

from __future__ import annotations

import dataclasses
import os

import jax
import jax.numpy as jnp
import numpy as np

from score_jax.agents.growth import plan
from score_jax.evaluation.curves import plot_curves
from score_jax.run.build import resolve_agent_index, restore_run
from score_jax.run.checkpoint import dump_json
from score_jax.run.config import TransferSpec, critic_owns_encoders
from score_jax.run.driver import train
from score_jax.run.validate import UsageError, transfer_run_dir, validate_transfer_args


@dataclasses.dataclass(frozen=True)
class TransferArgs:
    """Grow a trained run (score, isac, maac, qmix) by unseen sub-spaces, or fine-tune one built
    for the full space (sac, ppo, hppo, maddpg, and maac / qmix trained with a
    --single.transfer-variant) on them, and report Initial / Converge (§4.3, §5.2.4)."""

    checkpoint: str
    """Run directory of the trained (subset) run."""
    env: str | None = None
    """Environment to transfer to; must be the checkpoint's (None = the checkpoint's)."""
    subspaces: str | None = None
    """Comma-separated target sub-spaces (must include the trained ones); None = all."""
    total_steps: int | None = None
    """Fine-tuning decisions; None = the source run's budget."""
    run_dir: str | None = None
    """Where the fine-tuning run goes; None = <checkpoint>-transfer."""
    finetune_old_actors: bool = False
    """Also fine-tune the actors of the sub-spaces seen in training (default: frozen)."""
    new_actor_prior: bool = False
    """The new sub-spaces' actors start at their defaults (the default prior of
    ``score-train --default-prior``) instead of untrained (mid-range, uniform choices; §4.3),
    which lifts the Initial return towards the source run's. SCORE, ISAC, MAAC: actor offsets;
    QMIX: the new agents' candidate grid and Q head start. Refused for the fixed-width sac, ppo
    and hppo, which add no actors (their subset run started the unseen heads untrained)."""
    freeze_critic_encoder: bool = False
    """SCORE only: keep the critic's own encoders (its copy of the HVAE's state and action
    encoders) frozen, as §4.3 keeps the HVAE. By default they fine-tune with p_w, the
    hypernetwork and f_xi, as they train with the critic in training
    (``--score.critic.finetune-asrl``); frozen, the grown critic ended far below training from
    scratch (``docs/learning.md`` entry 34). The HVAE that embeds the new sub-spaces stays
    frozen either way."""
    compare_scratch: bool = False
    """Also train the same algorithm from scratch on the target space with the same budget, and
    plot both."""
    eval_episodes: int = 10
    """Evaluation episodes for the Initial and Converge returns."""
    quiet: bool = False
    """No progress bar."""
    compile_cache: bool = True
    """JAX's persistent compilation cache (see score-train --help)."""


def _mean_std(x) -> dict:
    """Mean and std over every seed's episodes, and each seed's mean (``x [K, E]``)."""
    x = np.asarray(x)
    per_seed = x.reshape(x.shape[0], -1).mean(-1) if x.ndim > 1 else x.mean(keepdims=True)
    return {"mean": float(x.mean()), "std": float(x.std()), "per_seed": per_seed.tolist()}


def run_transfer(args: TransferArgs, log=print) -> dict:
    problems = validate_transfer_args(args)  # every problem, before anything is restored
    if problems:
        raise UsageError(problems)
    src = restore_run(args.checkpoint, log=log)
    if src.algo.grow is None:
        raise ValueError(
            f"{args.checkpoint} was trained with {src.config.algo!r}, whose networks are tied to "
            "the sub-spaces it was trained on, so it cannot grow by unseen ones "
            "(see score-transfer --help)"
        )
    space = src.env.space
    names = () if args.subspaces is None else tuple(x.strip() for x in args.subspaces.split(","))
    target = resolve_agent_index(space, names)
    p = plan(src.agent_index, target)
    new_names = [space.names[i] for i in p.agent_index[p.is_new]]
    log(f"transfer: {[space.names[i] for i in src.agent_index]} + new {new_names}")
    # one embedding key per seed (seed s: PRNGKey(s + 40000), as a one-seed run of s)
    embed_keys = [jax.random.split(jax.random.PRNGKey(s + 40_000))[0] for s in src.seeds]
    run_dir = transfer_run_dir(args)
    total = args.total_steps if args.total_steps is not None else src.spec.total_steps
    cfg = dataclasses.replace(
        src.config,
        subspaces=",".join(space.names[i] for i in p.agent_index),
        run_dir=run_dir,
        resume=None,
        total_steps=total,
        quiet=args.quiet,
        eval_episodes=args.eval_episodes,
    )
    spec = TransferSpec(
        os.path.abspath(args.checkpoint),
        tuple(new_names),
        args.finetune_old_actors,
        args.new_actor_prior,
        critic_owns_encoders(src.config) and not args.freeze_critic_encoder,
    )
    initial = {}

    def grow(run, template):
        """Every seed grows its own trained agent (``template``: the fresh seed-stacked state)."""
        seed = lambda tree, k: jax.tree.map(lambda x: x[k], tree)
        grown = [
            run.algo.grow(seed(src.state.agent, k), seed(template, k), p, key)
            for k, key in enumerate(embed_keys)
        ]
        agent = jax.tree.map(lambda *xs: jnp.stack(xs), *grown)
        initial["returns"] = run.evaluate(agent, args.eval_episodes).returns
        log(f"Initial (before fine-tuning): {float(np.mean(initial['returns'])):.2f}")
        return agent

    run = train(cfg, log=log, initial_agent=grow, transfer=spec)
    final = run.evaluate(run.state.agent, args.eval_episodes).returns
    result = {
        "source": args.checkpoint,
        "new_subspaces": new_names,
        "total_steps": total,
        "initial": _mean_std(initial["returns"]),
        "converge": _mean_std(final),
    }
    label = "SCORE" if src.config.algo == "score" else src.config.algo.upper()
    curves = {f"{label} transfer (fine-tuning)": os.path.join(run_dir, "metrics.csv")}
    if args.compare_scratch:
        scratch_cfg = dataclasses.replace(cfg, run_dir=run_dir + "-scratch")
        scratch = train(scratch_cfg, log=log)
        result["scratch_converge"] = _mean_std(
            scratch.evaluate(scratch.state.agent, args.eval_episodes).returns
        )
        curves[f"{label} from scratch (full space)"] = os.path.join(
            run_dir + "-scratch", "metrics.csv"
        )
    dump_json(os.path.join(run_dir, "transfer.json"), result)
    plot_curves(
        curves,
        os.path.join(run_dir, "transfer.png"),
        f"transfer on {cfg.env}: + {', '.join(new_names)}",
    )
    log(f"{'':12s}{'Initial':>18s}{'Converge':>18s}")
    log(
        f"{label:12s}{result['initial']['mean']:>11.2f} ± {result['initial']['std']:<5.1f}"
        f"{result['converge']['mean']:>11.2f} ± {result['converge']['std']:<5.1f}"
    )
    if "scratch_converge" in result:
        log(
            f"{'scratch':12s}{'':>18s}{result['scratch_converge']['mean']:>11.2f} "
            f"± {result['scratch_converge']['std']:<5.1f}"
        )
    log(f"wrote {os.path.join(run_dir, 'transfer.json')} and transfer.png")
    return result
