"""The greenhouse observation (paper §5.3.1, Table 1): 225 numbers in [-1, 1].

Layout (in this order):

==========  ====  =============================================================  ==============
block       size  content                                                        physical range
==========  ====  =============================================================  ==============
indoor      96    previous simulated day, 24 hourly values each of: air          see INDOOR_RANGES
                  temperature, relative humidity, CO2, PAR at the canopy
outdoor     120   current simulated day (the day the action will act on), 24     see OUTDOOR_RANGES
                  hourly values each of: global radiation, air temperature,
                  relative humidity, wind speed, sky ("virtual atmospheric")
                  temperature
crop        9     days planted, watering volume (last day), drainage volume      see CROP_RANGES
                  (last day), LAI, plant dry weight (living above-ground,
                  W - W_m), node number (branches and leaves), cumulative fruit
                  fresh weight, cumulative fruit dry weight, cumulative fruit
                  number
==========  ====  =============================================================  ==============

Why 225 and not the paper's 223: Table 1 itemises 4 x 24 + 5 x 24 hourly values and nine crop
quantities, which is 225; the paper's total of 223 does not say which two it leaves out, so we
keep every listed item.

Normalisation: each quantity ``x`` with fixed physical range ``[lo, hi]`` becomes
``clip(2 (x - lo) / (hi - lo) - 1, -1, 1)``. The ranges are fixed (not data-dependent), so the
same number means the same thing in every run and every weather file.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from envs.greenhouse.weather import Weather

INDOOR_RANGES = (
    ("temperature_in", 0.0, 40.0),  # °C
    ("humidity_in", 0.0, 100.0),  # %
    ("co2_in", 200.0, 1200.0),  # ppm
    ("par_in", 0.0, 2000.0),  # µmol m^-2 s^-1
)
OUTDOOR_RANGES = (
    ("radiation_out", 0.0, 1200.0),  # W/m²
    ("temperature_out", -30.0, 45.0),  # °C
    ("humidity_out", 0.0, 100.0),  # %
    ("wind_out", 0.0, 20.0),  # m/s
    ("sky_temperature", -60.0, 40.0),  # °C
)
CROP_RANGES = (
    ("days_planted", 0.0, 365.0),  # days
    ("watering", 0.0, 15.0),  # L/m² per day
    ("drainage", 0.0, 15.0),  # L/m² per day
    ("lai", 0.0, 5.0),  # m²/m²
    ("plant_dry_weight", 0.0, 3000.0),  # g/m²
    ("nodes", 0.0, 120.0),  # nodes per plant
    ("fruit_fresh_weight", 0.0, 60.0),  # kg/m², cumulative harvest
    ("fruit_dry_weight", 0.0, 3600.0),  # g/m², cumulative harvest
    ("fruit_number", 0.0, 600.0),  # fruits/m², cumulative harvest
)
OBSERVATION_SIZE = 24 * len(INDOOR_RANGES) + 24 * len(OUTDOOR_RANGES) + len(CROP_RANGES)


def observation_names() -> list[str]:
    """One name per observation entry, e.g. ``"temperature_in[07]"``."""
    names = [f"{n}[{h:02d}]" for n, _, _ in INDOOR_RANGES for h in range(24)]
    names += [f"{n}[{h:02d}]" for n, _, _ in OUTDOOR_RANGES for h in range(24)]
    return names + [n for n, _, _ in CROP_RANGES]


def _bounds(ranges, repeat: int) -> tuple[np.ndarray, np.ndarray]:
    lo = np.repeat(np.asarray([r[1] for r in ranges], np.float32), repeat)
    hi = np.repeat(np.asarray([r[2] for r in ranges], np.float32), repeat)
    return lo, hi


_LO, _HI = (
    np.concatenate(x)
    for x in zip(
        _bounds(INDOOR_RANGES, 24),
        _bounds(OUTDOOR_RANGES, 24),
        _bounds(CROP_RANGES, 1),
        strict=True,
    )
)


def normalise(x: jax.Array) -> jax.Array:
    """Physical ``[225]`` -> ``[225]`` in [-1, 1] with the fixed ranges above."""
    return jnp.clip(2.0 * (x - _LO) / (_HI - _LO) - 1.0, -1.0, 1.0)


def denormalise(obs: jax.Array) -> jax.Array:
    """Inverse of ``normalise`` (exact inside the ranges)."""
    return _LO + (obs + 1.0) * 0.5 * (_HI - _LO)


def build_observation(indoor: jax.Array, next_weather: Weather, crop: jax.Array) -> jax.Array:
    """``indoor [4, 24]`` (last day), ``next_weather`` (fields ``[24]``), ``crop [9]`` ->
    ``[225]``."""
    outdoor = jnp.stack(
        [
            next_weather.ghi,
            next_weather.temp_air,
            next_weather.rh,
            next_weather.wind,
            next_weather.temp_sky,
        ]
    )
    x = jnp.concatenate([indoor.reshape(-1), outdoor.reshape(-1), crop])
    return normalise(x.astype(jnp.float32))
