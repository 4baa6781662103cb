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
    """Stands in for ``trainer.Trainer`` in a ``Run``: builds the checkpoint template from the
    algorithm's ``init`` (for ``restore_run``); there is nothing to shard."""

    def __init__(self, algo):
        self.algo = algo

    def init(self, key: jax.Array) -> ExternalState:
        return ExternalState(_arrays(self.algo.init(key)), jnp.zeros((), jnp.int32))

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
    key: jax.Array,
    log=print,
    initial_agent: Callable | None = None,
):
    """Train ``run`` (built by ``run.build.build``) with ``run.algo.train_external``; returns the
    run.

    ``key`` initialises the parameters brax starts from (brax always starts from them, not its
    own initialisation, so a run's initial parameters are reproducible from the seed);
    ``initial_agent(run, fresh_agent) -> agent`` replaces them (transfer.py warm-starts).
    """
    cfg, total = run.config, run.spec.total_steps
    initial = run.trainer.init(key).agent
    initial = _arrays(initial_agent(run, initial) if initial_agent is not None else initial)
    t0 = time.time()

    def report(env_steps: int, columns: dict, agent: Any = None) -> None:
        """One metrics row; ``agent``: the parameters ``columns["eval_return"]`` evaluated (kept if
        the best)."""
        recorder.record(int(env_steps), columns, None if agent is None else _arrays(agent))

    evaluate = None
    if (
        run.spec.eval_every
    ):  # the project's evaluator: compiled once per run, the parameters an argument
        evaluate = lambda agent: float(np.mean(run.evaluate(agent, cfg.eval_episodes).returns))
    agent = _arrays(run.algo.train_external(total, report, initial, evaluate))
    done = recorder.done
    recorder.close()
    if not _finite(agent):
        ckpt.close()
        raise NonFiniteError(
            f"{cfg.algo} ended with non-finite parameters after {done} env steps; nothing was saved"
        )
    run.state = ExternalState(agent, jnp.asarray(done, jnp.int32))
    ckpt.save(done, run.state, run.meta())
    ckpt.close()
    log(
        f"{cfg.algo}: trained {done} env steps in {time.time() - t0:.1f} s; "
        f"checkpoint in {ckpt.directory}"
    )
    return run
