"""Open-loop rollouts of the Spider: batched in MJX (one jit) and one env in plain MuJoCo.

Shared by the tests, the throughput benchmark and the render CLI, so that all of them measure
and show the same thing.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from envs.base import EnvState
from envs.spider.env import SpiderEnv, SpiderMetrics


@struct.dataclass
class Trajectory:
    """Per-step record of a batched rollout (leading axes ``[T, B]``).

    Attributes:
      qpos: ``[T, B, nq]`` generalised positions after each step (for rendering).
      reward, done, truncated: ``[T, B]``.
      obs_finite: ``[T, B]`` bool, every observation entry finite.
      foot_z: ``[T, B, n_legs]`` foot-sphere centre heights (from the last physics sub-step's
        kinematics); below the foot radius means the foot penetrates the floor.
      metrics: ``SpiderMetrics`` with ``[T, B]`` leaves.
    """

    qpos: jax.Array
    reward: jax.Array
    done: jax.Array
    truncated: jax.Array
    obs_finite: jax.Array
    foot_z: jax.Array
    metrics: SpiderMetrics


def make_rollout(env: SpiderEnv) -> Callable[[EnvState, jax.Array], tuple[EnvState, Trajectory]]:
    """Jitted ``(states [B], actions [T, B, n, max_dim]) -> (final states [B], Trajectory)``.

    ``jit(scan over T of vmap over B of env.step)``; it compiles once per (T, B). Episodes are
    not reset when they end: the physics simply continues (what a NaN/robustness check wants).
    """
    batched_step = jax.vmap(env.step)

    def body(state: EnvState, action: jax.Array) -> tuple[EnvState, Trajectory]:
        state = batched_step(state, action)
        record = Trajectory(
            state.sim.data.qpos,
            state.reward,
            state.done,
            state.truncated,
            jnp.all(jnp.isfinite(state.obs), axis=-1),
            env.foot_heights(state),
            state.metrics,
        )
        return state, record

    return jax.jit(lambda states, actions: jax.lax.scan(body, states, actions))


def reset_batch(env: SpiderEnv, key: jax.Array, batch: int) -> EnvState:
    """``batch`` independent resets (``EnvState`` with leading axis ``[batch]``)."""
    return jax.jit(jax.vmap(env.reset))(jax.random.split(key, batch))


def mujoco_rollout(
    model: mujoco.MjModel, qpos: np.ndarray, qvel: np.ndarray, ctrls: np.ndarray, frame_skip: int
) -> np.ndarray:
    """Plain MuJoCo (C, float64) from ``qpos [nq]``, ``qvel [nv]``: ``ctrls [T, nu]`` ->
    qpos ``[T, nq]``.

    Each control is held for ``frame_skip`` ``mj_step`` calls, as ``SpiderEnv.step`` does.
    """
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    data.qvel[:] = qvel
    out = np.empty((len(ctrls), model.nq))
    for k, ctrl in enumerate(ctrls):
        data.ctrl[:] = ctrl
        for _ in range(frame_skip):
            mujoco.mj_step(model, data)
        out[k] = data.qpos
    return out
