"""benchmarks/q_probe.py: the true action values it computes by rollout are right.

On the probe environment the future is independent of the action (the context is redrawn from
the state's key), so two candidates' true values differ by exactly their immediate scaled
rewards; the probe must reproduce that difference from its rollouts."""

import importlib.util
import os
import sys

import jax
import numpy as np
import pytest

from score_jax.core.spaces import agents_to_env_action
from score_jax.run.build import restore_run
from score_jax.run.driver import train
from tests.tiny import tiny_config

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _q_probe():
    spec = importlib.util.spec_from_file_location(
        "q_probe", os.path.join(ROOT, "benchmarks", "q_probe.py")
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules["q_probe"] = module  # dataclasses resolve string annotations through it
    spec.loader.exec_module(module)
    return module


def test_true_values_differ_by_the_immediate_rewards_where_the_future_is_action_blind(tmp_path):
    run_dir = str(tmp_path / "run")
    train(tiny_config(run_dir, total_steps=400, eval_every=0), log=lambda *a: None)
    qp = _q_probe()
    out = qp.main(qp.Args(run_dir=run_dir, candidates=6, decisions=(0, 4), out=str(tmp_path)))
    rows = out["seeds"][0]["decisions"]
    assert [r["decision"] for r in rows] == [0, 4]
    assert os.path.exists(tmp_path / "q_probe_run.md")

    run = restore_run(run_dir, log=lambda *a: None)
    one, env, idx = run.for_seed(0), run.env, np.asarray(run.agent_index)
    scale = float(run.algo.off_policy.hyper.reward_scale)
    key = jax.random.PRNGKey(0)
    s0 = jax.vmap(env.reset)(key[None])
    a_pol = run.algo.policy(one.state.agent)(s0, key)
    a_def = agents_to_env_action(env.space, env.space.default_action()[idx][None], idx)
    r_pol = jax.vmap(env.step)(s0, agents_to_env_action(env.space, a_pol, idx)).reward[0]
    r_def = jax.vmap(env.step)(s0, a_def).reward[0]
    first = rows[0]
    assert first["true"]["policy"] - first["true"]["default"] == pytest.approx(
        scale * float(r_pol - r_def), abs=1e-5
    )
    for r in rows:
        assert -1.0 <= r["spearman"] <= 1.0 and r["true_std"] > 0.0 and r["critic_std"] > 0.0
        assert np.isfinite(list(r["critic"].values())).all()
