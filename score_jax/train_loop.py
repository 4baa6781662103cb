"""The Python driver of a training run: epochs, progress, metrics.csv, checkpoints, evaluation.

Everything numeric happens inside the jitted epoch (``score_jax.trainer``); this loop only
moves one small metrics struct to the host per epoch. Reliability:
- a checkpoint (the whole ``TrainState`` + config + space spec) every ``checkpoint_every``
  env steps and at the end; ``--resume RUN_DIR`` continues bit-exactly from the latest one;
- a non-finite loss or parameter stops the run with a message and keeps the last good
  checkpoint (nothing after it is saved).
Algorithms that train inside brax (``Algorithm.train_external``: sac, ppo, hppo) are handed
to ``score_jax.external_loop``, which checkpoints their final policy and refuses ``--resume``.
"""

from __future__ import annotations

import csv
import dataclasses
import os
import sys
import time

import jax
import numpy as np

import envs
from score_jax import algorithms
from score_jax.checkpoint import Checkpointer, CheckpointError, check_space_matches, dump_json
from score_jax.best_policy import BestPolicy, has_best, restore_best
from envs.wrappers import with_action_repeat
from score_jax.config import TrainConfig, from_dict, resolved_action_repeat, resolved_eval_every, resolved_total_steps, to_dict
from score_jax.external_loop import ExternalTrainer, train_external
from score_jax.trainer import Trainer, TrainState, make_data_mesh

METRIC_COLUMNS = ("env_steps", "updates", "wall_s", "episode_return", "reward_mean", "critic_loss", "actor_loss", "alpha", "entropy", "q_mean", "eval_return")


class NonFiniteError(RuntimeError):
    """A loss or parameter became NaN/inf; the run stopped at the last good checkpoint."""


@dataclasses.dataclass
class Run:
    """Everything a finished (or resumed) run hands to evaluation, plots and transfer."""

    config: TrainConfig
    run_dir: str
    env: object
    algo: algorithms.Algorithm
    trainer: Trainer
    state: TrainState
    agent_index: np.ndarray


def default_run_dir(cfg: TrainConfig) -> str:
    return cfg.run_dir or os.path.join("runs", f"{cfg.env}-{cfg.algo}-s{cfg.seed}")


def resolve_agent_index(space, names: tuple[str, ...]) -> np.ndarray:
    """Sub-spaces controlled by agents, in the space's order (all when ``names`` is empty)."""
    if not names:
        return np.arange(space.n)
    return np.asarray([space.index(n) for n in space.subset(names).names])


def build(cfg: TrainConfig, key: jax.Array, run_dir: str, restoring: bool = False, log=print) -> Run:
    """Environment, algorithm (incl. SCORE's ASRL stage unless ``restoring``) and trainer."""
    env = envs.make(cfg.env, **cfg.env_overrides())
    env = with_action_repeat(env, resolved_action_repeat(cfg, env))
    agent_index = resolve_agent_index(env.space, cfg.agent_names())
    algo = algorithms.make(cfg, env, agent_index, key, pretrain=not restoring, log=log)
    mesh = make_data_mesh() if cfg.data_parallel and jax.device_count() > 1 else None
    if algo.train_external is not None:  # brax SAC / PPO, H-PPO: their own loop (score_jax.external_loop)
        trainer = ExternalTrainer(algo.off_policy)
    else:
        trainer = Trainer(env, algo.off_policy, cfg.off_policy, agent_index, mesh)
    return Run(cfg, run_dir, env, algo, trainer, None, agent_index)


def _meta(run: Run) -> dict:
    return {
        "env": run.config.env,
        "env_options": run.config.env_overrides(),
        "space": run.env.space.to_dict(),
        "agents": [run.env.space.names[i] for i in run.agent_index],
        "algo": run.config.algo,
        "config": to_dict(run.config),
    }


