"""The Python driver of a training run: set-up, the off-policy epochs, checkpoints, evaluation.

Everything numeric happens inside the jitted epoch (``run.trainer``); this loop only moves one
small metrics struct to the host per epoch. Reliability:
- a checkpoint (the whole ``TrainState`` + config + space spec) every ``checkpoint_every``
  decisions and at the end; ``--resume RUN_DIR`` continues bit-exactly from the latest one;
- a non-finite loss or parameter stops the run with a message and keeps the last good
  checkpoint (nothing after it is saved).
Algorithms that train inside brax (``Algorithm.train_external``: sac, ppo, hppo) are handed
to ``run.external.fit_external``, which checkpoints their final policy and refuses ``--resume``.
Both loops record their rows through one ``RunRecorder``.

Distributed (``--distributed``): every process runs this same loop on its shards of the seeds;
whatever the loop reads on the host goes through ``run.distributed.to_host`` (one gather per
epoch), and only process 0 writes files and prints.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from score_jax.run import distributed
from score_jax.run.build import Run, build, seed_keys
from score_jax.run.checkpoint import Checkpointer, CheckpointError, checks_for, dump_json
from score_jax.run.config import TrainConfig, TransferSpec, default_run_dir, to_dict
from score_jax.run.external import RESUME_ERROR, fit_external
from score_jax.run.provenance import provenance
from score_jax.run.recorder import NonFiniteError, RunRecorder, step_label
from score_jax.run.summary import announce, resolved_config, tracking_kinds
from score_jax.run.validate import prepare_train

__all__ = ["NonFiniteError", "Run", "train"]

# Columns every off-policy row has, before the algorithm's own metrics.
BASE_COLUMNS = ("updates", "wall_s", "episode_return", "reward_mean", "eval_return")


def _epoch_rows(m, updates) -> list[dict]:
    """One metrics row per seed from an epoch's metrics and update counts (seed-stacked, on the
    host)."""
    rows = []
    for k in range(len(updates)):
        done = float(m.completed_episodes[k])
        row = {
            "updates": int(updates[k]),
            "episode_return": float(m.completed_return_sum[k]) / done if done else math.nan,
            "reward_mean": float(m.reward_mean[k]),
        }
        row.update({name: float(value[k]) for name, value in sorted(m.agent.items())})
        rows.append(row)
    return rows


def _metric_columns(run: Run) -> list[str]:
    """``BASE_COLUMNS`` then the algorithm's own metrics, by name."""
    if run.algo.train_external is not None:
        return [*BASE_COLUMNS, *[n for n in run.algo.metric_names if n not in BASE_COLUMNS]]
    # the jitted epoch on the run's own state: jit keeps this trace, so the first epoch call
    # compiles it without tracing the epoch again
    shapes = jax.eval_shape(run.trainer.epoch, run.state, run.algo.off_policy.hyper)[1]
    return [*BASE_COLUMNS, *sorted(shapes.agent)]


def train(
    cfg: TrainConfig,
    log=print,
    on_epoch: Callable | None = None,
    initial_agent: Callable | None = None,
    transfer: TransferSpec | None = None,
) -> Run:
    """Train (or resume) a run of ``cfg.num_seeds`` seeds; returns the final ``Run``.

    ``initial_agent(run, fresh_agent_state) -> agent_state`` replaces the freshly initialised
    (seed-stacked) algorithm state of a new run (transfer grows it from a trained run, with
    ``transfer`` saying which sub-spaces are new); ``on_epoch(run, row)`` is called after every
    metrics row (one per seed, with its ``seed``).
    """
    log = distributed.primary_only(log)  # distributed: process 0 speaks for the run
    # every check that needs no computation, before any (run.validate); a --resume takes the
    # saved configuration, --total-steps extending it (``record`` goes to config.json)
    cfg, transfer, record = prepare_train(cfg, transfer, log=log)
    run_dir = default_run_dir(cfg)
    announce(cfg, run_dir, log)  # the header, before any heavy set-up
    writes = distributed.is_primary()
    if writes:
        os.makedirs(run_dir, exist_ok=True)

    restoring = bool(cfg.resume) or initial_agent is not None
    run = build(cfg, None, run_dir, restoring=restoring, log=log, transfer=transfer)
    keys_train = seed_keys(run.seeds)[1]
    ckpt = Checkpointer(run_dir)  # (distributed: every process waits for process 0's mkdir)
    external = run.algo.train_external is not None
    if cfg.resume and external:
        raise CheckpointError(RESUME_ERROR.format(algo=cfg.algo, run_dir=run_dir))
    if not cfg.resume and ckpt.latest_step() is not None:
        raise CheckpointError(
            f"{run_dir} already holds a run; pass --resume {run_dir} to continue it or choose "
            "another --run-dir"
        )
    if writes and (not cfg.resume or record is not None):
        dump_json(
            os.path.join(run_dir, "config.json"),
            {
                **to_dict(cfg),
                "resolved": resolved_config(cfg, run.spec, run.env, run.agent_index, transfer),
                "seeds": list(run.seeds),
                "provenance": provenance(),
                "transfer": run.meta()["transfer"],
                **(record or {}),
            },
        )

    if external:
        recorder = _recorder(run, None, log, on_epoch, total=run.spec.total_steps * run.num_seeds)
        return fit_external(run, recorder, ckpt, keys_train, log=log, initial_agent=initial_agent)

    state = run.trainer.init(keys_train, run.frozen)
    if initial_agent is not None and not cfg.resume:
        grown = initial_agent(run, state.agent)
        if run.trainer.shards == "nothing":
            # uncommitted like a fresh state's leaves: the grown agent mixes leaves restored
            # from the source's checkpoint (committed to a device) with fresh ones, and an
            # epoch called with that mix compiles again once its own outputs come back
            grown = jax.tree.map(lambda x: jnp.asarray(jax.device_get(x)), grown)
        state = run.trainer.place(state.replace(agent=grown))
    if cfg.resume:  # the newest usable checkpoint (skipped ones: one warning line)
        check = checks_for(to_dict(cfg), run.env.space)
        state, _ = ckpt.restore_usable(state, check, log=log, set_aside=True)
        state = run.trainer.place(state)
    resume_from = int(np.max(distributed.to_host(state.env_steps))) if cfg.resume else None
    if cfg.resume:
        log(f"resumed {run_dir} at {step_label(resume_from, run.spec.action_repeat)}")
    run.state = state
    recorder = _recorder(run, resume_from, log, on_epoch)
    return _fit_off_policy(run, recorder, ckpt)


