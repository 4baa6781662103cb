"""Building a run: the environment, its resolved configuration, the algorithm (with SCORE's ASRL
stage unless restoring) and the trainer that drives it; restoring a finished run."""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import envs
from envs.base import CompositeEnv
from envs.wrappers import with_action_repeat
from score_jax import registry
from score_jax.agents.base import Algorithm, BuildContext
from score_jax.run.best_policy import has_best, pick_seeds, restore_best
from score_jax.run.checkpoint import Checkpointer, CheckpointError, checks_for, saved_run_config
from score_jax.run.config import (
    RunSpec,
    TrainConfig,
    TransferSpec,
    from_saved,
    prior_agents,
    resolve,
    to_dict,
)
from score_jax.run.episodes import EvalResult, make_evaluator
from score_jax.run.external import ExternalTrainer
from score_jax.run.provenance import provenance
from score_jax.run.sharding import make_data_mesh
from score_jax.run.trainer import SeedTrainer, Trainer


def seed_keys(seeds) -> tuple[jax.Array, jax.Array]:
    """``(build keys [K, 2], train keys [K, 2])`` of the seeds: seed ``s`` splits
    ``PRNGKey(s)`` into its build key (ASRL, networks) and train key (init, exploration, replay),
    exactly as a one-seed run of seed ``s`` does."""
    keys = jnp.stack([jax.random.split(jax.random.PRNGKey(int(s))) for s in seeds])
    return keys[:, 0], keys[:, 1]


def _seed_of(x: Any, k: int) -> Any:
    """Row ``k`` of a seed-stacked leaf, on one device and uncommitted (like a fresh state's
    leaves), read from the local shard that holds it.

    Indexing an array sharded over the seed mesh gives a result replicated over every device,
    so each later program on a one-seed view (an evaluation, a season plot) would run on all
    of them, doubling the work on a 2-core host, and wait in a cross-device rendezvous that
    XLA's CPU client aborts after 40 s when a device's thread is held up (seen drawing
    ``benchmarks/paper.py``'s Fig. 10)."""
    if isinstance(x, jax.Array) and len(x.sharding.device_set) > 1:
        for shard in x.addressable_shards:
            rows = shard.index[0] if shard.index else slice(None)
            start, stop, _ = rows.indices(x.shape[0])
            if start <= k < stop:
                return jnp.asarray(np.asarray(shard.data)[k - start])
    return x[k]


