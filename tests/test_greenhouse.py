"""Greenhouse environment: action space, protocol, crop physiology, action handling.

Season-level behaviour (realism, weather, NaN-freedom over whole seasons) is in
``test_greenhouse_season.py``.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs.base import CompositeEnv
from envs.greenhouse.actions import on_fraction
from envs.greenhouse.crop import CropParams, gross_photosynthesis
from envs.greenhouse.env import make_greenhouse
from envs.greenhouse.observation import OBSERVATION_SIZE, denormalise


@pytest.fixture(scope="module")
def env():
    return make_greenhouse()


@pytest.fixture(scope="module")
def step(env):
    return jax.jit(env.step)


@pytest.fixture(scope="module")
def state0(env):
    return jax.jit(env.reset)(jax.random.PRNGKey(0))


# --- action space (Table 1) ----------------------------------------------------------------
def test_space_dims_order_and_defaults(env):
    sp = env.space
    assert sp.names == ("temperature", "co2", "lighting", "irrigation")
    assert sp.dims == (24, 24, 2, 2) and sp.total_dim == 52 and sp.max_dim == 24
    phys = np.asarray(sp.to_physical(sp.default_action()))
    np.testing.assert_allclose(phys[0], 19.0, atol=1e-5)
    np.testing.assert_allclose(phys[1], 550.0, atol=1e-3)
    np.testing.assert_allclose(phys[2, :2], [6.0, 18.0], atol=1e-4)
    np.testing.assert_allclose(phys[3, :2], [7.0, 17.0], atol=1e-4)
    temp, co2, lit, irr = sp.subspaces
    assert (temp.kind, min(temp.low), max(temp.high)) == ("continuous", 13.0, 25.0)
    assert (co2.kind, min(co2.low), max(co2.high)) == ("continuous", 400.0, 700.0)
    for s in (lit, irr):  # Table 1: discrete hours 0..23
        assert (s.kind, s.n_choices, s.low, s.high) == ("discrete", 24, (0.0, 0.0), (23.0, 23.0))


def test_continuous_hours_switch():
    sp = make_greenhouse(discrete_hours=False).space
    for name in ("lighting", "irrigation"):
        s = sp.subspaces[sp.index(name)]
        assert (s.kind, s.n_choices, s.low, s.high) == ("continuous", 0, (0.0, 0.0), (24.0, 24.0))
    assert sp.total_dim == 52
    # a continuous 7.3 h start survives (discrete would snap it to 7)
    x = np.zeros((4, 24), np.float32)
    x[2, :2] = (7.3, 20.6)
    assert np.asarray(sp.to_physical(sp.from_physical(x)))[2, 0] == pytest.approx(7.3, abs=1e-4)


def test_schedule_on_fraction():
    on = np.asarray(on_fraction(jnp.float32(6.0), jnp.float32(18.0), 1))[:, 0]
    np.testing.assert_array_equal(on, (np.arange(24) >= 6) & (np.arange(24) < 18))
    night = np.asarray(on_fraction(jnp.float32(18.0), jnp.float32(6.0), 1))[
        :, 0
    ]  # end < start: wraps midnight
    np.testing.assert_array_equal(night, [1] * 6 + [0] * 12 + [1] * 6)
    assert np.asarray(on_fraction(jnp.float32(9.0), jnp.float32(9.0), 1)).sum() == 0
    frac = np.asarray(on_fraction(jnp.float32(6.5), jnp.float32(8.25), 2)).reshape(
        -1
    )  # half-hour sub-steps
    np.testing.assert_allclose(frac[12:18], [0.0, 1.0, 1.0, 1.0, 0.5, 0.0])


# --- construction and protocol -------------------------------------------------------------
def test_unknown_override_lists_accepted():
    with pytest.raises(ValueError, match=r"unknown option.*'seasn_days'.*accepted.*season_days"):
        envs.make("greenhouse", seasn_days=100)
    with pytest.raises(ValueError, match="reward must be one of"):
        make_greenhouse(reward="yield")


def test_protocol_and_reset(env, state0):
    assert isinstance(env, CompositeEnv)
    assert envs.make("greenhouse").name == "greenhouse"
    assert env.observation_size == OBSERVATION_SIZE == 225
    assert env.episode_length == 160
    assert state0.obs.shape == (225,) and state0.obs.dtype == jnp.float32
    assert np.all(np.abs(np.asarray(state0.obs)) <= 1.0)
    phys = np.asarray(denormalise(state0.obs))
    assert phys[216] == 0.0  # days planted
    assert phys[216 + 5] == pytest.approx(10.0, abs=0.05)  # transplants with 10 nodes
    assert float(state0.reward) == 0.0 and float(state0.done) == 0.0


def test_jit_vmap_step_1024(env):
    n = 1024
    keys = jax.random.split(jax.random.PRNGKey(1), n)
    states = jax.vmap(env.reset)(keys)
    step_b = jax.jit(jax.vmap(env.step))
    for k in range(2):
        actions = env.space.sample(jax.random.PRNGKey(10 + k), (n,))
        states = step_b(states, actions)
    assert states.obs.shape == (n, 225) and states.reward.shape == (n,)
    assert np.all(np.isfinite(np.asarray(states.obs))) and np.all(
        np.abs(np.asarray(states.obs)) <= 1.0
    )
    assert np.all(np.asarray(states.t) == 2)
    # different actions give different indoor climates
    assert np.std(np.asarray(states.metrics.temp_in)) > 0.1


# --- actions are clipped, never NaN --------------------------------------------------------
def test_out_of_range_and_nan_actions(env, step, state0):
    a = env.space.sample(jax.random.PRNGKey(3))
    wild = a * 7.0
    wild = wild.at[0, 3].set(jnp.inf).at[1, 5].set(-jnp.inf)
    s_wild, s_clip = step(state0, wild), step(state0, jnp.clip(wild, -1.0, 1.0))
    jax.tree.map(np.testing.assert_array_equal, s_wild, s_clip)
    s_nan = step(state0, jnp.full_like(a, jnp.nan))
    s_def = step(state0, env.space.default_action())
    jax.tree.map(np.testing.assert_array_equal, s_nan, s_def)
    for leaf in jax.tree.leaves(s_nan):
        assert np.all(np.isfinite(np.asarray(leaf)))


# --- crop physiology -----------------------------------------------------------------------
def test_gross_photosynthesis_monotone_in_co2_and_par():
    p = CropParams()
    co2 = jnp.linspace(0.0, 1500.0, 151)[:, None, None, None]
    par = jnp.linspace(0.0, 2500.0, 126)[None, :, None, None]
    temp = jnp.asarray([5.0, 13.0, 20.0, 30.0])[None, None, :, None]
    lai = jnp.asarray([0.1, 1.0, 3.0, 4.0])[None, None, None, :]
    pg = np.asarray(gross_photosynthesis(par, co2, temp, lai, p))
    assert np.all(np.isfinite(pg)) and np.all(pg >= 0.0)
    assert np.all(np.diff(pg, axis=0) >= -1e-5), "raising CO2 lowered gross photosynthesis"
    assert np.all(np.diff(pg, axis=1) >= -1e-5), "raising PAR lowered gross photosynthesis"
    # and it does respond: strictly more at 700 than at 400 ppm in bright light, 20 °C, LAI 3
    hi = float(gross_photosynthesis(1000.0, 700.0, 20.0, 3.0, p))
    lo = float(gross_photosynthesis(1000.0, 400.0, 20.0, 3.0, p))
    assert hi > 1.15 * lo
    assert float(gross_photosynthesis(0.0, 700.0, 20.0, 3.0, p)) == 0.0
    # canopy rate of a bright hour: tens of µmol CO2 m^-2 s^-1
    assert 20.0 < hi < 80.0


def _profit(cfg, m):
    cost = (
        cfg.gas_price * m.heating_mj
        + cfg.co2_price * m.co2_kg
        + cfg.electricity_price * m.electricity_kwh
    )
    return cfg.tomato_price * m.daily_yield - cost


def test_reward_modes(env, step, state0):
    """cumulative = cumulative harvest, increment = the day's harvest, profit = EUR balance."""
    action = env.space.default_action()
    state = state0
    for _ in range(70):  # until harvest has started (the shared compiled step, no new compile)
        state = step(state, action)
    ref = step(state, action)
    m = ref.metrics
    assert float(m.daily_yield) > 0.0 and float(m.cumulative_yield) > float(m.daily_yield)
    assert float(ref.reward) == pytest.approx(float(m.cumulative_yield))  # default: cumulative
    for mode, want in (("increment", m.daily_yield), ("profit", _profit(env.config, m))):
        s1 = jax.jit(make_greenhouse(reward=mode).step)(state, action)
        assert float(s1.reward) == pytest.approx(float(want), rel=1e-5, abs=1e-7)
        jax.tree.map(
            np.testing.assert_array_equal, s1.sim, ref.sim
        )  # reward never changes the simulation


