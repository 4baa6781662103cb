"""Seeds as a batch axis: K independent runs in one compiled program (``--num-seeds``).

One run of 3 seeds on the probe is shared by the tests; it is compared with one-seed runs of
the same seeds, resumed from a checkpoint, and poisoned in one seed.
"""

import csv
import dataclasses
import os
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from score_jax.evaluation.report import final_evaluation
from score_jax.evaluation.robustness import run_sweep
from score_jax.run.best_policy import restore_best
from score_jax.run.build import restore_run
from score_jax.run.checkpoint import Checkpointer
from score_jax.run.driver import train
from tests.tiny import tiny_config

pytestmark = pytest.mark.slow  # scheduled first (conftest)

SILENT = lambda *a: None  # noqa: E731
SEEDS = 3
# A vmapped program accumulates its sums in another order than the one-seed program (XLA's CPU
# kernels for batched shapes), so values differ in their last bits (~1e-7 relative per op);
# training amplifies that over its updates; the tolerances leave room for a tiny run's updates.
RTOL_TRAINED, RTOL_ASRL = 2e-3, 1e-5


def _config(run_dir, **overrides):
    base = dict(total_steps=400, checkpoint_every=200, eval_every=200, eval_episodes=4)
    return tiny_config(run_dir, **{**base, **overrides})


@pytest.fixture(scope="module")
def batched(tmp_path_factory):
    return train(_config(tmp_path_factory.mktemp("seeds") / "k3", num_seeds=SEEDS), log=SILENT)


def _rel_error(a, b) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.max(np.abs(a - b)) / (np.max(np.abs(b)) + 1e-8)) if a.size else 0.0


def test_k_seeds_equal_k_one_seed_runs(batched, tmp_path):
    """Seed k of the 3-seed run is the one-seed run of seed k: the same data and replay (exactly),
    the same ASRL and trained parameters within the float tolerance stated above. Checked for
    the last seed only (one one-seed training fewer in CI); a seed other than 0 is where a
    batched run could mix up its seeds' keys."""
    assert batched.seeds == (0, 1, 2) and batched.state.env_steps.tolist() == [400] * SEEDS
    k = SEEDS - 1
    one = train(_config(tmp_path / f"s{k}", seed=k, num_seeds=1), log=SILENT).for_seed(0)
    mine = batched.for_seed(k)
    assert int(mine.state.updates) == int(one.state.updates) > 0
    first = slice(0, 200)  # collected by the uniform policy before any update
    np.testing.assert_array_equal(
        mine.state.buffer.data.obs[first], one.state.buffer.data.obs[first]
    )
    frozen = (mine.state.agent.consts.critic_inputs, one.state.agent.consts.critic_inputs)
    assert (
        max(_rel_error(a, b) for a, b in zip(*map(jax.tree.leaves, frozen), strict=True))
        < RTOL_ASRL
    )
    trained = (mine.state.agent.actor, one.state.agent.actor)
    assert (
        max(_rel_error(a, b) for a, b in zip(*map(jax.tree.leaves, trained), strict=True))
        < RTOL_TRAINED
    )


def test_seeds_are_independent(batched):
    """Different seeds: different ASRL, initial parameters, exploration and evaluations."""
    c = np.asarray(batched.state.agent.consts.critic_inputs.c)
    assert not np.allclose(c[0], c[1])
    rows = list(csv.DictReader(open(os.path.join(batched.run_dir, "metrics.csv"))))
    assert {r["seed"] for r in rows} == {"0", "1", "2"}
    per_seed = {s: [r["episode_return"] for r in rows if r["seed"] == s] for s in ("0", "1", "2")}
    assert len({tuple(v) for v in per_seed.values()}) == SEEDS


def test_resume_is_bit_exact_for_every_seed(batched, tmp_path):
    copy = tmp_path / "resumed"
    shutil.copytree(batched.run_dir, copy)
    shutil.rmtree(copy / "checkpoints" / "400")  # as if killed between the two checkpoints
    assert Checkpointer(str(copy)).latest_step() == 200
    resumed = train(dataclasses.replace(batched.config, resume=str(copy)), log=SILENT)
    for a, b in zip(
        jax.tree.leaves(jax.device_get(resumed.state.agent)),
        jax.tree.leaves(jax.device_get(batched.state.agent)),
        strict=True,
    ):
        np.testing.assert_array_equal(a, b)
    keep = lambda path: [
        {k: v for k, v in r.items() if k != "wall_s"} for r in csv.DictReader(open(path))
    ]
    assert keep(copy / "metrics.csv") == keep(os.path.join(batched.run_dir, "metrics.csv"))


def test_best_policy_and_evaluation_per_seed(batched):
    rows = list(csv.DictReader(open(os.path.join(batched.run_dir, "metrics.csv"))))
    agent, meta = restore_best(batched.run_dir, batched.state.agent)
    for k, seed in enumerate(batched.seeds):
        evals = [
            (int(r["env_steps"]), float(r["eval_return"]))
            for r in rows
            if r["seed"] == str(seed) and r["eval_return"] != "nan"
        ]
        step, value = max(evals, key=lambda x: x[1])
        assert meta["best_steps"][k] == step and meta["best_returns"][k] == pytest.approx(value)
    best = restore_run(batched.run_dir, log=SILENT, policy="best")
    again = np.asarray(best.evaluate(best.state.agent, 4).returns).mean(axis=1)
    np.testing.assert_allclose(again, meta["best_returns"], rtol=1e-5)
    table = final_evaluation(batched, 4, log=SILENT)
    learned = table["score"]
    iqm = learned["over_seeds"]["iqm"]
    assert len(learned["per_seed"]) == SEEDS and iqm["lo"] <= iqm["value"] <= iqm["hi"]
    sweep = run_sweep(batched, 2, log=SILENT)
    assert sweep.returns.shape[-1] == SEEDS * 2  # the trained seeds pooled per cell


def test_a_non_finite_seed_stops_alone_and_is_reported(tmp_path):
    """Seed 1 starts from NaN parameters: it stops at the first epoch (its state kept), the
    other seeds train to the end, and the log says which seed stopped."""
    lines = []

    def poison(run, agent):
        bad = jax.tree.map(
            lambda x: x.at[1].set(jnp.nan) if jnp.issubdtype(x.dtype, jnp.floating) else x,
            agent.actor,
        )
        return agent.replace(actor=bad)

    run = train(
        _config(tmp_path / "nan", num_seeds=SEEDS, eval_every=0),
        log=lines.append,
        initial_agent=poison,
    )
    assert run.state.alive.tolist() == [True, False, True]
    assert run.state.env_steps.tolist() == [400, 0, 400]
    assert any("seed 1: non-finite" in line for line in lines)
    rows = list(csv.DictReader(open(os.path.join(run.run_dir, "metrics.csv"))))
    assert {r["seed"] for r in rows} == {"0", "2"}
