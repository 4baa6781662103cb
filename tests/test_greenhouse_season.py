"""Greenhouse: whole seasons under several policies and weather files, in ONE compiled call.

The module fixture ``seasons`` runs ``jit(vmap(season))`` over rows of (greenhouse, policy):
the greenhouses differ only in their ``weather`` pytree (Greensboro TMY3, Sand Point AK TMY3,
and an EPW written by a fixture), the policy is an integer selecting among the expert, cold
+ dry, random, extreme and default actions. Every test reads its rows from that one result.
"""

import os

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

from envs.greenhouse.env import make_greenhouse
from envs.greenhouse.expert import expert_action, expert_schedule
from envs.greenhouse.observation import denormalise
from envs.greenhouse.season import expert_policy, format_summary, plot_season, run_season, summarize
from envs.greenhouse.weather import (
    STEFAN_BOLTZMANN,
    bundled_weather_path,
    load_weather,
    sky_temperature_from_clouds,
)

DAYS = 160
ALASKA = "703165TY.csv"
EXPERT, COLD_DRY, RANDOM, HIGH, ONES, DEFAULT, EXPERT_DRY = range(7)
# (weather name, policy) per row of the batched season run
ROWS = [
    ("greensboro", EXPERT),
    ("greensboro", COLD_DRY),
    ("greensboro", RANDOM),
    ("greensboro", HIGH),
    ("greensboro", ONES),
    ("greensboro", DEFAULT),
    ("greensboro", EXPERT_DRY),
    ("alaska", EXPERT),
    ("epw", EXPERT),
]


def write_epw(path: str, tmy3_path: str) -> None:
    """Write a valid EPW (8 header lines, 8760 rows of 35 fields) from a TMY3 file.

    The horizontal infrared field is filled from the cloud-based sky temperature of the TMY3
    data (Stefan-Boltzmann), except on the first day where it is EPW's missing code 9999 (the
    reader must fall back to the cloud-based estimate there).
    """
    from pvlib.iotools import read_tmy3

    df, meta = read_tmy3(tmy3_path, map_variables=True)
    t_sky = sky_temperature_from_clouds(
        df["temp_air"].to_numpy(), df["temp_dew"].to_numpy(), df["OpqCld (tenths)"].to_numpy()
    )
    ir = STEFAN_BOLTZMANN * (t_sky + 273.15) ** 4
    ir[:24] = 9999.0
    stamps = pd.date_range(
        "2001-01-01 01:00", periods=8760, freq="h"
    )  # a non-leap year, hour-ending
    hour = np.where(stamps.hour == 0, 24, stamps.hour)
    day_of = np.where(stamps.hour == 0, (stamps - pd.Timedelta(hours=1)).day, stamps.day)
    month = np.where(stamps.hour == 0, (stamps - pd.Timedelta(hours=1)).month, stamps.month)
    name = meta["Name"].strip('"').replace(",", " ")
    header = [
        f"LOCATION,{name},{meta['State']},USA,TMY3,{meta['USAF']},{meta['latitude']},{meta['longitude']},{meta['TZ']},{meta['altitude']}",
        "DESIGN CONDITIONS,0",
        "TYPICAL/EXTREME PERIODS,0",
        "GROUND TEMPERATURES,0",
        "HOLIDAYS/DAYLIGHT SAVINGS,No,0,0,0",
        "COMMENTS 1,written by tests/test_greenhouse_season.py from a pvlib TMY3 file",
        "COMMENTS 2,infrared from Berdahl-Martin sky emissivity",
        "DATA PERIODS,1,1,Data,Sunday, 1/ 1,12/31",
    ]
    rows = []
    for i in range(8760):
        r = df.iloc[i]
        fields = [
            2001,
            month[i],
            day_of[i],
            hour[i],
            60,
            "?9?9?9?9E0?9?9?9?9?9?9?9?9?9?9?9?9?9?9?9*9*9?9?9?9",
            r["temp_air"],
            r["temp_dew"],
            r["relative_humidity"],
            r["pressure"] * 100.0,
            r["ghi_extra"],
            r["dni_extra"],
            round(float(ir[i]), 2),
            r["ghi"],
            r["dni"],
            r["dhi"],
            999999,
            999999,
            999999,
            9999,
            r["wind_direction"],
            r["wind_speed"],
            r["TotCld (tenths)"],
            r["OpqCld (tenths)"],
            9999,
            77777,
            9,
            999999999,
            r["precipitable_water"],
            0.0,
            0,
            88,
            r["albedo"],
            0.0,
            1.0,
        ]
        assert len(fields) == 35
        rows.append(",".join(str(f) for f in fields))
    with open(path, "w") as f:
        f.write("\n".join(header + rows) + "\n")


@pytest.fixture(scope="module")
def epw_path(tmp_path_factory):
    path = str(tmp_path_factory.mktemp("weather") / "sand_point.epw")
    write_epw(path, bundled_weather_path(ALASKA))
    return path


