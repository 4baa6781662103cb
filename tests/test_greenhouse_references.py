"""Greenhouse references (``envs.greenhouse.references``) and the light-dependent expert.

The searches run with tiny budgets on a 70-day season (long enough for the first harvests, so
the cumulative reward is not all zeros); module fixtures run each search once and the tests
read them. The expert test runs full 160-day seasons on both bundled climates.
"""

import dataclasses
import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from envs.greenhouse import references as refs
from envs.greenhouse.actions import on_fraction
from envs.greenhouse.env import make_greenhouse
from envs.greenhouse.season import default_policy, expert_policy, run_season
from envs.greenhouse.weather import bundled_weather_path, load_weather

DAYS = 70
CONSTANT = {"n_random": 512, "rounds": 3, "batch": 256}
OPEN_LOOP = {"steps": 16, "snapshots": 2}
KEY = jax.random.PRNGKey(0)


@pytest.fixture(scope="module")
def env():
    return make_greenhouse(season_days=DAYS)


@pytest.fixture(scope="module")
def constant(env):
    return refs.best_constant_schedule(env, KEY, **CONSTANT)


@pytest.fixture(scope="module")
def open_loop(env, constant):
    return refs.best_open_loop_schedule(env, KEY, constant=constant, **OPEN_LOOP)


def _fresh_return(env, schedule) -> float:
    """Season return by a plain scan of ``env.step`` over a per-day schedule ``[D, n, m]``."""

    def day(state, action):
        state = env.step(state, action)
        return state, state.reward

    _, rewards = jax.jit(lambda s: jax.lax.scan(day, env.reset(KEY), s))(jnp.asarray(schedule))
    return float(jnp.sum(rewards))


# --- best constant ------------------------------------------------------------------------------
def test_constant_beats_default_and_expert(env, constant):
    default = float(run_season(env, default_policy, KEY).episode_return)
    expert = float(run_season(env, expert_policy, KEY).episode_return)
    assert constant.season_return > default * 1.5
    assert constant.season_return > expert
    assert constant.seasons_evaluated == 512 + 3 * 256 and constant.seconds > 0.0


def test_constant_is_a_valid_action_on_the_grid(env, constant):
    sp = env.space
    a = np.asarray(constant.action)
    assert a.shape == (sp.n, sp.max_dim) and np.all(np.abs(a) <= 1.0)
    assert np.all(a[~sp.dim_mask] == 0.0)
    np.testing.assert_allclose(a, np.asarray(sp.from_physical(sp.to_physical(a))), atol=1e-6)
    hours = constant.physical[sp.discrete_mask]
    np.testing.assert_allclose(hours, np.round(hours), atol=1e-4)
    assert np.all((hours >= 0) & (hours <= 23))
    np.testing.assert_allclose(constant.physical, np.asarray(sp.to_physical(a)), atol=1e-5)
    t = constant.physical[sp.index("temperature"), :24]
    assert np.all((t >= 13.0) & (t <= 25.0))
    assert refs.evaluate_schedule(env, a) == pytest.approx(constant.season_return, rel=1e-6)


def test_constant_search_is_deterministic_and_compiles_once(env, constant):
    size = refs._batched_returns._cache_size()
    again = refs.best_constant_schedule(env, KEY, **CONSTANT)
    assert refs._batched_returns._cache_size() == size  # no retracing for a second search
    np.testing.assert_array_equal(again.action, constant.action)
    assert again.season_return == constant.season_return
    other = refs.best_constant_schedule(env, jax.random.PRNGKey(1), **CONSTANT)
    assert not np.array_equal(other.action, constant.action)


# --- open-loop ----------------------------------------------------------------------------------
def test_open_loop_improves_on_the_constant(env, constant, open_loop):
    assert open_loop.season_return >= constant.season_return
    assert open_loop.constant_return == constant.season_return
    assert open_loop.grad_finite and np.all(np.isfinite(open_loop.history))
    assert open_loop.history[-1] > open_loop.history[0]  # the gradient is useful
    assert open_loop.source == "open-loop" and open_loop.rounded_return > constant.season_return
    assert open_loop.schedule.shape == (DAYS, env.space.n, env.space.max_dim)


