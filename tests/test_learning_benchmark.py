"""benchmarks/learning.py: the greenhouse part end to end at a tiny budget (references, SCORE over
2 seeds, targets, JSON / markdown / figure, the cached re-run); the run plans of both parts at
their full budgets (nothing trained); the targets' verdicts; the forward-speed measurement and
the Spider gait's act function (the Spider's training is too expensive for a test)."""

import dataclasses
import json
import math
import os
import time
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from benchmarks import compare, learning
from envs.base import CompositeEnv, EnvState
from envs.wrappers import ActionRepeat
from score_jax.core.spaces import CompositeSpace, SubSpace
from score_jax.run.config import TrainConfig
from tests.tiny import TINY_OFF_POLICY, TINY_SCORE

pytestmark = pytest.mark.slow  # scheduled first (conftest)

DECISIONS = 400  # per seed, decisions held 8 days: two epochs of TINY_OFF_POLICY
DAYS = 8 * DECISIONS
# The pipeline, not SCORE's representation stage: without ASRL a run skips its pretraining
# (about a minute of tracing the greenhouse per run on 2 CPU cores); ASRL has its own tests.
NO_ASRL = dataclasses.replace(TINY_SCORE, critic=dataclasses.replace(TINY_SCORE.critic, asrl=False))


def _tiny_args(tmp_path) -> learning.LearningArgs:
    return learning.LearningArgs(
        envs=("greenhouse",),
        seeds=2,
        env_steps=DAYS,
        daily=False,  # its plan is checked below; training it too would double the test's time
        planned_references=False,
        gif=False,
        eval_points=2,
        eval_episodes=2,
        out=str(tmp_path / "out"),
        work_dir=str(tmp_path / "work"),
        base=TrainConfig(
            quiet=True,
            robustness_seeds=0,
            checkpoint_every=DECISIONS,
            off_policy=TINY_OFF_POLICY,
            score=NO_ASRL,
        ),
    )


def _finite(values) -> bool:
    return len(values) > 0 and all(math.isfinite(v) for v in values)