def _policy_actions(env, state, key):
    """``[7, n, max_dim]``: the candidate actions, indexed by the policy constants above."""
    sp = env.space

    def phys(temp, co2, lamps, irrigation):
        x = jnp.zeros((4, 24), jnp.float32).at[0].set(temp).at[1].set(co2)
        return sp.from_physical(
            x.at[2, :2].set(jnp.asarray(lamps)).at[3, :2].set(jnp.asarray(irrigation))
        )

    expert = expert_action(env, state)
    expert_dry = expert.at[sp.index("irrigation"), :2].set(-1.0)  # start = end = 0: never irrigate
    return jnp.stack(
        [
            expert,
            phys(13.0, 400.0, (0.0, 0.0), (0.0, 0.0)),  # coldest setpoints, no lamps, no water
            sp.sample(key),
            phys(25.0, 700.0, (0.0, 23.0), (0.0, 23.0)),  # hottest, richest, lamps + water all day
            jnp.where(sp.dim_mask, 1.0, 0.0),  # every normalised dim at +1
            sp.default_action(),
            expert_dry,
        ]
    )


@pytest.fixture(scope="module")
def weathers(epw_path):
    return {
        "greensboro": make_greenhouse().weather,
        "alaska": load_weather(bundled_weather_path(ALASKA)),
        "epw": load_weather(epw_path),
    }


@pytest.fixture(scope="module")
def seasons(weathers):
    base = make_greenhouse()
    batch = [base.replace(weather=weathers[w]) for w, _ in ROWS]
    envs = jax.tree.map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *batch)
    modes = jnp.asarray([m for _, m in ROWS], jnp.int32)

    def season(env, mode, key):
        state = env.reset(key)

        def day(state, k):
            state = env.step(state, _policy_actions(env, state, k)[mode])
            return state, (state.obs, state.reward, state.done, state.truncated, state.metrics)

        return jax.lax.scan(day, state, jax.random.split(key, DAYS))[1]

    keys = jax.random.split(jax.random.PRNGKey(0), len(ROWS))
    obs, reward, done, truncated, metrics = jax.jit(jax.vmap(season))(envs, modes, keys)
    return {
        "obs": np.asarray(obs),
        "reward": np.asarray(reward),
        "done": np.asarray(done),
        "truncated": np.asarray(truncated),
        "metrics": jax.tree.map(np.asarray, metrics),
    }


def _row(weather, policy):
    return ROWS.index((weather, policy))


def _yield(seasons, weather, policy):
    return float(seasons["metrics"].cumulative_yield[_row(weather, policy), -1])


# --- stability --------------------------------------------------------------------------------
def test_no_nan_or_inf_over_whole_seasons(seasons):
    for name, x in (("obs", seasons["obs"]), ("reward", seasons["reward"])):
        assert np.all(np.isfinite(x)), f"non-finite {name}"
    for field, x in vars(seasons["metrics"]).items():
        assert np.all(np.isfinite(x)), f"non-finite metric {field}"
    assert np.all(np.abs(seasons["obs"]) <= 1.0)
    m = seasons["metrics"]
    assert np.all(m.cumulative_yield >= 0.0) and np.all(m.daily_yield >= -1e-6)
    assert (
        np.all(m.heating_mj >= 0.0) and np.all(m.co2_kg >= 0.0) and np.all(m.water_stress >= -1e-6)
    )
    # indoor climate stays physical under every policy (from the observation, previous day)
    indoor = np.asarray(denormalise(jnp.asarray(seasons["obs"])))[..., :96].reshape(
        len(ROWS), DAYS, 4, 24
    )
    assert np.all((indoor[..., 0, :] > -15.0) & (indoor[..., 0, :] < 40.0))  # °C
    assert np.all((indoor[..., 1, :] >= 0.0) & (indoor[..., 1, :] <= 100.0 + 1e-3))  # RH %
    assert np.all(indoor[..., 2, :] >= 200.0)  # ppm


def test_done_only_at_season_end(seasons):
    expected = np.zeros(DAYS, np.float32)
    expected[-1] = 1.0
    np.testing.assert_array_equal(seasons["done"], np.broadcast_to(expected, seasons["done"].shape))
    assert np.all(seasons["truncated"] == 0.0)  # the season end is terminal
    days = np.asarray(denormalise(jnp.asarray(seasons["obs"][0])))[:, 216]
    np.testing.assert_allclose(days, np.arange(1, DAYS + 1), atol=1e-3)