def test_open_loop_return_is_a_fresh_env_step_evaluation(env, open_loop):
    sp = env.space
    fresh = _fresh_return(env, open_loop.schedule)
    assert fresh == pytest.approx(open_loop.season_return, rel=1e-5)
    hours = open_loop.physical[:, sp.discrete_mask]
    np.testing.assert_allclose(hours, np.round(hours), atol=1e-4)  # rounded onto the grid
    gap = abs(open_loop.relaxed_return - open_loop.rounded_return)
    assert gap < 0.05 * open_loop.rounded_return


def test_open_loop_keeps_the_constant_when_rounding_loses(env, constant):
    # A constant that claims a return no schedule reaches: the ascent's rounded optimum loses,
    # and the result must be that constant, held every day.
    unbeatable = dataclasses.replace(constant, season_return=constant.season_return + 1e3)
    res = refs.best_open_loop_schedule(env, KEY, constant=unbeatable, **OPEN_LOOP)
    assert res.source == "constant" and res.season_return == unbeatable.season_return
    assert res.rounded_return < unbeatable.season_return
    expected = np.broadcast_to(constant.action, res.schedule.shape)
    np.testing.assert_array_equal(res.schedule, expected)


# --- relaxation ---------------------------------------------------------------------------------
def test_relaxed_timer_equals_hard_timer_in_the_sharp_limit():
    start, end = np.meshgrid(np.arange(24.0), np.arange(24.0), indexing="ij")
    start, end = jnp.asarray(start.ravel()), jnp.asarray(end.ravel())
    duration = jnp.mod(end - start, 24.0)  # end == start: 0 h, off
    for sub in (1, 3):
        hard = jax.vmap(lambda s, e, sub=sub: on_fraction(s, e, sub))(start, end)
        soft = jax.vmap(lambda s, d, sub=sub: refs.relaxed_on_fraction(s, d, sub, 1e-4))(
            start, duration
        )
        np.testing.assert_allclose(soft, hard, atol=1e-3)
    # fractional hours too (the continuous-hours timer), wrapping past midnight
    s, d = jnp.float32(21.5), jnp.float32(9.25)
    np.testing.assert_allclose(
        refs.relaxed_on_fraction(s, d, 2, 1e-4), on_fraction(s, jnp.mod(s + d, 24.0), 2), atol=1e-3
    )

    # smooth: moving a 10-h window one hour later shifts the light-weighted hour by one hour
    # (d/dstart of the on-hours' mean clock time = 10 h of window x 1), at an integer start too
    def clock(x):
        return jnp.sum(refs.relaxed_on_fraction(x, 10.0, 1, 0.5)[:, 0] * jnp.arange(24.0))

    assert float(jax.grad(clock)(7.0)) == pytest.approx(10.0, rel=1e-3)


def test_relax_and_round_trip(env):
    sp = env.space
    a = sp.sample(jax.random.PRNGKey(3), (32,))
    back = np.asarray(refs.round_schedule(sp, refs.relax(sp, a)))
    disc = np.broadcast_to(sp.discrete_mask, back.shape)
    np.testing.assert_allclose(back[disc], np.asarray(a)[disc], atol=1e-5)  # hours exactly
    np.testing.assert_allclose(back, np.asarray(a), atol=3e-3)  # setpoints within the edge
    # start 23, end 0 (one hour past midnight wraps to 0, not to 24 = clipped 23 = off)
    x = np.zeros((4, 24), np.float32)
    x[2, :2] = (23.0, 0.0)
    one = sp.from_physical(jnp.asarray(x))
    back = sp.to_physical(refs.round_schedule(sp, refs.relax(sp, one)))
    np.testing.assert_allclose(np.asarray(back)[2, :2], (23.0, 0.0), atol=1e-4)


