"""The greenhouse's composite action space (paper Table 1) and its decoding into hourly schedules.

Four sub-action spaces, in this order (52 dims in all):

=============  ==========  =====================================  =============================
name           dims        range (physical units)                 default (failed controller)
=============  ==========  =====================================  =============================
temperature    24          continuous [13, 25] °C, hourly heating  19 °C every hour (paper §5.3.3)
                           setpoint (ventilation opens 2 °C above)
co2            24          continuous [400, 700] ppm, hourly       550 ppm every hour
                           dosing setpoint
lighting       2           (start hour, end hour): discrete        (6, 18): a fixed 06:00-18:00
                           0..23 (Table 1) or continuous [0, 24]   lamp timer, the fallback a
                           with ``discrete_hours=False`` (§5.3.1)  grower keeps so a short winter
                                                                   day never leaves the crop dark
irrigation     2           (start hour, end hour), like lighting   (7, 17): ten hours of drip at
                                                                   the fixed rate (5 L/m²/day with
                                                                   the default 0.5 L/m²/h), ample
                                                                   except on the brightest days
=============  ==========  =====================================  =============================

Schedules: the lamps (irrigation) run during ``[start, end)`` in hours of the day, like a
timer: if ``end < start`` the interval wraps past midnight (lamps 22 -> 6 light the night,
which is common where night electricity is cheap); ``end == start`` is off for the day. A
sub-step contributes the fraction of its own interval that lies inside. (An earlier version
switched off whenever ``end <= start``: half of all random pairs meant "no water", a cliff that
made learning collapse.)
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from score_jax.core.spaces import CompositeSpace, SubSpace

SUBSPACE_NAMES = ("temperature", "co2", "lighting", "irrigation")
LIGHTING_DEFAULT = (6.0, 18.0)
IRRIGATION_DEFAULT = (7.0, 17.0)


def _hours(name: str, default: tuple[float, float], discrete: bool) -> SubSpace:
    if discrete:
        return SubSpace(
            name, "discrete", 2, (0.0, 0.0), (23.0, 23.0), default, n_choices=24, units="h"
        )
    return SubSpace(name, "continuous", 2, (0.0, 0.0), (24.0, 24.0), default, units="h")


def greenhouse_space(discrete_hours: bool = True) -> CompositeSpace:
    """The 4 sub-spaces of Table 1 (52 dims): temperature, co2, lighting, irrigation."""
    return CompositeSpace(
        (
            SubSpace.continuous("temperature", 24, 13.0, 25.0, 19.0, units="°C"),
            SubSpace.continuous("co2", 24, 400.0, 700.0, 550.0, units="ppm"),
            _hours("lighting", LIGHTING_DEFAULT, discrete_hours),
            _hours("irrigation", IRRIGATION_DEFAULT, discrete_hours),
        )
    )


def on_fraction(start: jax.Array, end: jax.Array, substeps_per_hour: int) -> jax.Array:
    """Fraction of every sub-step inside ``[start, end)`` hours: ``[] , [] -> [24, substeps]``.

    ``end < start`` wraps past midnight (``[start, 24) + [0, end)``); ``end == start`` is off.
    """
    dt = 1.0 / substeps_per_hour
    t0 = jnp.arange(24 * substeps_per_hour, dtype=jnp.float32).reshape(24, substeps_per_hour) * dt

    def inside(lo, hi):
        return jnp.clip(jnp.minimum(hi, t0 + dt) - jnp.maximum(lo, t0), 0.0, dt) / dt

    wrapped = inside(start, 24.0) + inside(0.0, end)
    return jnp.where(end > start, inside(start, end), jnp.where(end < start, wrapped, 0.0))


def decode_action(
    space: CompositeSpace, action: jax.Array, substeps_per_hour: int
) -> dict[str, jax.Array]:
    """Normalised ``[n, max_dim]`` action -> physical hourly schedules.

    ``space.to_physical`` clips out-of-range values, turns NaN into the default and snaps
    discrete dims to whole hours. Returns ``temp_sp [24]`` °C, ``co2_sp [24]`` ppm,
    ``lamp [24, substeps]`` and ``irrigation [24, substeps]`` on-fractions in [0, 1], and the
    physical hours ``lighting [2]``, ``irrigation_hours [2]``.
    """
    x = space.to_physical(action)
    lit = x[space.index("lighting"), :2]
    irr = x[space.index("irrigation"), :2]
    return {
        "temp_sp": x[space.index("temperature"), :24],
        "co2_sp": x[space.index("co2"), :24],
        "lamp": on_fraction(lit[0], lit[1], substeps_per_hour),
        "irrigation": on_fraction(irr[0], irr[1], substeps_per_hour),
        "lighting_hours": lit,
        "irrigation_hours": irr,
    }
