"""Building a run: the environment, its resolved configuration, the algorithm (with SCORE's ASRL
stage unless restoring) and the trainer that drives it; restoring a finished run."""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import numpy as np

import envs
from envs.base import CompositeEnv
from envs.wrappers import with_action_repeat
from score_jax import registry
from score_jax.agents.base import Algorithm, BuildContext
from score_jax.run.best_policy import has_best, restore_best
from score_jax.run.checkpoint import Checkpointer, CheckpointError, checks_for, saved_run_config
from score_jax.run.config import RunSpec, TrainConfig, TransferSpec, from_dict, resolve, to_dict
from score_jax.run.episodes import EvalResult, make_evaluator
from score_jax.run.external import ExternalTrainer
from score_jax.run.sharding import make_data_mesh
from score_jax.run.trainer import Trainer


@dataclasses.dataclass
class Run:
    """Everything a run (finished, resumed or fresh) hands to evaluation, plots and transfer."""

    config: TrainConfig
    spec: RunSpec
    env: CompositeEnv  # action-repeated
    algo: Algorithm
    trainer: Trainer | ExternalTrainer
    agent_index: np.ndarray
    state: Any = None
    transfer: TransferSpec | None = None
    evaluators: dict = dataclasses.field(default_factory=dict, repr=False)

    @property
    def run_dir(self) -> str:
        return self.spec.run_dir

    def evaluate(self, agent, n_episodes: int, n_failed=0, mode=0, key=None) -> EvalResult:
        """Deterministic-policy episodes of the agent state ``agent`` (one compiled evaluator per
        episode count, the parameters an argument, reused for every later call)."""
        key = jax.random.PRNGKey(self.config.seed + 10_000) if key is None else key
        if n_episodes not in self.evaluators:
            self.evaluators[n_episodes] = make_evaluator(
                self.env, self.algo.policy, self.agent_index, n_episodes
            )
        return self.evaluators[n_episodes](agent, key, n_failed, mode)

    def meta(self) -> dict:
        """What a checkpoint of this run records next to its arrays."""
        return {
            "env": self.config.env,
            "env_options": self.config.env_overrides(),
            "space": self.env.space.to_dict(),
            "agents": [self.env.space.names[i] for i in self.agent_index],
            "algo": self.config.algo,
            "config": to_dict(self.config),
            "resolved": self.spec.to_dict(),
            "transfer": None if self.transfer is None else dataclasses.asdict(self.transfer),
        }


def resolve_agent_index(space, names: tuple[str, ...]) -> np.ndarray:
    """Sub-spaces controlled by agents, in the space's order (all when ``names`` is empty)."""
    if not names:
        return np.arange(space.n)
    return np.asarray([space.index(n) for n in space.subset(names).names])


def trainable_agents(space, agent_index, transfer: TransferSpec | None) -> np.ndarray | None:
    """In a transfer run, ``[n_agents]`` True for the agents whose actors train."""
    if transfer is None:
        return None
    new = set(transfer.new)
    return np.asarray([transfer.finetune_old_actors or space.names[i] in new for i in agent_index])


def build(
    cfg: TrainConfig,
    key: jax.Array,
    run_dir: str | None = None,
    restoring: bool = False,
    log=print,
    transfer: TransferSpec | None = None,
) -> Run:
    """Environment, resolved configuration, algorithm (incl. SCORE's ASRL stage unless
    ``restoring``) and trainer of ``cfg``."""
    raw = envs.make(cfg.env, **cfg.env_overrides())
    spec = resolve(cfg, raw)
    if run_dir is not None:
        spec = dataclasses.replace(spec, run_dir=run_dir)
    env = with_action_repeat(raw, spec.action_repeat)
    agent_index = resolve_agent_index(env.space, cfg.agent_names())
    ctx = BuildContext(
        env=env,
        agent_index=agent_index,
        width=spec.width,
        seed=cfg.seed,
        total_steps=spec.total_steps,
        eval_every=spec.eval_every,
        eval_episodes=cfg.eval_episodes,
        num_envs=cfg.off_policy.num_envs,
        updates_per_step=cfg.off_policy.updates_per_step,
        trainable=trainable_agents(env.space, agent_index, transfer),
        pretrain=not restoring,
        log=log,
    )
    algo = registry.builder(cfg.algo)(cfg.algorithm_settings(), ctx, key)
    mesh = make_data_mesh() if cfg.data_parallel and jax.device_count() > 1 else None
    if algo.train_external is not None:  # brax SAC / PPO, H-PPO: their own loop (run.external)
        trainer = ExternalTrainer(algo.off_policy)
    else:
        schedule = dataclasses.replace(cfg.off_policy, exploration_hold=spec.exploration_hold)
        trainer = Trainer(env, algo.off_policy, schedule, agent_index, mesh)
    return Run(cfg, spec, env, algo, trainer, agent_index, transfer=transfer)


def saved_transfer(meta: dict) -> TransferSpec | None:
    t = meta.get("transfer")
    return (
        None
        if t is None
        else TransferSpec(t["source"], tuple(t["new"]), bool(t["finetune_old_actors"]))
    )


def restore_run(run_dir: str, log=print, policy: str = "last") -> Run:
    """Rebuild a finished run from its latest checkpoint (for evaluation, sweeps and transfer).

    ``policy="best"`` puts the best-evaluated agent state (``run.best_policy``) in place of the
    last one when the run kept one, and says so through ``log``.
    """
    if policy not in ("last", "best"):
        raise ValueError(f"policy must be 'last' or 'best', got {policy!r}")
    ckpt = Checkpointer(run_dir, create=False)  # reads only: "no run in ..." when absent
    config, transfer = saved_run_config(run_dir)
    cfg = from_dict(TrainConfig, config)
    key_build, key_train = jax.random.split(jax.random.PRNGKey(cfg.seed))
    grown = saved_transfer({"transfer": transfer})
    run = build(cfg, key_build, run_dir, restoring=True, log=log, transfer=grown)
    try:  # the newest usable checkpoint (skipped ones: one warning line)
        state, _ = ckpt.restore_usable(
            run.trainer.init(key_train), checks_for(config, run.env.space), log=log
        )
    finally:
        ckpt.close()
    if policy == "best" and has_best(run_dir):
        try:
            agent, best_meta = restore_best(run_dir, state.agent)
        except CheckpointError as e:  # a damaged best policy never stops the run
            log(f"warning: the best policy of {run_dir} is unusable ({e}); using the last one")
        else:
            state = state.replace(agent=agent)
            log(
                f"using the best policy of {run_dir} (env step {best_meta['step']}, "
                f"evaluation {best_meta['eval_return']:.1f})"
            )
    run.state = run.trainer.place(state)
    return run


def with_best_policy(run: Run, log=print) -> Run:
    """``run`` with its best-evaluated agent state in place of the last one (unchanged if none)."""
    if not has_best(run.run_dir):
        return run
    try:
        agent, meta = restore_best(run.run_dir, run.state.agent)
    except CheckpointError as e:  # a damaged best policy never stops the run
        log(f"warning: the best policy is unusable ({e}); keeping the last one")
        return run
    log(
        f"using the best policy (env step {meta['step']}, evaluation {meta['eval_return']:.1f}) "
        "from here on"
    )
    return dataclasses.replace(run, state=run.trainer.place(run.state.replace(agent=agent)))
