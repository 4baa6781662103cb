"""The Spider environment (paper §5.2): an Ant-like body with 8 heterogeneous legs in MuJoCo MJX.

Each leg is one sub-action space (``leg_<name>``, continuous in [-1, 1], default 0: the motor
is off). The task is Ant's: reward = forward (x) velocity + healthy bonus - control cost; the
episode ends (terminal) when the torso height leaves ``healthy_z_range`` and is truncated
after ``episode_length`` steps. One environment step is ``frame_skip`` physics steps.

Observation ``[observation_size]`` (shared by all sub-spaces, Ant without contact forces):
``qpos[2:]`` (torso z, torso quaternion, all leg joint angles) followed by ``qvel`` (torso
linear and angular velocity, all leg joint velocities). For the default body that is
``5 + 16`` positions and ``6 + 16`` velocities = 43 values.

Usage::

    env = envs.make("spider")                       # the 8-leg body, dims [2, 2, 2, 2, 3, 3, 1, 1]
    env6 = envs.make("spider", legs=("front_left", "front_right", "back_left", "back_right",
                                      "mid_left", "mid_right"))          # §5.2.4 transfer source
    state = env.reset(jax.random.PRNGKey(0))
    state = jax.jit(env.step)(state, env.space.default_action())
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import jax.numpy as jnp
from flax import struct
from mujoco import mjx

from envs.base import CompositeEnv, EnvHints, EnvState, build_config
from envs.spider.legs import LegSpec, select_legs
from envs.spider.model import PhysicsOptions, build_mj_model, foot_geom_ids
from envs.spider.physics import physics_step
from score_jax.core.spaces import CompositeSpace, SubSpace


@dataclasses.dataclass(frozen=True)
class SpiderConfig:
    """Static options of the Spider (every field is an accepted ``make_spider`` override).

    Attributes:
      episode_length: steps before truncation (§5.2: 1000, as Ant).
      frame_skip: physics steps per environment step (dt = frame_skip * timestep = 0.05 s).
      ctrl_cost_weight: weight of ``sum(ctrl ** 2)`` in the reward (Ant: 0.5).
      healthy_reward: bonus per step while the torso height is in range (Ant: 1).
      healthy_z_range: (min, max) torso-centre height (m); outside it the episode terminates.
      terminate_when_unhealthy: if False the episode only ends by the time limit and the
        healthy bonus is paid only while healthy.
      reset_noise_scale: uniform noise on qpos and Gaussian std on qvel at reset (Ant: 0.1).
      physics: MuJoCo options (``envs.spider.model.PhysicsOptions``); the defaults follow MJX's
        performance notes and are checked against accurate MuJoCo in the tests. From the
        command line: ``--env-options physics.timestep=0.005``.
      lean_step: step with ``envs.spider.physics.lean_step`` (``mjx.step`` without the unused
        Cartesian-force term, same result, faster) instead of ``mjx.step``.
    """

    episode_length: int = 1000
    frame_skip: int = 5
    ctrl_cost_weight: float = 0.5
    healthy_reward: float = 1.0
    healthy_z_range: tuple[float, float] = (0.2, 1.0)
    terminate_when_unhealthy: bool = True
    reset_noise_scale: float = 0.1
    physics: PhysicsOptions = PhysicsOptions()
    lean_step: bool = True

    def __post_init__(self):
        if self.episode_length < 1 or self.frame_skip < 1:
            raise ValueError("episode_length and frame_skip must be >= 1")
        lo, hi = self.healthy_z_range
        if not lo < hi:
            raise ValueError(
                f"healthy_z_range must be (min, max) with min < max, got {self.healthy_z_range}"
            )

    @property
    def dt(self) -> float:
        """Seconds of simulated time per environment step."""
        return self.frame_skip * self.physics.timestep


@struct.dataclass
class SpiderSim:
    """Simulator state: the MJX data of one spider (``qpos [nq]``, ``qvel [nv]``, ...)."""

    data: mjx.Data


@struct.dataclass
class SpiderMetrics:
    """Per-step diagnostics (all ``[]`` float32)."""

    forward_reward: jax.Array
    healthy_reward: jax.Array
    ctrl_cost: jax.Array
    x_position: jax.Array
    y_position: jax.Array
    x_velocity: jax.Array
    y_velocity: jax.Array
    torso_z: jax.Array


TORQUE_UNITS = "normalised torque"  # a motor's control ctrl in [-1, 1]: torque = gear * ctrl


def leg_space(legs: Sequence[LegSpec]) -> CompositeSpace:
    """One continuous sub-space ``leg_<name>`` in [-1, 1] (default 0) per leg, dim = its
    actuators."""
    return CompositeSpace(
        tuple(
            SubSpace.continuous(
                leg.subspace_name, leg.n_actuators, -1.0, 1.0, 0.0, units=TORQUE_UNITS
            )
            for leg in legs
        )
    )


class SpiderEnv(CompositeEnv):
    """The Spider as a ``CompositeEnv`` (pure ``reset`` / ``step``; ``jit(vmap(step))`` works).

    Attributes:
      legs: the leg table the body was built from.
      config: the ``SpiderConfig``.
      space: ``CompositeSpace`` with one sub-space per leg, in table order.
      mj_model: the host ``mujoco.MjModel`` (for rendering and CPU MuJoCo comparisons).
      sys: the ``mjx.Model`` stepped by ``step``.
    """

    name = "spider"
    hints = EnvHints(total_steps=200_000, eval_every=20_000)

    def __init__(self, legs: Sequence[LegSpec], config: SpiderConfig = SpiderConfig()):
        self.legs = tuple(legs)
        self.config = config
        self.space = leg_space(self.legs)
        self.mj_model = build_mj_model(self.legs, config.physics)
        self.sys = mjx.put_model(self.mj_model)
        self.foot_geoms = foot_geom_ids(self.mj_model, self.legs)
        # A template Data (zeros, qpos0) that reset fills; built once on the host.
        self._data0 = mjx.make_data(self.mj_model)
        self.episode_length = config.episode_length
        self.observation_size = (self.mj_model.nq - 2) + self.mj_model.nv

    @property
    def dt(self) -> float:
        return self.config.dt

    def reset(self, key: jax.Array) -> EnvState:
        """Standing pose + Ant's reset noise. ``key`` -> ``EnvState``
        (``obs [observation_size]``)."""
        key_pos, key_vel = jax.random.split(key)
        scale = self.config.reset_noise_scale
        nq, nv = self.mj_model.nq, self.mj_model.nv
        qpos = jnp.asarray(self.mj_model.qpos0, jnp.float32) + jax.random.uniform(
            key_pos, (nq,), minval=-scale, maxval=scale
        )
        # Keep the torso quaternion a unit quaternion (Ant's noise is added to it unnormalised).
        qpos = qpos.at[3:7].set(qpos[3:7] / jnp.linalg.norm(qpos[3:7]))
        qvel = scale * jax.random.normal(key_vel, (nv,))
        data = self._data0.replace(qpos=qpos, qvel=qvel)
        zero = jnp.zeros((), jnp.float32)
        metrics = SpiderMetrics(zero, zero, zero, qpos[0], qpos[1], zero, zero, qpos[2])
        return EnvState(
            SpiderSim(data), self._obs(data), zero, zero, zero, jnp.zeros((), jnp.int32), metrics
        )

    def step(self, state: EnvState, action: jax.Array) -> EnvState:
        """Apply ``action`` (normalised ``[n, max_dim]``) for ``frame_skip`` physics steps.

        The actuator vector is ``space.flatten(space.to_physical(action))``: clipped to [-1, 1],
        NaN replaced by the default, padded columns dropped.
        """
        cfg = self.config
        ctrl = self.space.flatten(self.space.to_physical(action))
        data0 = state.sim.data
        data = data0.replace(ctrl=ctrl)
        # A rolled loop (not unrolled) keeps the compiled program, and compile time, small.
        data = jax.lax.fori_loop(
            0, cfg.frame_skip, lambda _, d: physics_step(self.sys, d, cfg.lean_step), data
        )

        velocity = (data.qpos[:2] - data0.qpos[:2]) / cfg.dt
        z = data.qpos[2]
        lo, hi = cfg.healthy_z_range
        healthy = ((z >= lo) & (z <= hi)).astype(jnp.float32)
        healthy_reward = cfg.healthy_reward * (1.0 if cfg.terminate_when_unhealthy else healthy)
        ctrl_cost = cfg.ctrl_cost_weight * jnp.sum(jnp.square(ctrl))
        reward = velocity[0] + healthy_reward - ctrl_cost

        t = state.t + 1
        terminal = (1.0 - healthy) if cfg.terminate_when_unhealthy else jnp.zeros((), jnp.float32)
        time_up = (t >= cfg.episode_length).astype(jnp.float32)
        done = jnp.maximum(terminal, time_up)
        truncated = time_up * (1.0 - terminal)
        metrics = SpiderMetrics(
            velocity[0],
            jnp.asarray(healthy_reward, jnp.float32),
            ctrl_cost,
            data.qpos[0],
            data.qpos[1],
            velocity[0],
            velocity[1],
            z,
        )
        return EnvState(SpiderSim(data), self._obs(data), reward, done, truncated, t, metrics)

    def _obs(self, data: mjx.Data) -> jax.Array:
        """``[observation_size]``: qpos without torso x, y, then qvel."""
        return jnp.concatenate([data.qpos[2:], data.qvel]).astype(jnp.float32)

    def foot_heights(self, state: EnvState) -> jax.Array:
        """``[n_legs]`` height (m) of each foot sphere's centre (valid after at least one step)."""
        return state.sim.data.geom_xpos[..., self.foot_geoms, 2]


def make_spider(legs: Sequence[str | LegSpec] | None = None, **overrides) -> SpiderEnv:
    """Build a Spider (registered as ``envs.make("spider", ...)``).

    Args:
      legs: ``None`` for the default 8 legs; a tuple of leg names to keep (e.g. drop
        ``"front"`` and ``"back"`` for a 6-leg body; ``"leg_front"`` is accepted too); or a
        full custom table of ``LegSpec``.
      **overrides: ``SpiderConfig`` fields.

    Raises:
      ValueError: an unknown leg name or override (the message lists the accepted ones).
    """
    return SpiderEnv(select_legs(legs), build_config(SpiderConfig, overrides))


# typed --env-options (envs.option_types): the config's fields and the legs to keep, by name
make_spider.config_class = SpiderConfig
make_spider.extra_options = {"legs": tuple[str, ...] | None}
