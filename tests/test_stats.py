"""score_jax.stats: estimators against their definitions, interval behaviour, small n, plots."""

import dataclasses
import os

import numpy as np
import pytest
import scipy.stats

from score_jax.evaluation import stats

REPS = 2_000


def test_iqm_is_the_25_percent_trimmed_mean():
    rng = np.random.default_rng(0)
    for x in ([1.0, 2.0, 3.0, 4.0], [5.0, 1.0, 9.0, 2.0, 7.0, 100.0, -3.0], rng.normal(size=13)):
        a = stats.aggregate({"a": x}, reps=REPS)["a"]
        assert a.iqm.value == pytest.approx(scipy.stats.trim_mean(x, 0.25))
        assert a.mean.value == pytest.approx(np.mean(x))
        assert a.median.value == pytest.approx(np.median(x))  # one task: median over runs


def test_multi_task_definitions_follow_rliable():
    x = np.arange(12.0).reshape(4, 3) ** 2  # [runs, tasks]
    a = stats.aggregate({"a": x}, reps=REPS, optimality_threshold=50.0)["a"]
    assert (a.n, a.num_tasks) == (4, 3)
    assert a.iqm.value == pytest.approx(scipy.stats.trim_mean(x, 0.25, axis=None))
    assert a.mean.value == pytest.approx(x.mean(0).mean())
    assert a.median.value == pytest.approx(np.median(x.mean(0)))
    assert a.optimality_gap.value == pytest.approx(50.0 - np.minimum(x, 50.0).mean())
    np.testing.assert_allclose(a.per_seed, x.mean(1))


def test_iqm_below_four_runs_is_the_mean():
    for x in ([3.0, 8.0], [1.0, 2.0, 10.0]):
        a = stats.aggregate({"a": x}, reps=REPS)["a"]
        assert a.iqm.value == pytest.approx(np.mean(x))


def test_intervals_contain_the_estimate_and_shrink_with_more_seeds():
    rng = np.random.default_rng(1)
    widths = []
    for n in (5, 20, 80):
        a = stats.aggregate({"a": rng.normal(100.0, 10.0, size=n)}, reps=REPS)["a"]
        for iv in (a.iqm, a.mean, a.median):
            assert iv.lo <= iv.value <= iv.hi and not iv.degenerate
        widths.append(a.iqm.hi - a.iqm.lo)
    assert widths[0] > widths[1] > widths[2]


def test_deterministic_for_a_seed_and_independent_of_other_algorithms():
    rng = np.random.default_rng(2)
    x, y = rng.normal(size=15), rng.normal(size=(6, 2))
    one = stats.aggregate({"x": x, "y": y}, reps=REPS, seed=7)
    again = stats.aggregate({"x": x, "y": y}, reps=REPS, seed=7)
    alone = stats.aggregate({"x": x}, reps=REPS, seed=7)
    other = stats.aggregate({"x": x}, reps=REPS, seed=8)
    assert one == again
    assert one["x"] == alone["x"]
    assert other["x"] != one["x"]
    p1 = stats.probability_of_improvement(x, y[:, 0], reps=REPS, seed=3)
    assert p1 == stats.probability_of_improvement(x, y[:, 0], reps=REPS, seed=3)


def test_single_run_is_degenerate_not_an_error():
    a = stats.aggregate({"a": [903.2]}, reps=REPS)["a"]
    assert a.n == 1 and a.degenerate
    for iv in (a.iqm, a.mean, a.median):
        assert iv.degenerate and iv.lo == iv.hi == iv.value == 903.2
    assert "n=1, no CI" in stats.markdown_table({"a": a})
    p, (lo, hi) = stats.probability_of_improvement([2.0], [1.0])
    assert p == lo == hi == 1.0


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_scores_are_rejected_naming_the_algorithm(bad):
    with pytest.raises(ValueError, match="'score'.*runs \\[1\\]"):
        stats.aggregate({"ok": [1.0, 2.0], "score": [1.0, bad, 3.0]}, reps=REPS)
    with pytest.raises(ValueError, match="'baseline'"):
        stats.probability_of_improvement([1.0], [bad], names=("score", "baseline"))
    with pytest.raises(ValueError, match="'score'"):
        stats.performance_profile({"score": [bad, 1.0]}, [0.0])


