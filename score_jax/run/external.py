"""The driver of algorithms that run their own training loop (brax SAC / PPO, H-PPO).

``run.driver.train`` hands such a run (``Algorithm.train_external`` is set) to ``fit_external``,
which gives it what every run has: ``config.json`` and ``metrics.csv`` (one row per brax epoch,
through brax's ``progress_fn``), the best-evaluated policy when the algorithm hands its
evaluated parameters over (``run.recorder``), a progress bar, and an orbax checkpoint of the
final policy parameters + meta, as an ``ExternalState`` whose ``agent`` is what
``Algorithm.policy`` reads, so ``restore_run``, the final evaluation, the robustness sweep and
``transfer.py`` treat the run like any other.

Exact resume is impossible: brax keeps its optimiser states, replay buffer, environment states
and PRNG inside ``train()`` and returns only the policy, so ``--resume`` on such a run is an
error that says so. ``transfer.py --checkpoint RUN`` warm-starts a new run from the policy.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from score_jax.run.checkpoint import Checkpointer
from score_jax.run.recorder import NonFiniteError, RunRecorder

RESUME_ERROR = (
    "--resume: {algo} trains inside brax.training, which keeps its optimiser states, replay "
    "buffer, environment states and PRNG to itself and returns only the final policy, so the run "
    "cannot be continued exactly. Its checkpoint holds that policy: evaluate it (score-eval "
    "--run-dir {run_dir}, score-robustness --run-dir {run_dir}), fine-tune it on more sub-spaces "
    "(score-transfer --checkpoint {run_dir}), or start a new run with a larger --total-steps."
)


@struct.dataclass
class ExternalState:
    """What an externally trained run saves: ``agent`` (read by ``Algorithm.policy``) and its env
    steps."""

    agent: Any
    env_steps: jax.Array  # [] int32


class ExternalTrainer:
    """Stands in for the off-policy trainer in a ``Run``: builds the checkpoint template from the
    algorithm's ``init`` (for ``restore_run``), seed-stacked unless it is a one-seed view's
    (``single``); there is nothing to shard."""

    def __init__(self, algo, batched: bool = True):
        self.algo, self.batched = algo, batched

    @property
    def single(self) -> ExternalTrainer:
        return ExternalTrainer(self.algo, batched=False)

    def init(self, keys: jax.Array, frozen=None) -> ExternalState:
        if not self.batched:
            return ExternalState(_arrays(self.algo.init(keys)), jnp.zeros((), jnp.int32))
        agent = jax.vmap(self.algo.init)(keys)
        return ExternalState(_arrays(agent), jnp.zeros(keys.shape[0], jnp.int32))

    def place(self, state: ExternalState) -> ExternalState:
        return state


def _arrays(tree):
    return jax.tree.map(jnp.asarray, tree)


def _finite(tree) -> bool:
    return all(
        bool(np.all(np.isfinite(x)))
        for x in jax.tree.leaves(tree)
        if np.issubdtype(np.asarray(x).dtype, np.floating)
    )


def fit_external(
    run,
    recorder: RunRecorder,
    ckpt: Checkpointer,
    keys: jax.Array,
    log=print,
    initial_agent: Callable | None = None,
):
    """Train ``run`` (built by ``run.build.build``) with ``run.algo.train_external``, its seeds one
    after another (brax's ``train()`` cannot be vmapped); returns the run.

    ``keys [K, 2]`` initialise the parameters brax starts from (brax always starts from them,
    not its own initialisation, so a run's initial parameters are reproducible from the seed);
    ``initial_agent(run, fresh_agents) -> agents`` (seed-stacked) replaces them (transfer.py
    warm-starts).
    """
    cfg, total, k_seeds = run.config, run.spec.total_steps, run.num_seeds
    initial = run.trainer.init(keys).agent
    initial = _arrays(initial_agent(run, initial) if initial_agent is not None else initial)
    t0 = time.time()
    agents, done = [], []
    for k, seed in enumerate(run.seeds):
        live = [i == k for i in range(k_seeds)]

        def report(env_steps: int, columns: dict, agent: Any = None, k=k, live=live) -> None:
            """One metrics row of seed ``k``; ``agent``: the parameters its ``eval_return``
            evaluated (kept if that seed's best)."""
            rows = [columns if i == k else {} for i in range(k_seeds)]
            stacked = None
            if agent is not None:
                stacked = jax.tree.map(
                    lambda x: jnp.broadcast_to(x, (k_seeds, *jnp.shape(x))), _arrays(agent)
                )
            recorder.record(
                int(env_steps), rows, stacked, live=live, progress_at=k * total + int(env_steps)
            )

        evaluate = None
        if (
            run.spec.eval_every
        ):  # the project's evaluator: compiled once, the parameters an argument
            evaluate = lambda agent, seed=seed: float(
                np.mean(run.evaluate_one(agent, cfg.eval_episodes, seed).returns)
            )
        init_k = jax.tree.map(lambda x, k=k: x[k], initial)
        agent = _arrays(run.algo.train_external(total, report, init_k, evaluate, seed))
        if not _finite(agent):
            recorder.close()
            ckpt.close()
            raise NonFiniteError(
                f"{cfg.algo} seed {seed} ended with non-finite parameters; nothing was saved"
            )
        agents.append(agent)
        done.append(recorder.last_step)
    recorder.close()
    stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *agents)
    run.state = ExternalState(stacked, jnp.asarray(done, jnp.int32))
    ckpt.save(max(done), run.state, run.meta())
    ckpt.close()
    log(
        f"{cfg.algo}: trained {k_seeds} seed(s) x {max(done)} env steps in "
        f"{time.time() - t0:.1f} s; checkpoint in {ckpt.directory}"
    )
    return run
