"""A documented grower heuristic: the "expert" reference policy for the greenhouse.

Rules of thumb of tomato growing, decided each morning from today's weather (which the
observation also contains). The one quantity they all key on is the day's light sum at the
crop, the daily light integral (DLI, mol PAR m^-2 d^-1): today's global radiation through the
cover, plus the lamps' light when they are planned. Two guideline levels bound it: "poor
light" below ``DARK_DLI`` = 10 and "abundant light" above ``BRIGHT_DLI`` = 25 mol m^-2 d^-1
(a tomato crop grows well at a 24-h mean of about 17 °C in poor light and about 22 °C in
abundant light; e.g. the Wageningen-based guideline of the Saudi Estidamah programme, "Effect
of temperature on yield of tomato"). Between the two levels every rule interpolates linearly.

- Lamps (HPS): supplementary light whenever the sun alone does not give abundant light
  (natural DLI below ``BRIGHT_DLI``), as a 16-h photoperiod from 05:00 to 21:00 (tomato
  tolerates at most 16-18 h of light a day); off on bright days. This replaces day length as
  the criterion: a dull spring day at a high latitude is long but still dark.
- Temperature, light-dependent (the "temperature-light balance" that climate computers
  implement; Nederhoff 2021, "The temperature-light balance", NZGrower: tomatoes prefer about
  18 °C on a dull winter day and 24 °C or more in summer): the heating setpoint of the light
  period (sun or lamps) rises from ``DAY_TEMP[0]`` = 18 °C at poor light to ``DAY_TEMP[1]`` =
  24 °C at abundant light. The 24-h mean target rises from the guideline's ``MEAN_TEMP[0]`` =
  17 °C to ``MEAN_TEMP[1]`` = 22 °C over the same range, and the night
  setpoint is whatever makes the day's mean hit it (the 24-h mean, or temperature-integral,
  rule: growth follows the mean temperature, so a warm light period is balanced by a cooler
  night), kept between ``NIGHT_MIN`` = 15 °C and the day setpoint. The assimilates of a bright
  day can feed the faster growth of a warm day; on a dark day a warm greenhouse only burns
  them (respiration). The ventilation line follows 2 °C above (the climate model).
- CO2: enrich to 800 ppm in the light period (clipped by the action space to its 700 ppm
  maximum), ambient 400 ppm in the dark (no dosing at night: the crop does not use it).
- Irrigation: daytime drip from 07:00 to 17:00, when the crop transpires.

The rules were written from these guidelines, not fitted to the simulator. ``expert_action``
is pure jnp (jit/vmap-able) and returns the normalised ``[n, max_dim]`` action through
``space.from_physical``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from envs.base import EnvState
from envs.greenhouse.climate import ClimateParams

DARK_DLI, BRIGHT_DLI = 10.0, 25.0  # mol PAR m^-2 d^-1: poor / abundant light at the crop
DAY_TEMP = (18.0, 24.0)  # °C heating setpoint in the light period: poor -> abundant light
MEAN_TEMP = (17.0, 22.0)  # °C 24-h mean target: poor -> abundant light
NIGHT_MIN = 15.0  # °C: the night setpoint never goes below this
LIGHT_CO2, DARK_CO2 = 800.0, 400.0  # ppm (800 is clipped to the space's 700)
LAMP_HOURS = (5.0, 21.0)  # a 16-h photoperiod with the lamps
IRRIGATION_HOURS = (7.0, 17.0)


def natural_dli(ghi_today: jax.Array, params: ClimateParams) -> jax.Array:
    """Daily light integral of the sun at the crop, mol PAR m^-2 d^-1, from ``ghi [24]`` W/m²."""
    return jnp.sum(ghi_today) * 3600.0 * params.transmission * params.par_per_joule * 1e-6


def light_level(dli: jax.Array) -> jax.Array:
    """0 at poor light (``DARK_DLI``) -> 1 at abundant light (``BRIGHT_DLI``), linear, clipped."""
    return jnp.clip((dli - DARK_DLI) / (BRIGHT_DLI - DARK_DLI), 0.0, 1.0)


def expert_schedule(ghi_today: jax.Array, params: ClimateParams | None = None) -> jax.Array:
    """Today's hourly global radiation ``[24]`` W/m² -> physical action ``[4, 24]``.

    ``params``: the greenhouse's cover transmission and lamps (``ClimateParams``; defaults if
    None), which turn radiation and lamp hours into light at the crop.
    Rows: temperature setpoint [24], CO2 setpoint [24], lighting (start, end) in the first two
    columns, irrigation (start, end) in the first two columns (other columns zero).
    """
    p = ClimateParams() if params is None else params
    hours = jnp.arange(24, dtype=jnp.float32)
    sunny = ghi_today > 0.0
    natural = natural_dli(ghi_today, p)
    lamps_planned = natural < BRIGHT_DLI
    lamp_start = jnp.where(lamps_planned, LAMP_HOURS[0], 0.0)
    lamp_end = jnp.where(lamps_planned, LAMP_HOURS[1], 0.0)
    lamps_on = (hours >= lamp_start) & (hours < lamp_end)
    light = sunny | lamps_on
    lamp_mol_per_hour = p.lamp_power * p.lamp_efficacy * 3600.0 * 1e-6
    level = light_level(natural + jnp.sum(lamps_on) * lamp_mol_per_hour)
    day_temp = DAY_TEMP[0] + level * (DAY_TEMP[1] - DAY_TEMP[0])
    mean_temp = MEAN_TEMP[0] + level * (MEAN_TEMP[1] - MEAN_TEMP[0])
    light_hours = jnp.sum(light)
    night = (24.0 * mean_temp - light_hours * day_temp) / jnp.maximum(24.0 - light_hours, 1.0)
    night_temp = jnp.clip(night, NIGHT_MIN, day_temp)
    temp = jnp.where(light, day_temp, night_temp)
    co2 = jnp.where(light, LIGHT_CO2, DARK_CO2)
    pair = lambda a, b: jnp.zeros((24,), jnp.float32).at[0].set(a).at[1].set(b)  # noqa: E731
    rows = [temp, co2, pair(lamp_start, lamp_end), pair(*IRRIGATION_HOURS)]
    return jnp.stack(rows).astype(jnp.float32)


def expert_action(env, state: EnvState) -> jax.Array:
    """The grower heuristic for the day ``state`` is about to simulate: normalised ``[n, max_dim]``.

    ``env`` is a ``GreenhouseEnv``; works under ``jit`` and ``vmap`` (batched ``state``).
    """
    sim = state.sim
    today = env.weather.day(sim.start_doy + sim.day)
    physical = expert_schedule(today.ghi, env.climate_params)
    return env.space.from_physical(physical[:, : env.space.max_dim])
