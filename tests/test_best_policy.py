"""The best-evaluated policy is kept next to the last one, restored on request, and reported."""

import csv
import os

import jax
import numpy as np
import pytest

from score_jax.evaluation.report import final_evaluation
from score_jax.run.best_policy import BestPolicy, has_best, restore_best
from score_jax.run.build import restore_run
from score_jax.run.driver import train
from tests.tiny import tiny_config

SILENT = lambda *a: None  # noqa: E731


@pytest.fixture(scope="module")
def run_with_evals(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("best") / "run"
    return train(tiny_config(run_dir, eval_every=200, eval_episodes=4), log=SILENT)


def _evaluations(run):
    with open(os.path.join(run.run_dir, "metrics.csv")) as f:
        rows = [r for r in csv.DictReader(f) if r["eval_return"] != "nan"]
    return np.array([int(r["env_steps"]) for r in rows]), np.array(
        [float(r["eval_return"]) for r in rows]
    )


def test_best_is_the_argmax_of_the_periodic_evaluations(run_with_evals):
    steps, returns = _evaluations(run_with_evals)
    assert len(returns) == 5  # 1000 steps, one evaluation every 200
    best = BestPolicy(run_with_evals.run_dir, fresh=False)  # what a resumed run starts from
    assert best.steps[0] == steps[np.argmax(returns)]
    assert best.returns[0] == pytest.approx(returns.max())
    best.close()


def test_restored_best_policy_scores_its_recorded_return(run_with_evals):
    run = restore_run(run_with_evals.run_dir, log=SILENT, policy="best")
    agent, meta = restore_best(run_with_evals.run_dir, run_with_evals.state.agent)
    jax.tree.map(
        np.testing.assert_array_equal,
        jax.device_get(run.state.agent.actor),
        jax.device_get(agent.actor),
    )
    again = float(np.mean(run.evaluate(run.state.agent, n_episodes=4).returns))
    assert again == pytest.approx(meta["best_returns"][0], rel=1e-5)
    last = restore_run(run_with_evals.run_dir, log=SILENT, policy="last")
    jax.tree.map(
        np.testing.assert_array_equal,
        jax.device_get(last.state.agent.actor),
        jax.device_get(run_with_evals.state.agent.actor),
    )
    with pytest.raises(ValueError, match="'last' or 'best'"):
        restore_run(run_with_evals.run_dir, log=SILENT, policy="first")


def test_report_shows_last_and_best(run_with_evals):
    rows = final_evaluation(run_with_evals, 4, log=SILENT)
    step = BestPolicy(run_with_evals.run_dir, fresh=False).steps[0]
    assert set(rows) >= {"score", f"score (best, step {step})", "random", "default"}


def test_a_new_run_does_not_inherit_an_old_best(tmp_path):
    run_dir = tmp_path / "stale"
    stale = BestPolicy(str(run_dir), fresh=True)
    stale.offer(5, 1e9, {"w": np.zeros(3)}, {"note": "left by a crashed run"})
    stale.close()
    assert has_best(str(run_dir))
    fresh = BestPolicy(str(run_dir), fresh=True)
    assert (
        fresh.steps == [None] and fresh.returns[0] == float("-inf") and not has_best(str(run_dir))
    )
    assert not fresh.offer(6, float("nan"), {"w": np.zeros(3)}, {}).any()
    fresh.close()


def test_seeds_trained_one_after_another_keep_their_bests(tmp_path):
    """brax-driven seeds are trained in turn, each evaluating from env step 0 again: the bests
    of seeds evaluated at steps already saved (0, then 0 again) are kept, each in its slot."""
    run_dir = str(tmp_path / "seq")
    best = BestPolicy(run_dir, fresh=True, num_seeds=2)
    nan = float("nan")
    seed0 = lambda v: {"w": np.array([[v], [0.0]])}  # noqa: E731 (seed 1's slot unused)
    seed1 = lambda v: {"w": np.array([[0.0], [v]])}  # noqa: E731
    best.offer(0, [7.0, nan], seed0(7.0), {})
    best.offer(100, [5.0, nan], seed0(5.0), {})  # worse: the last save stays at step 0
    best.offer(0, [nan, 3.0], seed1(3.0), {})  # seed 1's first evaluation, at step 0 again
    best.offer(0, [nan, 2.0], seed1(2.0), {})  # worse: nothing saved
    best.offer(100, [nan, 4.0], seed1(4.0), {})
    best.close()
    agent, meta = restore_best(run_dir, {"w": np.zeros((2, 1))})
    np.testing.assert_array_equal(np.asarray(agent["w"]), [[7.0], [4.0]])
    assert meta["best_steps"] == [0, 100] and meta["best_returns"] == [7.0, 4.0]