@dataclasses.dataclass
class Run:
    """Everything a run (finished, resumed or fresh) hands to evaluation, plots and transfer.

    A run trains ``len(seeds)`` independent seeds at once: every leaf of ``state`` has a leading
    seed axis (``batched``). ``for_seed(k)`` is the one-seed view of seed ``k`` (no seed axis),
    for code that works on one run.
    """

    config: TrainConfig
    spec: RunSpec
    env: CompositeEnv  # action-repeated
    algo: Algorithm
    trainer: SeedTrainer | Trainer | ExternalTrainer
    agent_index: np.ndarray
    seeds: tuple[int, ...] = (0,)
    state: Any = None
    transfer: TransferSpec | None = None
    frozen: Any = None  # the seeds' Algorithm.pretrain output (None: none, or restored)
    batched: bool = True
    evaluators: dict = dataclasses.field(default_factory=dict, repr=False)

    @property
    def run_dir(self) -> str:
        return self.spec.run_dir

    @property
    def num_seeds(self) -> int:
        return len(self.seeds)

    def eval_keys(self, offset: int = 10_000) -> jax.Array:
        """One evaluation key per seed (``PRNGKey(seed + offset)``); one key for a one-seed
        view."""
        keys = jnp.stack([jax.random.PRNGKey(s + offset) for s in self.seeds])
        return keys if self.batched else keys[0]

    def evaluate(self, agent, n_episodes: int, n_failed=0, mode=0, key=None) -> EvalResult:
        """Deterministic-policy episodes of the agent state ``agent`` (seed-stacked when
        ``batched``: returns ``[K, E]``); one compiled evaluator per episode count, the
        parameters an argument, reused for every later call. ``key``: one per seed."""
        key = self.eval_keys() if key is None else key
        if n_episodes not in self.evaluators:
            self.evaluators[n_episodes] = make_evaluator(
                self.env, self.algo.policy, self.agent_index, n_episodes, seeds=self.batched
            )
        return self.evaluators[n_episodes](agent, key, n_failed, mode)

    def evaluate_one(self, agent, n_episodes: int, seed: int, n_failed=0, mode=0) -> EvalResult:
        """``evaluate`` of ONE seed's (unstacked) agent state, with that seed's evaluation key."""
        slot = ("one", n_episodes)
        if slot not in self.evaluators:
            self.evaluators[slot] = make_evaluator(
                self.env, self.algo.policy, self.agent_index, n_episodes
            )
        return self.evaluators[slot](agent, jax.random.PRNGKey(seed + 10_000), n_failed, mode)

    def for_seed(self, k: int) -> Run:
        """The one-seed view of seed ``seeds[k]``: its state without the seed axis."""
        if not self.batched:
            raise ValueError("for_seed: this is already a one-seed view")
        pick = lambda tree: None if tree is None else jax.tree.map(lambda x: _seed_of(x, k), tree)
        return dataclasses.replace(
            self,
            trainer=self.trainer.single,
            seeds=(self.seeds[k],),
            state=pick(self.state),
            frozen=pick(self.frozen),
            batched=False,
            evaluators={},
        )

    def meta(self) -> dict:
        """What a checkpoint of this run records next to its arrays."""
        return {
            "env": self.config.env,
            "env_options": self.config.env_overrides(),
            "space": self.env.space.to_dict(),
            "agents": [self.env.space.names[i] for i in self.agent_index],
            "algo": self.config.algo,
            "seeds": list(self.seeds),
            "config": to_dict(self.config),
            "resolved": self.spec.to_dict(),
            "transfer": None if self.transfer is None else dataclasses.asdict(self.transfer),
            "provenance": provenance(),
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
    key: jax.Array | None = None,
    run_dir: str | None = None,
    restoring: bool = False,
    log=print,
    transfer: TransferSpec | None = None,
) -> Run:
    """Environment, resolved configuration, algorithm and trainer of ``cfg``, and (unless
    ``restoring``) the algorithm's pretraining for every seed (SCORE's ASRL, in one program).

    ``key``: the build key of a one-seed run (default: the seed's own, as ``seed_keys``); a
    run of ``cfg.num_seeds`` seeds always uses ``seed_keys``.
    """
    raw = envs.make(cfg.env, **cfg.env_overrides())
    spec = resolve(cfg, raw)
    if run_dir is not None:
        spec = dataclasses.replace(spec, run_dir=run_dir)
    env = with_action_repeat(raw, spec.action_repeat)
    agent_index = resolve_agent_index(env.space, cfg.agent_names())
    seeds = tuple(cfg.seed + k for k in range(cfg.num_seeds))
    keys_build = seed_keys(seeds)[0]
    if key is not None and cfg.num_seeds == 1:
        keys_build = jnp.asarray(key)[None]
    ctx = BuildContext(
        env=env,
        agent_index=agent_index,
        width=spec.width,
        seed=cfg.seed,
        total_steps=spec.total_steps,
        eval_every=spec.eval_every,
        eval_episodes=cfg.eval_episodes,
        num_envs=cfg.off_policy.num_envs,
        updates_per_step=spec.updates_per_step,
        trainable=trainable_agents(env.space, agent_index, transfer),
        finetune_encoder=transfer is not None and transfer.finetune_critic_encoder,
        prior=prior_agents(cfg, [env.space.names[i] for i in agent_index], transfer),
        transfer_variant=cfg.single.transfer_variant,
        penalty_coef=cfg.single.penalty_coef,
        log=log,
    )
    algo = registry.builder(cfg.algo)(cfg.algorithm_settings(), ctx)
    frozen = None
    if not restoring and algo.pretrain is not None:
        frozen = algo.pretrain(keys_build)
    mesh = make_data_mesh() if cfg.data_parallel and jax.device_count() > 1 else None
    if algo.train_external is not None:  # brax SAC / PPO, H-PPO: their own loop (run.external)
        trainer = ExternalTrainer(algo.off_policy)
    else:
        schedule = dataclasses.replace(
            cfg.off_policy,
            exploration_hold=spec.exploration_hold,
            updates_per_step=spec.updates_per_step,
            n_step=spec.n_step,
        )
        # Seeds over the devices when they divide evenly (whole runs per device), else each
        # seed's environments and batches (see SeedTrainer).
        by_seed = mesh is not None and cfg.num_seeds % mesh.size == 0
        single = Trainer(env, algo.off_policy, schedule, agent_index, None if by_seed else mesh)
        trainer = SeedTrainer(single, cfg.num_seeds, mesh if by_seed else None)
    return Run(cfg, spec, env, algo, trainer, agent_index, seeds, transfer=transfer, frozen=frozen)


def saved_transfer(meta: dict) -> TransferSpec | None:
    t = meta.get("transfer")
    return None if t is None else TransferSpec.from_dict(t)


def restore_run(run_dir: str, log=print, policy: str = "last") -> Run:
    """Rebuild a finished run from its latest checkpoint (for evaluation, sweeps and transfer).

    ``policy="best"`` puts each seed's best-evaluated agent state (``run.best_policy``) in place
    of its last one when the run kept one, and says so through ``log``.
    """
    if policy not in ("last", "best"):
        raise ValueError(f"policy must be 'last' or 'best', got {policy!r}")
    ckpt = Checkpointer(run_dir, create=False)  # reads only: "no run in ..." when absent
    config, transfer = saved_run_config(run_dir)
    cfg = from_saved(config)
    grown = saved_transfer({"transfer": transfer})
    run = build(cfg, None, run_dir, restoring=True, log=log, transfer=grown)
    try:  # the newest usable checkpoint (skipped ones: one warning line)
        state, _ = ckpt.restore_usable(
            run.trainer.init(seed_keys(run.seeds)[1]), checks_for(config, run.env.space), log=log
        )
    finally:
        ckpt.close()
    run.state = run.trainer.place(state)
    return with_best_policy(run, log) if policy == "best" else run


def with_best_policy(run: Run, log=print) -> Run:
    """``run`` with each seed's best-evaluated agent state in place of its last one (seeds
    without a best keep theirs; unchanged if the run kept none)."""
    if not has_best(run.run_dir):
        return run
    try:
        best, meta = restore_best(run.run_dir, run.state.agent)
    except CheckpointError as e:  # a damaged best policy never stops the run
        log(f"warning: the best policy of {run.run_dir} is unusable ({e}); keeping the last one")
        return run
    found = np.asarray([s is not None for s in meta["best_steps"]])
    agent = pick_seeds(jnp.asarray(found), best, run.state.agent)
    described = ", ".join(
        f"seed {s}: step {st}, evaluation {r:.1f}"
        for s, st, r, f in zip(
            run.seeds, meta["best_steps"], meta["best_returns"], found, strict=True
        )
        if f
    )
    log(f"using the best policies of {run.run_dir} ({described}) from here on")
    return dataclasses.replace(
        run, state=run.trainer.place(run.state.replace(agent=agent)), evaluators=run.evaluators
    )
