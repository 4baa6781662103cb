"""Greenhouse climate: air temperature, CO2 and humidity balances with their controllers.

A lumped single-zone model in the spirit of Van Henten (2003, "Sensitivity analysis of an
optimal control problem in greenhouse climate management", Biosystems Engineering 85(3):
355-364): per m² of floor,

  c_cap,q dT/dt = Q_heat + Q_sun + Q_lamp - s U_cover (T - T_out) - s U_sky (T - T_sky)
                  - c_air (leak + vent) (T - T_out)
  h dC/dt       = (dose - uptake) / kappa - (leak + vent) (C - C_out)
  h dH/dt       = transpiration - (leak + vent) (H - H_out) - g_cond (H - H_sat(T_cover))^+

with s < 1 while the energy screen is drawn, T in °C, C in ppm, H the absolute humidity in
kg/m³, ``leak``/``vent`` volume fluxes in m³ air per m² floor per s. Parameters follow Van
Henten (2003) where his lettuce house fits a Venlo tomato house (heat capacity 30 kJ m^-2 K^-1,
air heat capacity 1290 J m^-3 K^-1, mean height 4.1 m, sensible solar fraction 0.2); the
others are typical glasshouse values, cited per field.

Controllers (what a climate computer does with the hourly setpoints):
- heating: the heat that brings T to the heating setpoint by the end of the sub-step,
  clipped to [0, heat_max] (capacity-limited tracking);
- ventilation: (a) humidity: the flux that removes the transpired vapour at ``rh_max``
  (growers keep RH below ~85 % against Botrytis), only with outside air drier than that and
  only as far as spare heating capacity makes up for its heat loss (temperature first);
  (b) temperature, only while the heating is off: the extra flux that brings T down to the
  ventilation setpoint (heating setpoint + ``vent_offset``) by the end of the sub-step, all
  the vents can give if even that is not enough; the sum is at most vent_max;
- CO2: the dose that reaches the CO2 setpoint by the end of the sub-step, clipped to
  [0, co2_max]; it never removes CO2, and ventilation/leakage lose it;
- energy screen: drawn in dark hours colder than ``screen_temp`` outside (standard in
  heated tomato houses), cutting cover and sky losses by ``screen_saving``;
- lamps (HPS): on/off fraction from the lighting schedule; they add PAR, sensible heat and
  radiation (transpiration), and use electricity.

Each balance is linear in its state over a sub-step (fluxes frozen at their start-of-step
values), and is advanced with its exact exponential solution, so the update is stable for any
sub-step length.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

KAPPA_CO2 = 1.83e-6  # kg CO2 per m³ air per ppm (44 g/mol / 24.05 L/mol at 20 °C, 101.3 kPa)
CO2_FLOOR = 50.0  # ppm: photosynthesis stops near the CO2 compensation point


@struct.dataclass
class ClimateParams:
    """Greenhouse physics and equipment (a pytree: vmap or swap it)."""

    transmission: float = (
        0.70  # fraction of outdoor global radiation reaching the crop (glass + structure)
    )
    par_per_joule: float = (
        2.1  # µmol PAR per J of global radiation (0.46 PAR fraction x 4.57 µmol/J)
    )
    solar_heat: float = (
        0.2  # c_rad,q,gh (Van Henten 2003): sensible heat per W of outdoor radiation
    )
    heat_capacity: float = 3.0e4  # c_cap,q (Van Henten 2003), J m^-2 K^-1
    air_heat_capacity: float = 1290.0  # c_cap,q,v (Van Henten 2003), J m^-3 K^-1
    height: float = 4.1  # c_cap,c = c_cap,h (Van Henten 2003), m: air volume per floor area
    u_cover: float = 4.5  # W m^-2 K^-1, convective/conductive loss through single glass, still air
    u_cover_wind: float = 0.45  # extra W m^-2 K^-1 per m/s of wind
    u_sky: float = (
        1.2  # W m^-2 K^-1, long-wave loss to the sky (U_cover + U_sky ~ Van Henten's 6.1)
    )
    leakage: float = 2.0e-4  # m/s (~0.2 air changes per hour at 4.1 m)
    leakage_wind: float = 1.0e-4  # extra m/s per m/s of wind
    vent_max: float = 0.03  # m/s, fully open vents (~26 air changes per hour)
    vent_offset: float = 2.0  # °C: vents open above heating setpoint + this
    rh_max: float = 85.0  # %: vents open to keep the relative humidity below this (disease control)
    # W/m² of floor, heating capacity (pipe rail + growing pipe): cover losses of ~6-7 W m^-2 K^-1
    # at a 35 K design difference, times a cover/floor area ratio of ~1.3.
    heat_max: float = 300.0
    screen_saving: float = (
        0.35  # fraction of cover + sky losses an energy screen saves (typically 0.25-0.45)
    )
    screen_temp: float = 12.0  # °C: the screen is drawn on dark hours colder than this outside
    co2_out: float = 410.0  # ppm, outdoor CO2
    co2_max: float = 5.0e-6  # kg m^-2 s^-1, CO2 dosing capacity (180 kg/ha/h, pure CO2)
    lamp_power: float = 110.0  # W/m² electric, HPS supplementary lighting
    lamp_efficacy: float = 1.8  # µmol PAR per J electric (modern HPS)
    lamp_heat: float = 0.6  # fraction of lamp power that heats the air directly
    lamp_radiation: float = 0.4  # fraction reaching the canopy as radiation (drives transpiration)
    cover_weight: float = (
        0.4  # cover temperature = T_out + cover_weight (T - T_out), for condensation
    )
    condensation: float = 3.0e-3  # m/s, vapour transfer coefficient to a cold cover


@struct.dataclass
class ClimateState:
    """Indoor air, every field ``[]`` float32: temperature °C, CO2 ppm, absolute humidity kg/m³."""

    temp: jax.Array
    co2: jax.Array
    vapour: jax.Array


def saturation_pressure(temp: jax.Array) -> jax.Array:
    """Saturated vapour pressure, kPa, at ``temp`` °C (Tetens 1930)."""
    return 0.61078 * jnp.exp(17.27 * temp / (temp + 237.3))


def vapour_density(pressure_kpa: jax.Array, temp: jax.Array) -> jax.Array:
    """Vapour pressure kPa at ``temp`` °C -> absolute humidity kg/m³ (ideal gas)."""
    return pressure_kpa * 1000.0 * 0.018015 / (8.314 * (temp + 273.15))


def relative_humidity(vapour: jax.Array, temp: jax.Array) -> jax.Array:
    """Absolute humidity kg/m³ at ``temp`` °C -> relative humidity, % (0..100)."""
    return 100.0 * vapour / vapour_density(saturation_pressure(temp), temp)


def initial_climate(temp: jax.Array, co2: jax.Array, rh: jax.Array) -> ClimateState:
    """Indoor air at ``temp`` °C, ``co2`` ppm and ``rh`` % relative humidity."""
    temp = jnp.asarray(temp, jnp.float32)
    return ClimateState(
        temp,
        jnp.asarray(co2, jnp.float32),
        vapour_density(saturation_pressure(temp) * rh / 100.0, temp),
    )


@struct.dataclass
class ClimateFlux:
    """What the equipment did over a sub-step (``[]`` each): heating W/m², CO2 dose
    kg m^-2 s^-1, ventilation m/s."""

    heat: jax.Array
    dose: jax.Array
    vent: jax.Array


VENT_BISECTIONS = 16  # halvings of the spare vent range: the flux is resolved to 2^-16 of it


@dataclasses.dataclass(frozen=True)
class _UnheatedAir:
    """The air temperature balance of one sub-step with the heating off, as a function of
    extra ventilation (m/s on top of the air exchange already in ``g_pass``).

    Fields: ``temp0`` °C at the start; ``q_free`` W/m² free gains (sun, lamps); ``g_pass``
    W m^-2 K^-1 conductance to the outside air and the sky; ``drive`` W/m², those conductances
    times their temperatures (``g_out T_out + u_sky T_sky``); ``temp_out`` °C; ``dt`` s.
    """

    temp0: jax.Array
    q_free: jax.Array
    g_pass: jax.Array
    drive: jax.Array
    temp_out: jax.Array
    dt: float
    p: ClimateParams

    def end_temperature(self, extra_vent: jax.Array) -> jax.Array:
        """Temperature at the end of the sub-step (the exact solution for frozen fluxes)."""
        g_vent = self.p.air_heat_capacity * extra_vent
        g = self.g_pass + g_vent
        t_eq = (self.q_free + self.drive + g_vent * self.temp_out) / g
        return t_eq + (self.temp0 - t_eq) * jnp.exp(-g * self.dt / self.p.heat_capacity)

    def vent_to_reach(self, target: jax.Array, room: jax.Array) -> jax.Array:
        """Extra flux in [0, room] that ends the sub-step at ``target`` (never above it): 0 if
        the closed house ends there anyway, ``room`` if even that much leaves it warmer.

        The flux changes the balance's decay rate as well as its equilibrium, so there is no
        closed form. A formula that keeps the closed house's decay rate (the earlier one)
        opens the vents too little when the air starts well below the target, e.g. a cold,
        sunny morning, and lets the sub-step end kelvins above the vent line. Bisection only
        needs the end temperature to be continuous in the flux; it need not be monotone
        (outdoor air warmer than the house first warms it). Each halving keeps a flux that
        is too small (``lo``) and one that is enough (``hi``), and ``hi`` is returned.
        """
        room = jnp.maximum(room, 0.0)
        lo, hi = jnp.zeros_like(room), room
        for _ in range(VENT_BISECTIONS):  # unrolled: XLA fuses the elementwise halvings
            mid = 0.5 * (lo + hi)
            too_warm = self.end_temperature(mid) > target
            lo, hi = jnp.where(too_warm, mid, lo), jnp.where(too_warm, hi, mid)
        return jnp.where(self.end_temperature(jnp.zeros_like(room)) <= target, 0.0, hi)


def climate_substep(
    s: ClimateState,
    *,
    temp_out: jax.Array,
    temp_sky: jax.Array,
    vapour_out: jax.Array,
    wind: jax.Array,
    ghi: jax.Array,
    lamp: jax.Array,
    temp_sp: jax.Array,
    co2_sp: jax.Array,
    uptake: jax.Array,
    transpiration: jax.Array,
    dt: float,
    p: ClimateParams,
) -> tuple[ClimateState, ClimateFlux]:
    """Advance the indoor climate by ``dt`` seconds under the setpoint controllers.

    Args: outdoor ``temp_out``/``temp_sky`` °C, ``vapour_out`` kg/m³, ``wind`` m/s, ``ghi``
      W/m²; ``lamp`` on-fraction; ``temp_sp`` °C and ``co2_sp`` ppm setpoints; crop
      ``uptake`` (net CO2 assimilation, kg m^-2 s^-1) and ``transpiration`` (kg m^-2 s^-1).
    """
    c_air = p.air_heat_capacity
    leak = p.leakage + p.leakage_wind * wind
    # Energy screen: drawn on dark, cold hours; it cuts cover and sky losses, not ventilation.
    screen = jnp.where((ghi <= 0.0) & (temp_out < p.screen_temp), 1.0 - p.screen_saving, 1.0)
    u_cover = screen * (p.u_cover + p.u_cover_wind * wind)
    u_sky = screen * p.u_sky
    q_free = p.solar_heat * ghi + p.lamp_heat * p.lamp_power * lamp

    def heat_demand(vent):
        """Heat that brings T to the setpoint by the end of the sub-step (exact for the
        linear balance) with air exchange ``leak + vent``; also returns the conductances."""
        g_out = u_cover + c_air * (leak + vent)  # W m^-2 K^-1 to the outside air
        g_pass = g_out + u_sky
        t_ref = (g_out * temp_out + u_sky * temp_sky) / g_pass  # where T settles unheated, dark
        e_pass = jnp.exp(-g_pass * dt / p.heat_capacity)
        t_eq_heat = (temp_sp - s.temp * e_pass) / (1.0 - e_pass)
        return g_pass * (t_eq_heat - t_ref) - q_free, g_pass, t_ref

    # Humidity ventilation: the vent flux that carries the transpired vapour out at rh_max
    # (steady state). It only helps when the outside air is drier than the target (by >= 1
    # g/m³), and temperature has priority: it may only use spare heating capacity.
    h_max = p.rh_max / 100.0 * vapour_density(saturation_pressure(s.temp), s.temp)
    dry_margin = h_max - vapour_out
    vent_h = jnp.where(
        dry_margin > 1e-3,
        jnp.clip(transpiration / jnp.maximum(dry_margin, 1e-3) - leak, 0.0, p.vent_max),
        0.0,
    )
    demand_closed = heat_demand(0.0)[0]
    spare = jnp.maximum(p.heat_max - jnp.maximum(demand_closed, 0.0), 0.0)
    vent_h = jnp.minimum(vent_h, spare / (c_air * jnp.maximum(temp_sp - temp_out, 1.0)))

    demand, g_pass, t_ref = heat_demand(vent_h)
    heat = jnp.clip(demand, 0.0, p.heat_max)
    # Temperature ventilation (heating off): the extra flux that ends the sub-step at the
    # ventilation setpoint, like the heating ends it at the heating setpoint.
    unheated = _UnheatedAir(s.temp, q_free, g_pass, g_pass * t_ref, temp_out, dt, p)
    vent_t = unheated.vent_to_reach(temp_sp + p.vent_offset, p.vent_max - vent_h)
    vent_t = jnp.where(heat > 0.0, 0.0, vent_t)
    vent = jnp.minimum(vent_h + vent_t, p.vent_max)

    g_out = u_cover + c_air * (leak + vent)
    g_tot = g_out + u_sky
    t_eq = (heat + q_free + g_out * temp_out + u_sky * temp_sky) / g_tot
    temp = t_eq + (s.temp - t_eq) * jnp.exp(-g_tot * dt / p.heat_capacity)

    # CO2 (ppm): exchange rate (1/s) with the outside, dose to reach the setpoint.
    exchange = (leak + vent) / p.height
    e_co2 = jnp.exp(-exchange * dt)
    c_eq_needed = (co2_sp - s.co2 * e_co2) / (1.0 - e_co2)
    dose = jnp.clip(
        KAPPA_CO2 * p.height * exchange * (c_eq_needed - p.co2_out) + uptake, 0.0, p.co2_max
    )
    c_eq = p.co2_out + (dose - uptake) / (KAPPA_CO2 * p.height * exchange)
    co2 = jnp.maximum(c_eq + (s.co2 - c_eq) * e_co2, CO2_FLOOR)

    # Humidity: transpiration in, ventilation/leakage out, condensation on a cold cover.
    t_cover = temp_out + p.cover_weight * (s.temp - temp_out)
    h_cover = vapour_density(saturation_pressure(t_cover), t_cover)
    cond = jnp.where(s.vapour > h_cover, p.condensation, 0.0)
    g_h = leak + vent + cond
    h_eq = (transpiration + (leak + vent) * vapour_out + cond * h_cover) / g_h
    vapour = h_eq + (s.vapour - h_eq) * jnp.exp(-g_h * dt / p.height)
    vapour = jnp.minimum(vapour, vapour_density(saturation_pressure(temp), temp))  # fog condenses

    return ClimateState(temp, co2, vapour), ClimateFlux(heat, dose, vent)
