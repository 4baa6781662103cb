"""The MJX physics step the Spider uses: ``mjx.step`` minus work this model never needs.

``mjx.step`` = ``forward`` (position, sensors, velocity, actuation, acceleration, constraint
solve) + the integrator. Two of its parts cost time here for nothing:

* ``fwd_acceleration`` adds ``xfrc_applied`` (Cartesian forces on bodies) through the
  Jacobian of *every* body (``[nbody, nv, 3]`` per env and physics step) even when those
  forces are zero, which XLA cannot know because they live in the loop carry. The Spider never
  applies Cartesian forces, so ``lean_step`` skips that term (``benchmarks/spider_throughput.py``
  measures both variants).
* The model has no sensors, so the sensor stages are no-ops either way.

``lean_step`` is otherwise the same sequence of public MJX stages, so it returns the same
``mjx.Data`` as ``mjx.step`` whenever ``xfrc_applied`` is zero (``tests/test_spider.py``
checks equality). It needs ``solve_m`` from MJX's ``_src`` (it is not re-exported); if a
future MJX moves it, ``physics_step`` falls back to ``mjx.step``.
"""

from __future__ import annotations

from mujoco import mjx

try:  # pinned mujoco-mjx 3.17: dense/sparse M^-1 x; not part of the public API.
    from mujoco.mjx._src.smooth import solve_m as _solve_m
except ImportError:  # pragma: no cover - only on an MJX without it
    _solve_m = None


def lean_step(m: mjx.Model, d: mjx.Data) -> mjx.Data:
    """One Euler physics step without the ``xfrc_applied`` term (see module docstring).

    Requires the JAX implementation, the Euler integrator and ``xfrc_applied == 0``.
    """
    d = mjx.fwd_position(m, d)
    d = mjx.fwd_velocity(m, d)
    d = mjx.fwd_actuation(m, d)
    qfrc_smooth = d.qfrc_passive - d.qfrc_bias + d.qfrc_actuator + d.qfrc_applied
    d = d.replace(qfrc_smooth=qfrc_smooth, qacc_smooth=_solve_m(m, d, qfrc_smooth))
    d = mjx.solve(m, d)
    return mjx.euler(m, d)


def physics_step(m: mjx.Model, d: mjx.Data, lean: bool = True) -> mjx.Data:
    """``lean_step`` when possible, else ``mjx.step`` (Python-level choice, static under jit)."""
    if lean and _solve_m is not None and m.opt.integrator == mjx.IntegratorType.EULER:
        return lean_step(m, d)
    return mjx.step(m, d)
