"""An open-loop sinusoidal gait for any leg table: a reference controller, not a learned one.

Used by the tests (the gait must walk forward further than doing nothing) and by the render
CLI. Legs are split into two groups that alternate, like a trot / tripod gait: the diagonal
Ant legs pair up (front-left with back-right, front-right with back-left) and each side's long
middle leg joins the group of the diagonal legs on the other side. In its stance half-cycle a
leg swings its foot backwards with the hip while its pitch joints press down; in the swing
half-cycle it lifts and swings forwards. Legs pointing straight forwards/backwards (the rigid
pegs) cannot push along x with a yaw hip, so their hip stays at 0.

The motors are Ant's torque motors (gear 150 on light legs), so joint angles lag the commands
and large commands make the body hop and flip; ``lift_phase`` shifts the pitch commands
relative to the hip commands to compensate. The defaults were chosen by a grid search on the
default body in plain MuJoCo (period 0.3-1.0 s, amplitudes 0.1-1.0, four lift phases, 5-10
noisy resets each): small commands at 2 Hz walk forward on every reset (1.9-3.5 m in 10 s,
never unhealthy) while zero action drifts by at most 0.3 m.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import jax.numpy as jnp
import numpy as np

from envs.spider.legs import LegSpec
from score_jax.core.spaces import CompositeSpace


@dataclasses.dataclass(frozen=True)
class GaitParams:
    """Open-loop gait shape (normalised command units, seconds, radians)."""

    period: float = 0.5
    hip_amplitude: float = 0.15
    lift_amplitude: float = 0.2
    lift_phase: float = -0.5 * math.pi


def _leg_coefficients(leg: LegSpec) -> tuple[float, float]:
    """(hip sign, group phase) of a leg from its mounting angle.

    A positive hip angle moves the foot along (-sin a, cos a), i.e. backwards for a leg on the
    left (sin a > 0); the hip sign makes every leg's stance push the body towards +x.
    """
    a = math.radians(leg.angle_deg)
    side = math.sin(a)
    hip_sign = 0.0 if abs(side) < 1e-6 else math.copysign(1.0, side)
    diagonal = math.sin(2.0 * a)
    group = diagonal if abs(diagonal) > 1e-6 else -side
    phase = 0.0 if group > 0 else math.pi
    return hip_sign, phase


def gait_tables(
    legs: Sequence[LegSpec], space: CompositeSpace
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Static per-dimension tables ``[n, max_dim]``: hip weights, pitch weights, leg phases."""
    hip = np.zeros((space.n, space.max_dim), np.float32)
    pitch = np.zeros((space.n, space.max_dim), np.float32)
    phase = np.zeros((space.n, space.max_dim), np.float32)
    for i, leg in enumerate(legs):
        hip_sign, leg_phase = _leg_coefficients(leg)
        phase[i, :] = leg_phase
        for j, joint in enumerate(leg.joints):
            if joint.kind == "hip":
                hip[i, j] = hip_sign
            else:
                pitch[i, j] = 1.0
    return hip, pitch, phase


def sinusoidal_gait(
    legs: Sequence[LegSpec],
    space: CompositeSpace,
    t: jnp.ndarray,
    params: GaitParams = GaitParams(),
) -> jnp.ndarray:
    """Normalised action ``[..., n, max_dim]`` of the gait at time(s) ``t`` (seconds, shape
    ``[...]``).

    hip_i(t) = A_h * s_i * sin(w t + phi_i);  pitch_i(t) = A_l * cos(w t + phi_i + lift_phase)
    """
    hip, pitch, phase = gait_tables(legs, space)
    theta = 2.0 * jnp.pi / params.period * jnp.asarray(t, jnp.float32)[..., None, None] + phase
    action = params.hip_amplitude * hip * jnp.sin(theta) + params.lift_amplitude * pitch * jnp.cos(
        theta + params.lift_phase
    )
    return jnp.clip(action, -1.0, 1.0)


def gait_actions(
    legs: Sequence[LegSpec],
    space: CompositeSpace,
    n_steps: int,
    dt: float,
    params: GaitParams = GaitParams(),
) -> jnp.ndarray:
    """``[n_steps, n, max_dim]`` gait actions for env steps 0..n_steps-1 of length ``dt``."""
    return sinusoidal_gait(legs, space, jnp.arange(n_steps) * dt, params)