def _recorder(
    run: Run, resume_from: int | None, log, on_epoch, total: int | None = None
) -> RunRecorder:
    keep = run.config.keep_best and bool(run.spec.eval_every)
    on_row = None if on_epoch is None else (lambda row: on_epoch(run, row))
    return RunRecorder(
        run.run_dir,
        _metric_columns(run),
        total or run.spec.total_steps,
        run.config.quiet,
        run.meta(),
        keep,
        run.seeds,
        resume_from,
        log,
        on_row,
        track=tracking_kinds(run.config),
        wandb_project=run.config.wandb_project,
        wandb_mode=run.config.wandb_mode,
        wandb_config={**to_dict(run.config), "resolved": run.spec.to_dict()},
        action_repeat=run.spec.action_repeat,
    )


def _fit_off_policy(run: Run, recorder: RunRecorder, ckpt: Checkpointer) -> Run:
    """The off-policy epochs of every seed until ``spec.total_steps`` decisions, with periodic
    evaluations and checkpoints. A seed that goes non-finite stops (``SeedTrainer``) and is
    reported; the run stops when every seed has."""
    spec, cfg = run.spec, run.config
    state = run.state
    meta = run.meta()
    spe, eval_every = spec.steps_per_epoch, spec.eval_every
    alive, env_steps = distributed.to_host((state.alive, state.env_steps))
    steps = int(np.max(env_steps))
    last_ckpt = steps
    hyper = run.algo.off_policy.hyper
    label = lambda decisions: step_label(decisions, spec.action_repeat)
    while steps < spec.total_steps:
        state, metrics = run.trainer.epoch(state, hyper)
        # everything the host reads of this epoch, in one transfer (distributed: one gather)
        now_alive, env_steps, updates, host_metrics = distributed.to_host(
            (state.alive, state.env_steps, state.updates, metrics)
        )
        for k in np.flatnonzero(alive & ~now_alive):
            recorder.progress.write(
                f"seed {run.seeds[k]}: non-finite loss or parameter at {label(steps + spe)}; "
                "this seed stopped (its last finite state is kept), the others go on",
                recorder.log,
            )
        alive = now_alive
        if not alive.any():
            ckpt.close()
            recorder.close()
            which = "every seed" if run.num_seeds > 1 else "the run"
            raise NonFiniteError(
                f"non-finite loss or parameter at {label(steps + spe)} in {which}; stopped. "
                f"The last good checkpoint ({label(last_ckpt)}) is kept in {ckpt.directory}."
            )
        steps = int(np.max(env_steps))
        rows = _epoch_rows(host_metrics, updates)
        if eval_every and steps // eval_every != (steps - spe) // eval_every:
            returns = distributed.to_host(
                run.evaluate(state.agent, n_episodes=cfg.eval_episodes).returns
            )
            for k, row in enumerate(rows):
                row["eval_return"] = float(np.mean(returns[k]))
        run.state = state
        recorder.record(steps, rows, state.agent, live=alive)
        if steps - last_ckpt >= spec.checkpoint_every:
            ckpt.save(steps, state, {**meta, "alive": alive.tolist()})
            last_ckpt = steps
    if last_ckpt != steps:
        ckpt.save(steps, state, {**meta, "alive": alive.tolist()})
    recorder.close()
    ckpt.close()
    if not alive.all():
        stopped = [s for s, ok in zip(run.seeds, alive, strict=True) if not ok]
        recorder.log(f"warning: seeds {stopped} stopped at non-finite values; the others finished")
    return run