# --- cache --------------------------------------------------------------------------------------
def test_reference_cache_round_trip_and_corrupt_file(env, tmp_path, monkeypatch):
    kwargs = dict(cache_dir=str(tmp_path), constant_kwargs=CONSTANT, open_loop_kwargs=OPEN_LOOP)
    first = refs.greenhouse_references(env, KEY, **kwargs)
    assert set(first) == {"best constant", "open-loop"}
    assert first["open-loop"] >= first["best constant"] > 0.0
    (path,) = tmp_path.glob("*.json")
    assert json.loads(path.read_text())["returns"] == first

    def boom(*args, **kw):
        raise AssertionError("searched although the cache holds the answer")

    with monkeypatch.context() as m:
        m.setattr(refs, "best_constant_schedule", boom)
        assert refs.greenhouse_references(env, KEY, **kwargs) == first
        # another key, other settings or another env are other entries
        with pytest.raises(AssertionError):
            refs.greenhouse_references(env, jax.random.PRNGKey(5), **kwargs)
        other = env.replace(weather=load_weather(bundled_weather_path("703165TY.csv")))
        with pytest.raises(AssertionError):
            refs.greenhouse_references(other, KEY, **kwargs)

    for garbage in ("{not json", json.dumps({"format": refs.CACHE_FORMAT, "returns": {"x": 1}})):
        path.write_text(garbage)
        assert refs.greenhouse_references(env, KEY, **kwargs) == first  # recomputed, no crash
        assert json.loads(path.read_text())["returns"] == first  # and rewritten
    assert len(list(tmp_path.iterdir())) == 1  # no temporary files left behind


def test_planned_references_play_their_schedules_for_the_decision_interval(env, tmp_path):
    """``reference_schedules(hold_days=8)`` through ``schedule_policy``, evaluated as the report
    does (the env's decisions held 8 days, ``run.episodes``), returns the searched return; the
    cache holds the schedules, and ``ActionRepeat`` asks its env for its own interval."""
    from envs.wrappers import ActionRepeat
    from score_jax.run.episodes import evaluate, scripted_act_fn

    kwargs = dict(cache_dir=str(tmp_path), constant_kwargs=CONSTANT, open_loop_kwargs=OPEN_LOOP)
    schedules = refs.reference_schedules(env, KEY, hold_days=8, **kwargs)
    assert schedules["best constant"].shape == (env.space.n, env.space.max_dim)
    loop = schedules["open-loop"]
    assert loop.shape == (DAYS, env.space.n, env.space.max_dim)
    np.testing.assert_array_equal(loop[8:16], np.broadcast_to(loop[8], loop[8:16].shape))
    returns = refs.greenhouse_references(
        env, KEY, cache_dir=str(tmp_path), constant_kwargs=CONSTANT,
        open_loop_kwargs={**OPEN_LOOP, "hold_days": 8},
    )  # fmt: skip
    assert len(list(tmp_path.glob("*.json"))) == 1  # the same cache entry
    held = ActionRepeat(env, 8)
    idx = np.arange(env.space.n)
    for name, schedule in schedules.items():
        act = scripted_act_fn(refs.schedule_policy(schedule), idx, env.space.max_dim)
        got = jax.jit(lambda k, act=act: evaluate(held, act, k, 1, idx).returns)(KEY)
        assert float(got[0]) == pytest.approx(returns[name], rel=1e-5)


def test_action_repeat_asks_for_planned_references_of_its_decision_interval(env, monkeypatch):
    from envs.wrappers import ActionRepeat, AutoReset

    asked = []
    monkeypatch.setattr(
        refs, "reference_schedules", lambda e, hold_days=1, **kw: asked.append(hold_days) or {}
    )
    assert AutoReset(ActionRepeat(ActionRepeat(env, 2), 4)).planned_references() == {}
    assert env.planned_references() == {} and asked == [8, 1]


def test_cache_dir_default_honours_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("SCORE_JAX_CACHE", str(tmp_path))
    assert refs.default_cache_dir() == os.path.join(str(tmp_path), "references")
    monkeypatch.delenv("SCORE_JAX_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    expected = os.path.join(str(tmp_path / "xdg"), "score-jax", "references")
    assert refs.default_cache_dir() == expected


# --- the light-dependent expert -----------------------------------------------------------------
def test_expert_beats_default_setpoints_on_both_climates():
    """Full seasons: the expert out-yields and out-scores the default setpoints at Greensboro and
    at Sand Point (where the old day-length lamp rule lost yield)."""
    base = make_greenhouse()
    envs = {
        "greensboro": base,
        "sand_point": base.replace(weather=load_weather(bundled_weather_path("703165TY.csv"))),
    }
    for name, e in envs.items():
        ex, de = run_season(e, expert_policy, KEY), run_season(e, default_policy, KEY)
        y_ex, y_de = float(ex.metrics.cumulative_yield[-1]), float(de.metrics.cumulative_yield[-1])
        r_ex, r_de = float(ex.episode_return), float(de.episode_return)
        assert y_ex > 1.05 * y_de, (name, y_ex, y_de)
        assert r_ex > 1.1 * r_de, (name, r_ex, r_de)