def _row(state: TrainState, metrics, wall: float, eval_return: float) -> dict:
    m = jax.device_get(metrics)
    done = float(m.completed_episodes)
    agent = m.agent
    get = lambda name: float(getattr(agent, name)) if hasattr(agent, name) else float("nan")
    return {
        "env_steps": int(state.env_steps), "updates": int(state.updates), "wall_s": round(wall, 2),
        "episode_return": float(m.completed_return_sum) / done if done else float("nan"),
        "reward_mean": float(m.reward_mean), "critic_loss": get("critic_loss"), "actor_loss": get("actor_loss"),
        "alpha": get("alpha"), "entropy": get("entropy"), "q_mean": get("q_mean"), "eval_return": eval_return,
    }


def _truncate_csv(path: str, max_env_steps: int) -> None:
    """Keep only rows up to ``max_env_steps`` (on resume, rows after the checkpoint are produced again)."""
    rows = []
    if os.path.exists(path):
        with open(path) as f:
            rows = [r for r in csv.DictReader(f) if int(r["env_steps"]) <= max_env_steps]
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, METRIC_COLUMNS)
        w.writeheader()
        w.writerows(rows)


def train(cfg: TrainConfig, log=print, on_epoch=None, initial_agent=None) -> Run:
    """Train (or resume) a run; returns the final ``Run``.

    ``initial_agent(run, fresh_agent_state) -> agent_state`` replaces the freshly initialised
    algorithm state of a new run (transfer grows it from a trained run); ``on_epoch(run, row)``
    is called after every epoch.
    """
    if cfg.resume:
        meta = Checkpointer(cfg.resume).read_meta()
        saved = from_dict(TrainConfig, meta["config"])
        cfg = dataclasses.replace(saved, resume=cfg.resume, run_dir=cfg.resume, quiet=cfg.quiet)
    run_dir = default_run_dir(cfg)
    os.makedirs(run_dir, exist_ok=True)
    total = resolved_total_steps(cfg)
    key_build, key_train = jax.random.split(jax.random.PRNGKey(cfg.seed))

    run = build(cfg, key_build, run_dir, restoring=bool(cfg.resume) or initial_agent is not None, log=log)
    if run.algo.train_external is not None:
        return train_external(run, total, key_train, log=log, on_epoch=on_epoch, initial_agent=initial_agent)
    state = run.trainer.init(key_train)
    if initial_agent is not None and not cfg.resume:
        state = run.trainer.place(state.replace(agent=initial_agent(run, state.agent)))
    ckpt = Checkpointer(run_dir)
    csv_path = os.path.join(run_dir, "metrics.csv")
    if cfg.resume:
        state, meta = ckpt.restore(state)
        check_space_matches(meta, cfg.env, run.env.space)
        state = run.trainer.place(state)
        _truncate_csv(csv_path, int(state.env_steps))
        log(f"resumed {run_dir} at env step {int(state.env_steps)}")
    else:
        if ckpt.latest_step() is not None:
            raise CheckpointError(f"{run_dir} already holds a run; pass --resume {run_dir} to continue it or choose another --run-dir")
        dump_json(os.path.join(run_dir, "config.json"), to_dict(cfg))
        _truncate_csv(csv_path, -1)
    run.state = state

    steps_per_epoch = cfg.off_policy.num_envs * cfg.off_policy.steps_per_epoch
    ckpt_every = cfg.checkpoint_every or max(steps_per_epoch, (total // 10) // steps_per_epoch * steps_per_epoch)
    eval_every = resolved_eval_every(cfg)
    best = BestPolicy(run_dir, fresh=not cfg.resume) if cfg.keep_best and eval_every else None
    last_ckpt = int(state.env_steps)
    hyper = run.algo.off_policy.hyper
    progress = _progress(total, int(state.env_steps), cfg.quiet)
    recent = []
    t0 = time.time()
    with open(csv_path, "a", newline="") as f:
        writer = csv.DictWriter(f, METRIC_COLUMNS)
        while int(state.env_steps) < total:
            state, metrics = run.trainer.epoch(state, hyper)
            if not bool(metrics.finite):
                ckpt.close()
                raise NonFiniteError(
                    f"non-finite loss or parameter at env step {int(state.env_steps)}; stopped. "
                    f"The last good checkpoint (env step {last_ckpt}) is kept in {ckpt.directory}."
                )
            eval_return = float("nan")
            if eval_every and int(state.env_steps) // eval_every != (int(state.env_steps) - steps_per_epoch) // eval_every:
                eval_return = float(np.mean(run.algo.evaluate(run, state, n_episodes=cfg.eval_episodes).returns))
                if best is not None and best.offer(int(state.env_steps), eval_return, state.agent, _meta(run)):
                    progress.write(f"env step {int(state.env_steps)}: evaluation {eval_return:.1f}, the best so far (saved to {best.ckpt.directory})", log)
                else:
                    progress.write(f"env step {int(state.env_steps)}: evaluation {eval_return:.1f}", log)
            row = _row(state, metrics, time.time() - t0, eval_return)
            writer.writerow(row)
            f.flush()
            if not np.isnan(row["episode_return"]):
                recent = (recent + [row["episode_return"]])[-10:]
            progress.update(steps_per_epoch, recent[-1] if recent else None)
            run.state = state
            if on_epoch is not None:
                on_epoch(run, row)
            if int(state.env_steps) - last_ckpt >= ckpt_every:
                ckpt.save(int(state.env_steps), state, _meta(run))
                last_ckpt = int(state.env_steps)
    if last_ckpt != int(state.env_steps):
        ckpt.save(int(state.env_steps), state, _meta(run))
    progress.close()
    ckpt.close()
    if best is not None:
        best.close()
    return run


class _progress:
    """tqdm progress over env steps with the recent episode return; silent when quiet."""

    def __init__(self, total: int, start: int, quiet: bool):
        self.bar = None
        if not quiet:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=total, initial=start, unit="step", dynamic_ncols=True, file=sys.stderr, mininterval=1.0)

    def update(self, n: int, recent_return: float | None):
        if self.bar is not None:
            if recent_return is not None:
                self.bar.set_postfix_str(f"return {recent_return:.1f}", refresh=False)
            self.bar.update(n)

    def write(self, message: str, log=print):
        """A line above the bar (or through ``log`` when quiet)."""
        if self.bar is not None:
            self.bar.write(message, file=sys.stderr)
        else:
            log(message)

    def close(self):
        if self.bar is not None:
            self.bar.close()


def restore_run(run_dir: str, log=print, policy: str = "last") -> Run:
    """Rebuild a finished run from its latest checkpoint (for evaluation, sweeps and transfer).

    ``policy="best"`` puts the best-evaluated agent state (``score_jax.best_policy``) in place of
    the last one when the run kept one, and says so through ``log``.
    """
    if policy not in ("last", "best"):
        raise ValueError(f"policy must be 'last' or 'best', got {policy!r}")
    ckpt = Checkpointer(run_dir)
    meta = ckpt.read_meta()
    cfg = from_dict(TrainConfig, meta["config"])
    key_build, key_train = jax.random.split(jax.random.PRNGKey(cfg.seed))
    run = build(cfg, key_build, run_dir, restoring=True, log=log)
    state, meta = ckpt.restore(run.trainer.init(key_train))
    check_space_matches(meta, cfg.env, run.env.space)
    ckpt.close()
    if policy == "best" and has_best(run_dir):
        agent, best_meta = restore_best(run_dir, state.agent)
        state = state.replace(agent=agent)
        log(f"using the best policy of {run_dir} (env step {best_meta['step']}, evaluation {best_meta['eval_return']:.1f})")
    run.state = run.trainer.place(state)
    return run


def with_best_policy(run: Run, log=print) -> Run:
    """``run`` with its best-evaluated agent state in place of the last one (unchanged if none)."""
    if not has_best(run.run_dir):
        return run
    agent, meta = restore_best(run.run_dir, run.state.agent)
    log(f"using the best policy (env step {meta['step']}, evaluation {meta['eval_return']:.1f}) from here on")
    return dataclasses.replace(run, state=run.trainer.place(run.state.replace(agent=agent)))