def test_greenhouse_targets_tables_figure_and_cached_rerun(tmp_path):
    args = _tiny_args(tmp_path)
    t0 = time.time()
    assert learning.main(args) == 0
    first_s = time.time() - t0
    out = tmp_path / "out"
    data = json.load(open(out / "learning_greenhouse.json"))
    assert data["errors"] == {}
    assert data["env_steps"] == DAYS and data["seeds"] == 2

    # the references of the run's decision interval (no planned ones: skipped), on the README's
    # reference table (Greensboro, cumulative reward, decisions held 8 days)
    refs = data["references"]
    assert set(refs) == {"8-day"}
    r8 = refs["8-day"]
    assert set(r8) == {"random", "default", "expert"}
    assert r8["default"]["mean"] == pytest.approx(818.3, abs=0.1)
    assert r8["expert"]["mean"] == pytest.approx(1003.8, abs=0.1)
    assert r8["default"]["std"] == pytest.approx(0.0, abs=1e-3)  # deterministic seasons
    assert r8["random"]["std"] > 0  # two different random seasons

    assert set(data["runs"]) == {"8-day"}
    run = data["runs"]["8-day"]
    assert (run["action_repeat"], run["decisions"], run["env_steps"]) == (8, DECISIONS, DAYS)
    assert run["seeds"] == [0, 1] and run["num_envs"] == TINY_OFF_POLICY.num_envs
    final, best = run["final"]["per_seed"], run["best"]["per_seed"]
    assert len(final) == len(best) == 2 and _finite(final) and _finite(best)
    # the last periodic evaluation is of the final policy, on the same episodes: best >= final
    assert all(b >= f - 1e-3 for b, f in zip(best, final, strict=True)), (best, final)
    assert all(s in (DAYS // 2, DAYS) for s in run["best_env_steps"])
    iqm = run["final"]["iqm"]
    assert iqm["lo"] <= iqm["value"] <= iqm["hi"]
    assert run["final"]["mean"] == pytest.approx(np.mean(final))
    # curves in simulated days (decisions x 8), not decisions; the final point is the final policy
    for curve, value in zip(run["curves"], final, strict=True):
        assert curve["env_steps"] == [DAYS // 2, DAYS]
        assert curve["returns"][-1] == pytest.approx(value, abs=1e-3)
    assert 0 < run["wall_s"] < first_s
    stability = run["stability"]  # seasons of 20 decisions: training returns were logged
    assert stability["threshold"] == r8["default"]["mean"]
    assert set(stability["per_seed"]) == {"0", "1"}
    for s in stability["per_seed"].values():
        assert isinstance(s["held"], bool)
        assert s["first_above"] is None or 0 < s["first_above"] <= DAYS
    assert "share_of_open_loop" not in run  # no open-loop reference was evaluated

    targets = {t["target"].split(" (")[0]: t for t in data["targets"]}
    assert len(targets) == 4
    assert targets["every seed's final policy above the expert"]["met"] is (
        min(final) > r8["expert"]["mean"]
    )
    assert targets["IQM of the final policies >= the best constant schedule"]["met"] is None
    assert targets["every seed held"]["met"] is all(
        s["held"] for s in stability["per_seed"].values()
    )
    assert targets["2-seed run within 20 minutes"]["met"] is (run["wall_s"] <= 1200)
    assert data["commit"] and data["machine"] and data["date_utc"]
    assert data["command"].startswith("benchmarks.learning.main(") and "seeds=2" in data["command"]

    md = (out / "learning_greenhouse.md").read_text()
    for text in ("## Targets", "not measured", "## Per seed", "## References", "## Provenance"):
        assert text in md, text
    for value in (*final, *best, r8["expert"]["mean"], r8["default"]["mean"]):
        assert f"{value:.1f}" in md
    assert "![learning curves](learning_greenhouse.png)" in md
    assert os.path.getsize(out / "learning_greenhouse.png") > 20_000

    # a second invocation trains nothing: the run's result.json is reused, same numbers
    results = list((tmp_path / "work").rglob("result.json"))
    assert len(results) == 1
    stamp = results[0].stat().st_mtime
    t1 = time.time()
    assert learning.main(args) == 0
    second_s = time.time() - t1
    assert results[0].stat().st_mtime == stamp
    again = json.load(open(out / "learning_greenhouse.json"))
    assert again["runs"]["8-day"]["final"] == run["final"]
    assert again["runs"]["8-day"]["best"] == run["best"]
    assert again["targets"] == data["targets"]
    assert second_s < first_s / 2, (first_s, second_s)


def test_plans_at_full_budget(tmp_path):
    """Nothing trained: the runs the default invocation would train."""
    args = learning.LearningArgs(work_dir=str(tmp_path))
    assert learning.greenhouse_budget(args) == 1_152_000  # the main job: 144k decisions x 8 days
    plans = learning.greenhouse_configs(args)
    main, daily = plans["8-day"], plans["daily"]
    assert (main.env, main.algo, main.num_seeds, main.seed) == ("greenhouse", "score", 5, 0)
    assert compare.action_repeat(main) == 8 and main.total_steps == 144_000
    assert main.off_policy == TrainConfig().off_policy and main.score == TrainConfig().score
    assert main.eval_every == 16_000  # the main job's evaluations
    assert compare.action_repeat(daily) == 1 and daily.total_steps == 1_152_000
    assert daily.eval_every == 128_000  # as many simulated days apart
    assert (daily.off_policy.num_envs, daily.off_policy.replay_capacity) == (64, 400_000)
    # as many vectorised steps (and gradient updates) as the 8-day run
    assert daily.total_steps // 64 == main.total_steps // main.off_policy.num_envs
    assert main.run_dir != daily.run_dir and main.run_dir.endswith("s0-4")
    assert not main.planned_references and main.robustness_seeds == 0
    # a second draw of the same settings: seeds 6..10 in their own run directories
    later = learning.greenhouse_configs(dataclasses.replace(args, first_seed=6))
    assert [(c.seed, c.num_seeds) for c in later.values()] == [(6, 5), (6, 5)]
    assert later["8-day"].run_dir == main.run_dir[: -len("s0-4")] + "s6-10"
    assert dataclasses.replace(later["8-day"], seed=0, run_dir=main.run_dir) == main
    assert learning.spider_configs(dataclasses.replace(args, first_seed=6))["score"].seed == 0

    spider = learning.spider_configs(args)
    assert set(spider) == {"score", "sac"}
    for algo, cfg in spider.items():
        assert (cfg.env, cfg.algo, cfg.num_seeds) == ("spider", algo, 3)
        assert cfg.total_steps == 500_000 and cfg.eval_every == 20_000

    quick = learning.resolved(dataclasses.replace(args, quick=True))
    assert (quick.seeds, quick.spider_seeds, quick.eval_episodes) == (2, 2, 2)
    assert learning.greenhouse_budget(quick) == 16_000
    assert quick.base.score.asrl_steps == 300
    q = learning.greenhouse_configs(quick)
    assert (q["8-day"].total_steps, q["daily"].total_steps) == (2_000, 16_000)
    assert q["8-day"].eval_every == 500 and q["daily"].eval_every == 4_000

    committed = dataclasses.replace(args, out=learning.COMMITTED_OUT)
    assert learning.gif_destination(committed) == learning.COMMITTED_GIF
    assert learning.gif_destination(args) == os.path.join(args.out, learning.GIF_NAME)


def test_no_main_trains_only_the_daily_run(tmp_path, monkeypatch):
    """``--no-main``: both intervals' references, only the daily run trained (nothing trained
    here: the training and reference calls are recorded); with ``--no-daily`` too it is an
    error before anything starts."""
    args = dataclasses.replace(_tiny_args(tmp_path), daily=True, main=False)
    trained, evaluated = [], []
    ref = {"default": {"mean": 818.3, "std": 0.0}}
    monkeypatch.setattr(
        learning, "references", lambda cfg, *a: evaluated.append(cfg.action_repeat) or ref
    )
    monkeypatch.setattr(learning, "_train", lambda steps, label, cfg, errors: trained.append(cfg))
    out = learning.greenhouse(args)
    assert [compare.action_repeat(c) for c in trained] == [1]
    assert evaluated == [None, 1] and set(out["references"]) == {"8-day", "daily"}
    assert out["runs"] == {} and out["errors"] == {}
    with pytest.raises(SystemExit, match="no greenhouse run"):
        learning.main(dataclasses.replace(args, daily=False))


def test_seed_offset_is_refused_by_every_script_that_builds_rows(tmp_path):
    """Rows train seeds 0..K-1, so ``--base.seed 6`` is an error before anything starts in
    learning.py, compare.py and paper.py (it used to retrain seeds 0..K-1 silently); learning.py
    names its own option for a later draw, and refuses a negative one."""
    from benchmarks import paper

    args = _tiny_args(tmp_path)
    base = dataclasses.replace(args.base, seed=6)
    mains = [
        lambda: learning.main(dataclasses.replace(args, base=base)),
        lambda: compare.main(compare.CompareArgs(base=base, out=str(tmp_path / "c"))),
        lambda: paper.main(paper.PaperArgs(base=base, out=str(tmp_path / "p"))),
    ]
    for run_main in mains:
        with pytest.raises(SystemExit, match="--base.seed 6 is not used"):
            run_main()
    with pytest.raises(SystemExit, match="--base.seed 6 is not used.*--first-seed S"):
        mains[0]()
    with pytest.raises(SystemExit, match="--first-seed must be >= 0"):
        learning.main(dataclasses.replace(args, first_seed=-1))
    assert not os.listdir(tmp_path)  # refused before any output or run directory


def test_figure_has_a_panel_per_trained_interval(tmp_path):
    """A ``--no-main`` run's figure has the daily panel only (no empty 8-day axes); with no run
    at all (every run failed) both intervals' references are still drawn."""
    import matplotlib.image

    refs = {"default": {"mean": 818.3}}
    curve = {"seed": 0, "env_steps": [1000, 2000], "returns": [800.0, 900.0]}
    out = {
        "env": "greenhouse",
        "references": {"8-day": refs, "daily": refs},
        "action_repeats": {"8-day": 8, "daily": 1},
        "runs": {"daily": {"curves": [curve]}},
    }
    widths = []
    for runs in ({"daily": {"curves": [curve]}}, {}):
        learning.plot({**out, "runs": runs}, str(tmp_path / "f.png"))
        widths.append(matplotlib.image.imread(tmp_path / "f.png").shape[1])
    assert widths[1] == 2 * widths[0]


def _summary(values):
    return compare._summary(values)


def test_targets_verdicts():
    refs = {
        "8-day": {
            "default": {"mean": 818.3},
            "expert": {"mean": 1003.8},
            "best constant": {"mean": 1284.4},
        },
        "daily": {"default": {"mean": 818.3}},
    }
    held = {  # seed 2 collapsed after beating the default setpoints, seed 3 never beat them
        "0": {"held": True, "first_above": 1e5},
        "1": {"held": True, "first_above": 2e5},
        "2": {"held": False, "first_above": 3e5},
        "3": {"held": False, "first_above": None},
    }
    runs = {
        "8-day": {
            "final": _summary([1010.0, 1300.0, 1290.0, 1295.0]),  # IQM 1292.5
            "stability": {"per_seed": held},
            "wall_s": 1300.0,
        },
        "daily": {"final": _summary([800.0, 820.0, 810.0, 790.0])},
    }
    targets = learning.greenhouse_targets(refs, runs, 4)
    got = {t["target"].split(" (")[0]: t["met"] for t in targets}
    assert "2 of 4 held, 1 fell below" in targets[2]["value"]
    assert "1 never beat them" in targets[2]["value"]
    assert got == {
        "every seed's final policy above the expert": True,
        "IQM of the final policies >= the best constant schedule": True,
        "every seed held": False,
        "4-seed run within 20 minutes": False,
        "daily decisions: IQM of the final policies above the default setpoints": False,
    }

    spider_refs = {"gait": {"mean": 950.0}}
    spider_runs = {
        "score": {"final": _summary([2100.0, 2500.0, 1900.0])},
        "sac": {"final": _summary([1000.0, 1200.0, 900.0])},
    }
    targets = learning.spider_targets(spider_refs, spider_runs)
    assert [t["met"] for t in targets] == [True, True, True]
    assert targets[1]["p_score_better"]["value"] == pytest.approx(1.0)
    spider_runs["sac"] = {"final": _summary([2600.0, 3000.0, 2800.0])}
    assert [t["met"] for t in learning.spider_targets(spider_refs, spider_runs)] == [
        True,
        False,
        True,
    ]
    del spider_runs["sac"]
    assert [t["met"] for t in learning.spider_targets(spider_refs, spider_runs)] == [
        True,
        None,
        True,
    ]


@struct.dataclass
class _Metrics:
    x_position: jax.Array


class _Walker(CompositeEnv):
    """Moves along x at the speed its one action asks for (m/s); falls (ends) past ``fall_at``."""

    name = "walker"
    observation_size = 1
    episode_length = 10
    dt = 0.05
    space = CompositeSpace((SubSpace.continuous("leg", 1, -1.0, 1.0, 0.0),))

    def __init__(self, fall_at: float = 1e9):
        self.fall_at = fall_at

    def reset(self, key):
        zero = jnp.zeros(())
        return EnvState(
            zero, zero[None], zero, zero, zero, jnp.zeros((), jnp.int32), _Metrics(zero)
        )

    def step(self, state, action):
        v = action[0, 0]
        x = state.metrics.x_position + v * self.dt
        done = (x >= self.fall_at).astype(jnp.float32)
        return EnvState(x, x[None], v, done, 0.0 * done, state.t + 1, _Metrics(x))


def _constant(value: float):
    return lambda state, key: jnp.full((state.obs.shape[0], 1, 1), value)


@pytest.mark.parametrize(
    "env, value, distance, speed",
    [
        (_Walker(), 0.5, 0.25, 0.5),  # 10 steps of 0.05 s at 0.5 m/s
        (_Walker(fall_at=0.1), 1.0, 0.1, 1.0),  # falls after 2 steps: only those count
        (ActionRepeat(_Walker(), 2), 0.5, 0.25, 0.5),  # 5 decisions of 2 steps
    ],
)
def test_forward_speed_is_displacement_over_simulated_time(env, value, distance, speed):
    res = jax.jit(lambda k: learning.episodes(env, _constant(value), k, 3, [0]))(
        jax.random.PRNGKey(0)
    )
    np.testing.assert_allclose(res["distance"], distance, rtol=1e-5)
    np.testing.assert_allclose(res["speed"], speed, rtol=1e-5)
    assert learning._row(jax.device_get(res))["speed"] == pytest.approx(speed, rel=1e-5)


def test_spider_gait_act_fn_plays_the_gait():
    import envs
    from envs.spider.gait import gait_actions

    env = envs.make("spider")
    act = learning.gait_act_fn(env, np.arange(env.space.n), env.space.max_dim + 1)
    t = jnp.arange(7)
    got = act(types.SimpleNamespace(t=t), None)
    want = gait_actions(env.legs, env.space, 7, env.dt)
    assert got.shape == (7, env.space.n, env.space.max_dim + 1)
    np.testing.assert_allclose(got[..., : env.space.max_dim], want, atol=1e-6)
    assert float(jnp.abs(got[..., -1]).max()) == 0.0  # padded
    assert float(jnp.abs(want).max()) > 0.05  # it moves
    assert learning.reports_position(env) and not learning.reports_position(envs.make("probe"))


def test_seed_walls_of_seeds_trained_one_after_another(tmp_path):
    csv = tmp_path / "metrics.csv"
    csv.write_text(
        "env_steps,seed,updates,wall_s\n"
        "100,0,1,10.0\n200,0,2,25.0\n100,1,1,31.5\n200,1,2,40.0\n100,2,1,44.0\n200,2,2,47.0\n"
    )
    assert learning.seed_walls(str(csv)) == pytest.approx([25.0, 15.0, 7.0])


def test_a_stored_result_from_before_an_option_existed_is_reused(tmp_path):
    """A result.json whose key lacks an option added since (at a default that keeps the old
    behaviour) is the same run; a changed value, a changed default's old value or an option
    that no longer exists are not."""
    key = compare._key(TrainConfig(run_dir=str(tmp_path)), episodes=10)
    copy = lambda: json.loads(json.dumps(key))
    older = copy()
    del older["config"]["score"]["critic"]["self_term"]
    assert compare.same_settings(older, key)
    changed = copy()
    changed["config"]["score"]["critic"]["self_term"] = True
    assert not compare.same_settings(changed, key)
    before_finetune = copy()  # saved before finetune_asrl's default became True: it ran frozen
    del before_finetune["config"]["score"]["critic"]["finetune_asrl"]
    assert not compare.same_settings(before_finetune, key)
    removed = copy()
    removed["config"]["score"]["critic"]["an_option_since_removed"] = 1
    assert not compare.same_settings(removed, key)
    other_episodes = copy()
    del other_episodes["config"]["score"]["critic"]["self_term"]
    other_episodes["episodes"] = 5
    assert not compare.same_settings(other_episodes, key)
    path = tmp_path / "result.json"
    json.dump({"key": older, "returns": [1.0]}, open(path, "w"))
    assert compare._cached(str(path), key)["returns"] == [1.0]


def test_a_stored_transfer_from_before_the_encoder_switch_is_not_reused(tmp_path):
    """A transfer result saved before score-transfer fine-tuned SCORE's critic encoders ran
    with them frozen: it does not stand for today's SCORE transfer, and still does for a
    baseline's (whose critic has no such encoders)."""
    for algo, reused in (("score", False), ("isac", True)):
        cfg = TrainConfig(algo=algo, run_dir=str(tmp_path / algo))
        _, key = compare._transfer_cache(cfg, str(tmp_path / "t"), 100, 10)
        assert key["finetune_critic_encoder"] is (algo == "score")
        before = {k: v for k, v in key.items() if k != "finetune_critic_encoder"}
        assert compare.same_settings(before, key) is reused
        assert compare.same_settings(key, key)
