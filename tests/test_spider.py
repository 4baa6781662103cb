"""Spider environment (paper §5.2): spec, MJX batching, physics sanity, MuJoCo agreement, variants.

MJX compiles are slow on CPU, so the expensive pieces are module-scoped and shared:
``batched_step`` (``jit(vmap(env.step))`` over 64 envs) and ``long_rollout`` (one
``jit(scan(vmap(step)))`` of 1000 steps over 16 envs: 8 random, 4 gait, 4 zero action).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import envs
from envs.base import CompositeEnv
from envs.spider.env import SpiderConfig, make_spider
from envs.spider.gait import gait_actions
from envs.spider.legs import (
    DEFAULT_LEG_NAMES,
    LEG_RADIUS,
    STANCE_HEIGHT,
    JointSpec,
    LegSpec,
    ant_leg,
)
from envs.spider.model import build_mj_model, spider_xml
from envs.spider.rollout import make_rollout, mujoco_rollout, reset_batch

N_RANDOM, N_GAIT, N_ZERO = 8, 4, 4
T_LONG = 1000
GAIT_STEPS = 200  # 10 s


@pytest.fixture(scope="module")
def env():
    return envs.make("spider")


@pytest.fixture(scope="module")
def batched_step(env):
    return jax.jit(jax.vmap(env.step))


@pytest.fixture(scope="module")
def states64(env):
    return reset_batch(env, jax.random.PRNGKey(0), 64)


@pytest.fixture(scope="module")
def long_rollout(env):
    """(initial states, actions, final states, Trajectory) of the shared 1000-step rollout."""
    sp = env.space
    b = N_RANDOM + N_GAIT + N_ZERO
    random = sp.sample(jax.random.PRNGKey(1), (T_LONG, N_RANDOM))
    gait = jnp.broadcast_to(
        gait_actions(env.legs, sp, T_LONG, env.dt)[:, None], (T_LONG, N_GAIT, sp.n, sp.max_dim)
    )
    zero = jnp.zeros((T_LONG, N_ZERO, sp.n, sp.max_dim))
    actions = jnp.concatenate([random, gait, zero], axis=1)
    states = reset_batch(env, jax.random.PRNGKey(2), b)
    final, traj = make_rollout(env)(states, actions)
    return states, actions, final, jax.tree.map(np.asarray, traj)


# --- spec ------------------------------------------------------------------------------------
def test_spec_matches_paper(env):
    sp = env.space
    assert isinstance(env, CompositeEnv)
    assert env.name == "spider" and env.episode_length == 1000 and env.config.frame_skip == 5
    assert sp.dims == (2, 2, 2, 2, 3, 3, 1, 1)
    assert sp.names == (
        "leg_front_left",
        "leg_front_right",
        "leg_back_left",
        "leg_back_right",
        "leg_mid_left",
        "leg_mid_right",
        "leg_front",
        "leg_back",
    )
    for s in sp.subspaces:
        assert (
            s.kind == "continuous"
            and set(s.low) == {-1.0}
            and set(s.high) == {1.0}
            and set(s.default) == {0.0}
        )
    assert env.mj_model.nu == sp.total_dim == 16
    # Ant observation without contact forces: qpos[2:] + qvel.
    assert env.observation_size == (env.mj_model.nq - 2) + env.mj_model.nv == 43


def test_legs_are_symmetric_in_four_directions():
    """§5.2.1: the two-pitch-joint legs and the rigid legs sit opposite each other on the axes."""
    legs = {leg.name: leg for leg in make_spider().legs}
    assert [legs[n].angle_deg % 360 for n in ("mid_left", "mid_right", "front", "back")] == [
        90,
        270,
        0,
        180,
    ]
    assert legs["mid_left"].segment_lengths == legs["mid_right"].segment_lengths
    assert legs["front"].segment_lengths == legs["back"].segment_lengths
    ant = [
        legs[n].segment_lengths for n in ("front_left", "front_right", "back_left", "back_right")
    ]
    assert len(set(ant)) == 4, "each Ant leg has its own length"
    # Every foot reaches the floor at the stance height.
    for leg in legs.values():
        assert leg.tip_drop() == pytest.approx(STANCE_HEIGHT - LEG_RADIUS)


def test_only_feet_and_torso_collide_with_the_floor(env):
    m = env.mj_model
    colliding = {
        mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g)
        for g in range(m.ngeom)
        if m.geom_contype[g] or m.geom_conaffinity[g]
    }
    assert colliding == {"floor", "torso"} | {f"{n}_foot" for n in DEFAULT_LEG_NAMES}


def test_reset_is_deterministic_and_standing(env):
    a, b = env.reset(jax.random.PRNGKey(3)), env.reset(jax.random.PRNGKey(3))
    np.testing.assert_array_equal(a.obs, b.obs)
    assert a.obs.shape == (env.observation_size,) and float(a.done) == 0.0 and int(a.t) == 0
    quat = np.asarray(a.sim.data.qpos[3:7])
    assert np.linalg.norm(quat) == pytest.approx(1.0, abs=1e-6)


# --- batched stepping --------------------------------------------------------------------------
def test_jit_vmap_step_64_envs(env, batched_step, states64):
    sp = env.space
    actions = sp.sample(jax.random.PRNGKey(4), (64,))
    out = batched_step(states64, actions)
    assert out.obs.shape == (64, env.observation_size)
    assert out.reward.shape == out.done.shape == (64,)
    assert np.all(np.isfinite(out.obs)) and np.all(out.t == 1)
    # Padded columns never reach the simulator; out-of-range values are clipped.
    junk = jnp.where(sp.dim_mask, 0.0, 123.0)
    padded = batched_step(states64, actions + junk)
    np.testing.assert_array_equal(padded.sim.data.qpos, out.sim.data.qpos)
    clipped = batched_step(states64, jnp.clip(actions * 5.0, -1.0, 1.0))
    np.testing.assert_array_equal(
        batched_step(states64, actions * 5.0).sim.data.qpos, clipped.sim.data.qpos
    )


def test_reward_is_ant_style(env, batched_step, states64):
    cfg = env.config
    actions = env.space.sample(jax.random.PRNGKey(5), (64,))
    out = batched_step(states64, actions)
    ctrl = env.space.flatten(env.space.to_physical(actions))
    vx = (out.sim.data.qpos[:, 0] - states64.sim.data.qpos[:, 0]) / cfg.dt
    np.testing.assert_allclose(out.metrics.x_velocity, vx, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(
        out.metrics.ctrl_cost, cfg.ctrl_cost_weight * jnp.sum(ctrl**2, -1), rtol=1e-5
    )
    np.testing.assert_allclose(
        out.reward, vx + cfg.healthy_reward - out.metrics.ctrl_cost, rtol=1e-5, atol=1e-5
    )


def test_no_nan_over_1000_random_steps(long_rollout):
    """1000 steps without resets: random envs hop, flip and land on their backs; nothing is NaN."""
    _, _, _, traj = long_rollout
    assert traj.obs_finite.all()
    assert np.isfinite(traj.reward).all()
    # Standing and walking contacts hold with the fast solver settings. Standing feet rest
    # within 1 mm of the floor; walking feet sink at most ~5 cm on impact (MuJoCo's default soft
    # contact at Ant's 0.01 s step; see the next test for the same depth with 100 iterations).
    zero, gait = traj.foot_z[:, N_RANDOM + N_GAIT :], traj.foot_z[:, N_RANDOM : N_RANDOM + N_GAIT]
    assert np.abs(zero[-100:] - LEG_RADIUS).max() < 1e-3
    assert gait.min() > LEG_RADIUS - 0.07


def _random_episode_min_foot_z(model, feet, seeds):
    """Plain MuJoCo: lowest foot-centre height of random-action episodes (until unhealthy)."""
    data, out = mujoco.MjData(model), []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        mujoco.mj_resetData(model, data)
        data.qpos[:] += rng.uniform(-0.1, 0.1, model.nq)
        data.qpos[3:7] /= np.linalg.norm(data.qpos[3:7])
        lowest = np.inf
        for _ in range(1000):
            data.ctrl[:] = rng.uniform(-1.0, 1.0, model.nu)
            for _ in range(5):
                mujoco.mj_step(model, data)
                lowest = min(lowest, data.geom_xpos[feet, 2].min())
            if not 0.2 <= data.qpos[2] <= 1.0:
                break
        out.append(lowest)
    return np.asarray(out)


def test_fast_settings_do_not_change_impact_penetration(env):
    """Random torques (Ant's gear 150) slam feet into the floor at up to ~10 m/s, and one 0.01 s
    step then overshoots by centimetres. That is the soft-contact model at Ant's timestep, not
    the cheap solver: MuJoCo with 100 iterations penetrates just as deep."""
    accurate = build_mj_model(
        env.legs,
        dataclasses.replace(env.config.physics, iterations=100, ls_iterations=50, eulerdamp=True),
    )
    seeds = range(16)
    fast = _random_episode_min_foot_z(env.mj_model, env.foot_geoms, seeds)
    acc = _random_episode_min_foot_z(accurate, env.foot_geoms, seeds)
    assert abs(np.median(fast) - np.median(acc)) < 0.01 and abs(fast.min() - acc.min()) < 0.02, (
        fast,
        acc,
    )


def test_termination_and_truncation(env, long_rollout):
    _, _, _, traj = long_rollout
    z = traj.metrics.torso_z
    lo, hi = env.config.healthy_z_range
    unhealthy = (z < lo) | (z > hi)
    time_up = np.arange(1, T_LONG + 1)[:, None] >= env.episode_length
    np.testing.assert_array_equal(traj.done, (unhealthy | time_up).astype(np.float32))
    np.testing.assert_array_equal(traj.truncated, (time_up & ~unhealthy).astype(np.float32))
    zero = slice(N_RANDOM + N_GAIT, None)
    assert not unhealthy[:, zero].any(), "standing still must stay healthy"
    assert (traj.truncated[-1, zero] == 1).all() and (traj.done[:-1, zero] == 0).all()


def test_gait_walks_forward_further_than_zero_action(long_rollout):
    initial, _, _, traj = long_rollout
    x0 = np.asarray(initial.sim.data.qpos[:, 0])
    dx = traj.metrics.x_position[GAIT_STEPS - 1] - x0
    gait = dx[N_RANDOM : N_RANDOM + N_GAIT]
    zero = dx[N_RANDOM + N_GAIT :]
    assert gait.min() > zero.max() + 0.5, (gait, zero)
    assert gait.mean() > 1.0, gait  # ~2-3 m in 10 s
    assert (traj.done[:GAIT_STEPS, N_RANDOM : N_RANDOM + N_GAIT] == 0).all(), (
        "the gait keeps the torso healthy"
    )


# --- agreement with plain MuJoCo -----------------------------------------------------------------
def _play(batched_step, states, actions):
    """Batched env steps; returns qpos ``[T, B, nq]``."""
    qs = []
    for a in actions:
        states = batched_step(states, a)
        qs.append(np.asarray(states.sim.data.qpos))
    return np.stack(qs)


def test_mjx_matches_mujoco_on_the_same_model(env, batched_step, states64):
    """MJX (float32) vs MuJoCo C (float64) with identical solver settings.

    Tolerance: 2e-3 on every qpos entry after one env step (5 physics steps) and 2e-2 after
    three. Contact-rich dynamics are chaotic, so longer horizons diverge from float32 rounding.
    """
    sp = env.space
    n_steps, n_envs = 3, 8
    actions = 0.5 * sp.sample(jax.random.PRNGKey(6), (n_steps, 64))
    q_mjx = _play(batched_step, states64, actions)
    ctrls = np.asarray(sp.flatten(sp.to_physical(actions)))
    for b in range(n_envs):
        q_c = mujoco_rollout(
            env.mj_model,
            np.asarray(states64.sim.data.qpos[b]),
            np.asarray(states64.sim.data.qvel[b]),
            ctrls[:, b],
            env.config.frame_skip,
        )
        err = np.abs(q_c - q_mjx[:, b]).max(axis=1)
        assert err[0] < 2e-3 and err.max() < 2e-2, (b, err)


def test_fast_settings_agree_with_accurate_mujoco(env, long_rollout):
    """The speed settings (Newton, 1 iteration, 4 line-search steps, no eulerdamp) in MJX vs
    MuJoCo with 100 iterations, 50 line-search steps and eulerdamp, from the same initial
    states: the zero-action body (unpowered joints: it slowly sags as its feet creep outwards)
    stands at the same height after 1000 steps (within 1.5 cm; lying down would be 0.25 m
    lower), and the gait walks forward there too. Single trajectories are chaotic, so
    distances are not compared one to one."""
    accurate = build_mj_model(
        env.legs,
        dataclasses.replace(env.config.physics, iterations=100, ls_iterations=50, eulerdamp=True),
    )
    initial, actions, _, traj = long_rollout
    ctrls = np.asarray(env.space.flatten(env.space.to_physical(actions)))
    gait_dx = []
    for b in range(N_RANDOM, N_RANDOM + N_GAIT + N_ZERO):
        q0, v0 = np.asarray(initial.sim.data.qpos[b]), np.asarray(initial.sim.data.qvel[b])
        if b >= N_RANDOM + N_GAIT:
            q_acc = mujoco_rollout(accurate, q0, v0, ctrls[:, b], env.config.frame_skip)
            assert abs(q_acc[-1, 2] - traj.qpos[-1, b, 2]) < 1.5e-2
        else:
            q_acc = mujoco_rollout(accurate, q0, v0, ctrls[:GAIT_STEPS, b], env.config.frame_skip)
            gait_dx.append(q_acc[-1, 0] - q0[0])
    # Each gait trajectory is chaotic (one ulp in the controls moves it by tens of cm); the
    # walk itself is not: every one moves forward and on average well beyond standing still.
    gait_dx = np.asarray(gait_dx)
    assert gait_dx.min() > 0.2 and gait_dx.mean() > 0.5, (
        "the gait also walks in accurate MuJoCo",
        gait_dx,
    )


# --- variants and errors -------------------------------------------------------------------------
def test_six_leg_body_runs_and_matches_subset_space(env):
    six = ("front_left", "front_right", "back_left", "back_right", "leg_mid_left", "mid_right")
    env6 = envs.make("spider", legs=six)
    assert env6.space.dims == (2, 2, 2, 2, 3, 3)
    assert env6.space == env.space.subset([f"leg_{n.removeprefix('leg_')}" for n in six])
    assert env6.observation_size == env.observation_size - 4
    step = jax.jit(env6.step)
    state = env6.reset(jax.random.PRNGKey(7))
    for a in gait_actions(env6.legs, env6.space, 10, env6.dt):
        state = step(state, a)
    assert np.isfinite(state.obs).all() and float(state.done) == 0.0


def test_custom_leg_table_builds():
    legs = (
        ant_leg("a", 0.0, 0.2, 0.5),
        ant_leg("b", 120.0, 0.2, 0.5),
        ant_leg("c", 240.0, 0.3, 0.6),
    )
    env3 = make_spider(legs=legs, episode_length=10)
    assert env3.space.dims == (2, 2, 2) and env3.mj_model.nu == 6 and env3.episode_length == 10
    assert "c_ankle" in spider_xml(legs)


def test_bad_names_give_clear_errors():
    with pytest.raises(ValueError, match="unknown leg name.*'tail'.*accepted.*front_left"):
        make_spider(legs=("front_left", "tail"))
    with pytest.raises(ValueError, match="unknown option.*'wings'.*accepted.*episode_length"):
        envs.make("spider", wings=2)
    with pytest.raises(ValueError, match="at least one leg"):
        make_spider(legs=())
    with pytest.raises(ValueError, match="joints must be one 'hip'"):
        LegSpec(
            "x",
            0.0,
            (0.3, 0.3),
            (0.0, 45.0),
            (JointSpec("knee", "pitch", (-1.0, 1.0)), JointSpec("hip", "hip", (-1.0, 1.0))),
        )
    with pytest.raises(ValueError, match="healthy_z_range"):
        SpiderConfig(healthy_z_range=(1.0, 0.2))


# --- rendering ----------------------------------------------------------------------------------
def test_render_frames_and_gif(env, long_rollout, tmp_path):
    from envs.spider.render import RenderingUnavailable, render_rollout

    _, _, _, traj = long_rollout
    qpos = traj.qpos[:2, N_RANDOM]
    try:
        written = render_rollout(env.mj_model, qpos, tmp_path, width=96, height=72)
    except RenderingUnavailable as err:
        pytest.skip(f"no OpenGL backend for off-screen rendering: {err}")
    import imageio.v3 as iio

    assert len(written["png"]) == 2 and written["gif"][0].exists()
    frame = iio.imread(written["png"][0])
    assert frame.shape == (72, 96, 3) and frame.std() > 1.0  # not a blank image


def test_simulation_imports_without_an_opengl_library():
    """Without libOSMesa (and no DISPLAY) the package must not pick MUJOCO_GL=osmesa, which
    would make ``import mujoco`` itself fail: training needs no OpenGL, only rendering does."""
    import os
    import subprocess
    import sys

    code = (
        "import ctypes.util\n"
        "ctypes.util.find_library = lambda name: None  # a machine without libosmesa6\n"
        "import os, envs.spider, mujoco\n"
        "print(os.environ.get('MUJOCO_GL', 'unset'))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY")}
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "unset"