# --- realism ----------------------------------------------------------------------------------
def test_expert_yield_realistic_and_first_harvest(seasons):
    m = seasons["metrics"]
    y = _yield(seasons, "greensboro", EXPERT)
    assert 15.0 <= y <= 40.0, (
        f"expert season yield {y:.1f} kg/m² outside the heated-greenhouse range"
    )
    cum = m.cumulative_yield[_row("greensboro", EXPERT)]
    first = int(np.argmax(cum >= 0.1)) + 1
    assert 40 <= first <= 80, (
        f"first harvest on day {first}, expected roughly two months after planting"
    )
    # the cumulative reward sums the cumulative yields (the paper's return, hundreds)
    r = seasons["reward"][_row("greensboro", EXPERT)]
    np.testing.assert_allclose(r, cum, rtol=1e-6)
    assert 300.0 < r.sum() < 3000.0


def test_expert_beats_cold_and_dry(seasons):
    expert, cold = _yield(seasons, "greensboro", EXPERT), _yield(seasons, "greensboro", COLD_DRY)
    assert expert > cold + 10.0 and cold < 0.2 * expert
    assert expert > _yield(seasons, "greensboro", RANDOM)


def test_no_irrigation_hurts_yield(seasons):
    m = seasons["metrics"]
    wet, dry = _row("greensboro", EXPERT), _row("greensboro", EXPERT_DRY)
    assert m.irrigation_l[dry].sum() == 0.0 and m.irrigation_l[wet].sum() > 100.0
    assert _yield(seasons, "greensboro", EXPERT_DRY) < 0.5 * _yield(seasons, "greensboro", EXPERT)
    assert m.water_stress[dry, 30:].mean() > 0.5 > m.water_stress[wet].mean()


def test_controllers_track_setpoints(seasons, weathers):
    """Heating holds the expert's (light-dependent) night setpoint; CO2 dosing reaches 700 ppm
    in the light in winter."""
    indoor = np.asarray(denormalise(jnp.asarray(seasons["obs"][_row("greensboro", EXPERT)])))[
        :, :96
    ].reshape(DAYS, 4, 24)
    env = make_greenhouse()
    doy = (env.config.start_day_of_year - 1 + np.arange(DAYS)) % 365
    ghi = weathers["greensboro"].ghi[doy]
    setpoints = np.asarray(jax.vmap(lambda g: expert_schedule(g, env.climate_params))(ghi))
    night, night_sp = indoor[:60, 0, 1:4], setpoints[:60, 0, 1:4]  # 01:00-04:00, first 60 days
    assert np.mean(np.abs(night - night_sp) < 0.5) > 0.8
    noon_co2 = indoor[:30, 2, 10:14]
    assert np.mean(noon_co2 > 650.0) > 0.7
    m = seasons["metrics"]
    assert m.electricity_kwh[_row("greensboro", EXPERT), :20].min() > 1.0  # lamps on short days
    assert m.electricity_kwh[_row("greensboro", COLD_DRY)].sum() == 0.0


# --- weather files ----------------------------------------------------------------------------
def test_epw_reader_matches_tmy3(weathers):
    """The EPW written from the Alaska TMY3 reads back the same weather (incl. sky temperature
    from infrared, and the cloud fallback where infrared is missing)."""
    a, e = weathers["alaska"], weathers["epw"]
    for field in ("ghi", "temp_air", "rh", "wind"):
        np.testing.assert_allclose(getattr(e, field), getattr(a, field), atol=1e-3, err_msg=field)
    np.testing.assert_allclose(e.temp_sky, a.temp_sky, atol=0.02)
    assert e.ghi.shape == (365, 24)


def test_different_weather_changes_outcome(seasons):
    m = seasons["metrics"]
    gso, ak, epw = (
        _yield(seasons, "greensboro", EXPERT),
        _yield(seasons, "alaska", EXPERT),
        _yield(seasons, "epw", EXPERT),
    )
    assert abs(ak - gso) > 0.1 * gso
    assert epw == pytest.approx(ak, rel=2e-3)  # same data through the EPW reader
    heat = {w: m.heating_mj[_row(w, EXPERT)].sum() for w in ("greensboro", "alaska")}
    assert heat["alaska"] > heat["greensboro"]  # a colder site needs more heat
    t_out = {w: m.temp_out[_row(w, EXPERT)].mean() for w in ("greensboro", "alaska")}
    assert t_out["alaska"] != pytest.approx(t_out["greensboro"], abs=0.5)


# --- season API -------------------------------------------------------------------------------
def test_run_season_summary_and_plot(seasons, tmp_path):
    env = make_greenhouse()
    trace = run_season(env, expert_policy, jax.random.PRNGKey(0))
    assert trace.reward.shape == (DAYS,)
    assert float(trace.metrics.cumulative_yield[-1]) == pytest.approx(
        _yield(seasons, "greensboro", EXPERT), rel=1e-4
    )
    s = summarize(trace)
    assert s["first_harvest_day"] == int(trace.first_harvest_day) > 0
    assert s["return"] == pytest.approx(float(np.sum(trace.reward)), rel=1e-5)
    assert "expert" in format_summary({"expert": trace})
    path = plot_season({"expert": trace, "expert again": trace}, str(tmp_path / "season.png"))
    assert os.path.getsize(path) > 10_000
