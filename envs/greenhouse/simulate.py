"""One simulated day: 24 hourly steps (``lax.scan``) coupling climate, crop and water.

Each hour has ``substeps_per_hour`` sub-steps. A sub-step, in order:
 1. water-stress factor of the slab (``water.stress_factor``);
 2. PAR at the canopy (sun through the cover + lamps) and gross photosynthesis / maintenance
    respiration of the crop at the current indoor temperature and CO2 (``crop.py``; the
    day's photoperiod factor is computed once from the weather and the lamp schedule);
 3. transpiration from indoor radiation and vapour-pressure deficit (``water.py``);
 4. climate update under the heating / ventilation / CO2 controllers (``climate.py``), with
    the crop's CO2 uptake and transpiration as sources;
 5. slab water balance with the irrigation schedule.
The crop state itself changes once per day (``crop.crop_update``) from the day's sums.

Everything is float32, elementwise and branch-free, so ``vmap`` over thousands of
greenhouses turns every line into one vectorised loop.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from envs.greenhouse.climate import (
    ClimateParams,
    ClimateState,
    climate_substep,
    relative_humidity,
    saturation_pressure,
    vapour_density,
)
from envs.greenhouse.crop import (
    CropDay,
    CropParams,
    CropState,
    gross_photosynthesis,
    maintenance_respiration,
    node_rate_factor,
    photoperiod_factor,
)
from envs.greenhouse.water import WaterParams, potential_transpiration, stress_factor, water_update
from envs.greenhouse.weather import Weather

CO2_KG_PER_UMOL = 44.01e-9  # kg CO2 per µmol
CH2O_TO_CO2 = 44.01 / 30.03  # g CO2 per g CH2O


@struct.dataclass
class DayResult:
    """Output of one simulated day.

    Attributes:
      climate: indoor climate at midnight (carried to the next day).
      theta: slab water at midnight, L/m².
      crop_day: the day's sums driving the crop update.
      indoor: ``[4, 24]`` hourly indoor temperature °C, relative humidity %, CO2 ppm and PAR
        µmol m^-2 s^-1 (hourly means of the sub-steps).
      heating_mj, co2_kg, electricity_kwh: energy and CO2 used, per m².
      irrigation_l, transpiration_l, drainage_l: water flows of the day, L/m².
    """

    climate: ClimateState
    theta: jax.Array
    crop_day: CropDay
    indoor: jax.Array
    heating_mj: jax.Array
    co2_kg: jax.Array
    electricity_kwh: jax.Array
    irrigation_l: jax.Array
    transpiration_l: jax.Array
    drainage_l: jax.Array


def simulate_day(
    climate: ClimateState,
    theta: jax.Array,
    crop: CropState,
    day_weather: Weather,
    schedule: dict[str, jax.Array],
    crop_params: CropParams,
    climate_params: ClimateParams,
    water_params: WaterParams,
    substeps_per_hour: int,
) -> DayResult:
    """Integrate one day.

    Args:
      climate, theta, crop: state at the start of the day.
      day_weather: ``Weather`` with ``[24]`` fields (``Weather.day``).
      schedule: from ``actions.decode_action``: ``temp_sp [24]``, ``co2_sp [24]``,
        ``lamp [24, S]``, ``irrigation [24, S]`` (S = ``substeps_per_hour``).
    """
    cp, kp, wp = crop_params, climate_params, water_params
    n_sub = substeps_per_hour
    dt = 3600.0 / n_sub
    dt_h = 1.0 / n_sub
    # Quantities constant over the day: the crop state only changes at midnight.
    w_living = crop.w - crop.wm
    vapour_out = vapour_density(
        saturation_pressure(day_weather.temp_air) * day_weather.rh / 100.0, day_weather.temp_air
    )
    lamp_par = kp.lamp_power * kp.lamp_efficacy  # µmol m^-2 s^-1 with lamps fully on
    lamp_rad = kp.lamp_power * kp.lamp_radiation  # W/m² radiation at the canopy
    pg_to_g_per_h = cp.d_conv / 24.0  # µmol CO2 m^-2 s^-1 -> g CH2O m^-2 h^-1
    # Hours of light today (sun or lamps): long days injure the leaves (crop.photoperiod_factor).
    light_hours = jnp.sum(
        jnp.maximum((day_weather.ghi > 0.0).astype(jnp.float32), jnp.mean(schedule["lamp"], axis=1))
    )
    pp_factor = photoperiod_factor(light_hours, cp)

    def hour(carry, x):
        clim, th = carry
        acc = {
            k: 0.0
            for k in (
                "t",
                "rh",
                "co2",
                "par",
                "pg",
                "rm",
                "dn",
                "heat",
                "dose",
                "irr",
                "tr",
                "drain",
                "fw",
            )
        }
        for k in range(n_sub):
            lamp, irr_on = x["lamp"][k], x["irr"][k]
            f_w = stress_factor(th, wp)
            par = x["ghi"] * kp.transmission * kp.par_per_joule + lamp * lamp_par
            pg = (
                f_w * pp_factor * gross_photosynthesis(par, clim.co2, clim.temp, crop.lai, cp)
            )  # µmol m^-2 s^-1
            rm = maintenance_respiration(clim.temp, w_living, cp)  # g CH2O m^-2 h^-1
            uptake = pg * CO2_KG_PER_UMOL - rm * CH2O_TO_CO2 / 3.6e6  # kg CO2 m^-2 s^-1
            es = saturation_pressure(clim.temp)
            vpd = es - clim.vapour * 8.314 * (clim.temp + 273.15) / 18.015  # kPa
            radiation = x["ghi"] * kp.transmission + lamp * lamp_rad
            transp = f_w * potential_transpiration(radiation, vpd, crop.lai, wp)  # kg m^-2 s^-1
            t_prev = clim.temp
            clim, flux = climate_substep(
                clim,
                temp_out=x["temp_air"],
                temp_sky=x["temp_sky"],
                vapour_out=x["vapour_out"],
                wind=x["wind"],
                ghi=x["ghi"],
                lamp=lamp,
                temp_sp=x["temp_sp"],
                co2_sp=x["co2_sp"],
                uptake=uptake,
                transpiration=transp,
                dt=dt,
                p=kp,
            )
            th, transpired, drained = water_update(
                th, irr_on * wp.irrigation_rate * dt_h, transp * dt, wp
            )
            t_mid = 0.5 * (t_prev + clim.temp)
            acc["t"] += t_mid * dt_h
            acc["rh"] += relative_humidity(clim.vapour, clim.temp) * dt_h
            acc["co2"] += clim.co2 * dt_h
            acc["par"] += par * dt_h
            acc["pg"] += pg * pg_to_g_per_h * dt_h
            acc["rm"] += rm * dt_h
            acc["dn"] += cp.node_rate_max / 24.0 * node_rate_factor(t_mid) * dt_h
            acc["heat"] += flux.heat * dt
            acc["dose"] += flux.dose * dt
            acc["irr"] += irr_on * wp.irrigation_rate * dt_h
            acc["tr"] += transpired
            acc["drain"] += drained
            acc["fw"] += f_w * dt_h
        return (clim, th), acc

    xs = {
        "ghi": day_weather.ghi,
        "temp_air": day_weather.temp_air,
        "temp_sky": day_weather.temp_sky,
        "wind": day_weather.wind,
        "vapour_out": vapour_out,
        "temp_sp": schedule["temp_sp"],
        "co2_sp": schedule["co2_sp"],
        "lamp": schedule["lamp"],
        "irr": schedule["irrigation"],
    }
    (climate, theta), h = jax.lax.scan(hour, (climate, theta), xs)

    daylight = (day_weather.ghi > 0.0).astype(jnp.float32)
    t_daytime = jnp.sum(h["t"] * daylight) / jnp.maximum(jnp.sum(daylight), 1.0)
    crop_day = CropDay(
        pg=jnp.sum(h["pg"]),
        rm=jnp.sum(h["rm"]),
        dn=jnp.sum(h["dn"]),
        t_avg=jnp.mean(h["t"]),
        t_daytime=jnp.where(jnp.sum(daylight) > 0, t_daytime, jnp.mean(h["t"])),
        water=jnp.mean(h["fw"]),
    )
    return DayResult(
        climate=climate,
        theta=theta,
        crop_day=crop_day,
        indoor=jnp.stack([h["t"], h["rh"], h["co2"], h["par"]]),
        heating_mj=jnp.sum(h["heat"]) / 1e6,
        co2_kg=jnp.sum(h["dose"]),
        electricity_kwh=jnp.sum(schedule["lamp"]) * dt_h * kp.lamp_power / 1000.0,
        irrigation_l=jnp.sum(h["irr"]),
        transpiration_l=jnp.sum(h["tr"]),
        drainage_l=jnp.sum(h["drain"]),
    )