def test_start_day_jitter_and_static_use():
    e = make_greenhouse(start_day_jitter=20)
    reset = jax.jit(jax.vmap(e.reset))
    starts = np.asarray(reset(jax.random.split(jax.random.PRNGKey(0), 64)).sim.start_doy)
    days_from_start = (starts - 354 + 180) % 365 - 180  # signed distance from day 355
    assert (
        days_from_start.min() >= -20
        and days_from_start.max() <= 20
        and len(set(starts.tolist())) > 10
    )
    # the environment object can be a static jit argument (identity hash), like any env object
    f = jax.jit(lambda env, k: env.reset(k).obs, static_argnums=0)
    assert f(e, jax.random.PRNGKey(1)).shape == (225,)


def test_finer_substeps_converge(env, step, state0):
    """The exponential sub-step integration is already accurate at 1 sub-step per hour."""
    from envs.greenhouse.expert import expert_action

    fine = make_greenhouse(substeps_per_hour=6)
    action = expert_action(env, state0)
    a, b = step(state0, action), jax.jit(fine.step)(state0, action)
    assert abs(float(a.metrics.temp_in - b.metrics.temp_in)) < 0.3
    assert float(a.metrics.heating_mj) == pytest.approx(float(b.metrics.heating_mj), rel=0.1)
    assert float(a.metrics.gross_photosynthesis) == pytest.approx(
        float(b.metrics.gross_photosynthesis), rel=0.05
    )
    assert float(a.metrics.transpiration_l) == pytest.approx(
        float(b.metrics.transpiration_l), rel=0.05
    )