def test_bad_shapes_are_rejected():
    with pytest.raises(ValueError, match="empty"):
        stats.aggregate({"a": []})
    with pytest.raises(ValueError, match="num_runs"):
        stats.aggregate({"a": np.zeros((2, 2, 2))})
    with pytest.raises(ValueError, match="tasks"):
        stats.probability_of_improvement(np.zeros((3, 2)), np.zeros((3, 4)))


def test_probability_of_improvement():
    rng = np.random.default_rng(3)
    x = rng.normal(size=7)
    y = x.max() + 1.0 + rng.random(size=5)  # every run of y above every run of x
    assert stats.probability_of_improvement(y, x, reps=REPS) == (1.0, (1.0, 1.0))
    assert stats.probability_of_improvement(x, y, reps=REPS) == (0.0, (0.0, 0.0))
    p, (lo, hi) = stats.probability_of_improvement(x, x, reps=REPS)
    assert p == 0.5 and lo <= 0.5 <= hi
    a, b = rng.normal(size=(6, 3)), rng.normal(size=(4, 3)) + 0.3
    pab, (lo, hi) = stats.probability_of_improvement(a, b, reps=REPS)
    pba, _ = stats.probability_of_improvement(b, a, reps=REPS)
    assert pab + pba == pytest.approx(1.0)
    assert lo <= pab <= hi
    mwu = np.mean([scipy.stats.mannwhitneyu(a[:, j], b[:, j]).statistic for j in range(3)])
    assert pab == pytest.approx(mwu / (6 * 4))


def test_performance_profile_is_non_increasing():
    rng = np.random.default_rng(4)
    taus = np.linspace(-3.0, 3.0, 25)
    out = stats.performance_profile(
        {"a": rng.normal(size=10), "b": rng.normal(size=(5, 3))}, taus, reps=500
    )
    for profile, (lo, hi) in out.values():
        assert profile.shape == lo.shape == hi.shape == taus.shape
        assert np.all(np.diff(profile) <= 0) and np.all(np.diff(lo) <= 0)
        assert np.all(lo <= profile) and np.all(profile <= hi)
    np.testing.assert_allclose(out["a"][0][0], 1.0)
    single = stats.performance_profile({"s": [0.5]}, taus)["s"]
    np.testing.assert_array_equal(single[0], single[1][0])


def test_format_and_markdown_table():
    assert stats.format_interval(903.24, 871.0, 944.94) == "903.2 [871.0, 944.9]"
    assert stats.format_interval(1.0, 0.5, 2.0, digits=2) == "1.00 [0.50, 2.00]"
    aggs = stats.aggregate({"low": [1.0, 2.0, 3.0], "high": [10.0, 11.0, 12.0, 13.0]}, reps=REPS)
    table = stats.markdown_table(aggs).splitlines()
    assert table[0].startswith("| algorithm | IQM [95% CI] | mean [95% CI] | median [95% CI] | n |")
    assert table[2].startswith("| high | 11.5 [")
    assert table[2].endswith("| 4 | 10.0, 11.0, 12.0, 13.0 |")
    assert table[3].startswith("| low | 2.0 [")
    with pytest.raises(ValueError, match="optimality_threshold"):
        stats.markdown_table(aggs, metric="optimality_gap")
    with pytest.raises(ValueError, match="known: iqm"):
        stats.markdown_table(aggs, metric="max")


def test_aggregate_is_frozen():
    a = stats.aggregate({"a": [1.0, 2.0]}, reps=REPS)["a"]
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.n = 3
    with pytest.raises(ValueError):
        a.scores[0, 0] = 5.0


def test_plots_write_files(tmp_path):
    rng = np.random.default_rng(5)
    scores = {"score": rng.normal(1.0, size=5), "baseline": rng.normal(size=5), "one": [0.2]}
    aggs = stats.aggregate(scores, reps=REPS)
    path = os.path.join(tmp_path, "intervals.png")
    stats.plot_interval_estimates(aggs, path)
    taus = np.linspace(-2.0, 3.0, 11)
    profile_path = os.path.join(tmp_path, "profiles.png")
    stats.plot_performance_profiles(
        stats.performance_profile(scores, taus, reps=200), taus, profile_path
    )
    for p in (path, profile_path):
        with open(p, "rb") as f:
            assert f.read(8) == b"\x89PNG\r\n\x1a\n"


