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
