"""A documented grower heuristic: the "expert" reference policy for the greenhouse.

Rules of thumb of Dutch tomato growing (e.g. Heuvelink 2005, "Tomatoes", ch. 4 and 9),
decided each morning from today's weather (which the observation also contains):

- Temperature: 21 °C heating setpoint in the light period (daylight or lamps on), 17 °C at
  night (a 24-h mean near 19 °C; the warm day drives photosynthesis and fruit growth, the
  cool night saves energy and respiration). The ventilation line follows 2 °C above.
- CO2: enrich to 800 ppm in the light period (clipped by the action space to its 700 ppm
  maximum), ambient 400 ppm in the dark (no dosing at night: the crop does not use it).
- Lamps: on short days (fewer than ``SHORT_DAY_HOURS`` hours of sun), extend the day from
  05:00 to 21:00 (a 16-h photoperiod); off (start = end) once the days are long.
- Irrigation: daytime drip from 07:00 to 17:00, when the crop transpires.

``expert_action`` is pure jnp (jit/vmap-able) and returns the normalised ``[n, max_dim]``
action through ``space.from_physical``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from envs.base import EnvState

DAY_TEMP, NIGHT_TEMP = 21.0, 17.0  # °C
LIGHT_CO2, DARK_CO2 = 800.0, 400.0  # ppm (800 is clipped to the space's 700)
LAMP_HOURS = (5.0, 21.0)
IRRIGATION_HOURS = (7.0, 17.0)
SHORT_DAY_HOURS = 14  # fewer sunny hours than this: supplementary lighting


def expert_schedule(ghi_today: jax.Array) -> jax.Array:
    """Today's hourly global radiation ``[24]`` W/m² -> physical action ``[4, 24]``.

    Rows: temperature setpoint [24], CO2 setpoint [24], lighting (start, end) in the first two
    columns, irrigation (start, end) in the first two columns (other columns zero).
    """
    hours = jnp.arange(24, dtype=jnp.float32)
    sunny = ghi_today > 0.0
    short_day = jnp.sum(sunny) < SHORT_DAY_HOURS
    lamp_start = jnp.where(short_day, LAMP_HOURS[0], 0.0)
    lamp_end = jnp.where(short_day, LAMP_HOURS[1], 0.0)
    lamps_on = (hours >= lamp_start) & (hours < lamp_end)
    light = sunny | lamps_on
    temp = jnp.where(light, DAY_TEMP, NIGHT_TEMP)
    co2 = jnp.where(light, LIGHT_CO2, DARK_CO2)
    pair = lambda a, b: jnp.zeros((24,), jnp.float32).at[0].set(a).at[1].set(b)  # noqa: E731
    return jnp.stack([temp, co2, pair(lamp_start, lamp_end), pair(*IRRIGATION_HOURS)]).astype(jnp.float32)


def expert_action(env, state: EnvState) -> jax.Array:
    """The grower heuristic for the day ``state`` is about to simulate: normalised ``[n, max_dim]``.

    ``env`` is a ``GreenhouseEnv``; works under ``jit`` and ``vmap`` (batched ``state``).
    """
    sim = state.sim
    today = env.weather.day(sim.start_doy + sim.day)
    physical = expert_schedule(today.ghi)
    return env.space.from_physical(physical[:, : env.space.max_dim])