def test_learned_returns_are_given_as_a_share_of_a_positive_open_loop_reference():
    from score_jax.evaluation.report import add_shares

    rows = {"score": {"mean": 900.0}, "expert": {"mean": 1000.0}, "open-loop": {"mean": 1200.0}}
    add_shares(rows, ["score"])
    assert rows["score"]["share_of_open_loop"] == pytest.approx(0.75)
    assert "share_of_open_loop" not in rows["expert"]  # references get none
    loss = {"score": {"mean": -3.0}, "open-loop": {"mean": -1.0}}
    assert "share_of_open_loop" not in add_shares(loss, ["score"])["score"]
    assert "share_of_open_loop" not in add_shares({"score": {"mean": 1.0}}, ["score"])["score"]


def test_stability_finds_the_lowest_moving_mean_after_the_curve_first_beats_a_threshold(tmp_path):
    """Seed 0 climbs past 10, collapses to 2 and recovers; seed 1 climbs and holds; seed 2
    never gets there (40 rows each: the moving mean is 2 rows wide)."""
    from score_jax.evaluation.stability import format_stability, lowest_after_exceeding

    curves = {
        0: [0.0] * 10 + [20.0] * 10 + [2.0] * 4 + [20.0] * 16,
        1: [0.0] * 10 + [20.0] * 30,
        2: [5.0] * 40,
    }
    path = tmp_path / "metrics.csv"
    lines = ["env_steps,seed,episode_return,eval_return"]
    for step in range(40):
        lines += [f"{100 * (step + 1)},{seed},{c[step]},nan" for seed, c in curves.items()]
    path.write_text("\n".join(lines) + "\n")
    s = lowest_after_exceeding(str(path), 10.0)
    assert s[0]["first_above"] == 1200 and s[0]["lowest_after"] == 2.0 and not s[0]["held"]
    assert s[0]["lowest_at"] == 2200  # the first window wholly inside the dip ends there
    assert s[1]["lowest_after"] == pytest.approx(20.0) and s[1]["held"]
    assert s[2]["first_above"] is None and not s[2]["held"]
    text = format_stability(s, 10.0, "the default policy")
    assert "seed 0" in text and "fell below it" in text and "seed 2: never above" in text


def test_learning_curve_draws_the_reference_returns(tmp_path, monkeypatch):
    import matplotlib.axes

    from score_jax.evaluation.curves import plot_learning_curve

    path = tmp_path / "metrics.csv"
    rows = [f"{100 * i},{s},{i + s},nan" for i in range(1, 30) for s in range(2)]
    path.write_text("env_steps,seed,episode_return,eval_return\n" + "\n".join(rows) + "\n")
    drawn = []
    original = matplotlib.axes.Axes.axhline
    monkeypatch.setattr(
        matplotlib.axes.Axes,
        "axhline",
        lambda self, y, **kw: drawn.append((y, kw["label"])) or original(self, y, **kw),
    )
    png = tmp_path / "curve.png"
    plot_learning_curve(str(path), str(png), "t", references={"default": 8.0, "open-loop": 30.5})
    assert drawn == [(8.0, "default (8.0)"), (30.5, "open-loop (30.5)")]
    assert png.stat().st_size > 10_000


def test_robustness_cells_get_an_iqm_over_trained_seeds():
    from score_jax.evaluation.robustness import iqm_over_seeds

    rng = np.random.default_rng(0)
    per_seed = rng.normal(100.0, 10.0, size=(6, 3, 2))
    per_seed[:, 2, 1] = 50.0  # every seed equal: the interval is the point
    out = iqm_over_seeds(per_seed, ["default", "random"])
    assert len(out["iqm"]) == 3 and len(out["iqm"][0]) == 2 and out["trained_seeds"] == 6
    cell = out["iqm"][0][0]
    assert cell["value"] == pytest.approx(scipy.stats.trim_mean(per_seed[:, 0, 0], 0.25))
    assert cell["lo"] < cell["value"] < cell["hi"]
    assert out["iqm"][2][1] == {"value": 50.0, "lo": 50.0, "hi": 50.0}
    assert "| 2 |" in out["markdown"] and "random IQM [95% CI]" in out["markdown"]
