"""Measured hourly weather for the greenhouse, read once on the host from a standard file.

Two standard formats are read with pvlib's readers (``pvlib.iotools``), nothing is
downloaded at run time:

- EPW (EnergyPlus weather): ``read_epw``; sky temperature from the measured horizontal
  infrared radiation ``ghi_infrared`` (W/m², hourly mean) by Stefan-Boltzmann,
  ``T_sky = (IR / sigma) ** 0.25``.
- TMY3 (NSRDB typical meteorological year, CSV): ``read_tmy3``; TMY3 has no infrared
  field, so the sky temperature is estimated like EnergyPlus does for files without it
  (EnergyPlus Engineering Reference, "Sky Radiation Modeling"): clear-sky emissivity of
  Berdahl & Martin (1984), ``eps_clear = 0.711 + 0.56 (Td/100) + 0.73 (Td/100)^2`` with the
  dew point ``Td`` in °C, Walton's (1983) cloud correction
  ``eps = eps_clear (1 + 0.0224 N - 0.0035 N^2 + 0.00028 N^3)`` with ``N`` the opaque sky
  cover in tenths, then ``T_sky = T_air,K * eps ** 0.25``.

The default file is pvlib's bundled TMY3 of Greensboro NC (``pvlib/data/723170TYA.CSV``,
36.1 °N): it installs with the pvlib dependency. pvlib also bundles ``703165TY.csv``
(Sand Point, Alaska), handy as "different weather".

Rows of both formats are hour-ending (row ``k`` covers the hour ``[k, k+1)`` of the year),
so a file becomes ``[365, 24]`` arrays indexed ``[day_of_year - 1, hour]``; a leap year's
29 February is dropped. Missing values (NaN, EPW's 9999-style codes) are filled by linear
interpolation in time before anything reaches JAX.
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

DAYS_PER_YEAR = 365
HOURS_PER_DAY = 24
STEFAN_BOLTZMANN = 5.670374419e-8  # W m^-2 K^-4
KELVIN = 273.15


@struct.dataclass
class Weather:
    """One year of hourly outdoor weather, every field ``[365, 24]`` float32.

    Attributes:
      ghi: global horizontal radiation, W/m² (hourly mean).
      temp_air: dry-bulb air temperature, °C.
      rh: relative humidity, % (0..100).
      wind: wind speed, m/s.
      temp_sky: effective sky temperature for long-wave exchange, °C.
    """

    ghi: jax.Array
    temp_air: jax.Array
    rh: jax.Array
    wind: jax.Array
    temp_sky: jax.Array

    def day(self, day_of_year_index: jax.Array) -> Weather:
        """The 24 hours of one day: ``[]`` int index 0..364 (wraps) -> fields ``[24]``."""
        i = jnp.mod(day_of_year_index, DAYS_PER_YEAR)
        return jax.tree.map(
            lambda x: jax.lax.dynamic_index_in_dim(x, i, axis=0, keepdims=False), self
        )


def default_weather_path() -> str:
    """Path of pvlib's bundled TMY3 file for Greensboro NC (the default weather)."""
    import pvlib

    return os.path.join(os.path.dirname(pvlib.__file__), "data", "723170TYA.CSV")


def bundled_weather_path(name: str) -> str:
    """Path of a weather file bundled with pvlib, e.g. ``"703165TY.csv"`` (Sand Point, AK)."""
    import pvlib

    path = os.path.join(os.path.dirname(pvlib.__file__), "data", name)
    if not os.path.exists(path):
        raise FileNotFoundError(
            f"pvlib does not bundle {name!r} (looked in {os.path.dirname(path)})"
        )
    return path


def sky_temperature_from_infrared(ir: np.ndarray) -> np.ndarray:
    """Horizontal infrared radiation W/m² -> sky temperature °C (Stefan-Boltzmann)."""
    return (np.maximum(ir, 1.0) / STEFAN_BOLTZMANN) ** 0.25 - KELVIN


def sky_temperature_from_clouds(
    temp_air: np.ndarray, temp_dew: np.ndarray, opaque_cover_tenths: np.ndarray
) -> np.ndarray:
    """Sky temperature °C from air temperature °C, dew point °C and opaque sky cover (tenths).

    Berdahl & Martin (1984) clear-sky emissivity with Walton's (1983) cloud correction, as in
    EnergyPlus for weather files without infrared data.
    """
    td = temp_dew / 100.0
    eps_clear = 0.711 + 0.56 * td + 0.73 * td**2
    n = np.clip(opaque_cover_tenths, 0.0, 10.0)
    eps = np.clip(eps_clear * (1.0 + 0.0224 * n - 0.0035 * n**2 + 0.00028 * n**3), 0.05, 1.0)
    return (temp_air + KELVIN) * eps**0.25 - KELVIN


def _fill(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Treat values outside [lo, hi] (missing-data codes) and NaN as missing; interpolate in
    time."""
    x = np.asarray(x, np.float64).copy()
    bad = ~np.isfinite(x) | (x < lo) | (x > hi)
    if bad.all():
        raise ValueError(f"weather column has no valid value in [{lo}, {hi}]")
    if bad.any():
        idx = np.arange(x.size)
        x[bad] = np.interp(idx[bad], idx[~bad], x[~bad])
    return x


def _year_rows(x: np.ndarray) -> np.ndarray:
    """8760 or 8784 hourly rows -> [365, 24] (dropping 29 February of a leap year)."""
    if x.size == 8784:
        x = np.concatenate([x[: 59 * 24], x[60 * 24 :]])
    if x.size != DAYS_PER_YEAR * HOURS_PER_DAY:
        raise ValueError(f"a weather file must hold one year of hourly rows (8760), got {x.size}")
    return x.reshape(DAYS_PER_YEAR, HOURS_PER_DAY)


def _columns_epw(path: str) -> dict[str, np.ndarray]:
    from pvlib.iotools import read_epw

    df, _ = read_epw(path)
    temp_air = _fill(df["temp_air"].to_numpy(), -70.0, 70.0)
    temp_dew = _fill(df["temp_dew"].to_numpy(), -70.0, 70.0)
    ir = df["ghi_infrared"].to_numpy(np.float64)
    # EPW marks missing infrared as 9999; fall back to the cloud-based estimate hour by hour.
    ir_ok = np.isfinite(ir) & (ir > 50.0) & (ir < 800.0)
    cover = _fill(df["opaque_sky_cover"].to_numpy(), 0.0, 10.0)
    temp_sky = np.where(
        ir_ok,
        sky_temperature_from_infrared(np.where(ir_ok, ir, 300.0)),
        sky_temperature_from_clouds(temp_air, temp_dew, cover),
    )
    return {
        "ghi": _fill(df["ghi"].to_numpy(), 0.0, 1500.0),
        "temp_air": temp_air,
        "rh": _fill(df["relative_humidity"].to_numpy(), 0.0, 110.0),
        "wind": _fill(df["wind_speed"].to_numpy(), 0.0, 60.0),
        "temp_sky": temp_sky,
    }


def _columns_tmy3(path: str) -> dict[str, np.ndarray]:
    from pvlib.iotools import read_tmy3

    df, _ = read_tmy3(path, map_variables=True)
    temp_air = _fill(df["temp_air"].to_numpy(), -70.0, 70.0)
    temp_dew = _fill(df["temp_dew"].to_numpy(), -70.0, 70.0)
    cover = _fill(df["OpqCld (tenths)"].to_numpy(), 0.0, 10.0)
    return {
        "ghi": _fill(df["ghi"].to_numpy(), 0.0, 1500.0),
        "temp_air": temp_air,
        "rh": _fill(df["relative_humidity"].to_numpy(), 0.0, 110.0),
        "wind": _fill(df["wind_speed"].to_numpy(), 0.0, 60.0),
        "temp_sky": sky_temperature_from_clouds(temp_air, temp_dew, cover),
    }


def load_weather(path: str | None = None, fmt: str = "auto") -> Weather:
    """Read a one-year hourly EPW or TMY3 file into a ``Weather`` of ``[365, 24]`` arrays.

    Args:
      path: file path; None = pvlib's bundled Greensboro NC TMY3 (``default_weather_path``).
      fmt: ``"epw"``, ``"tmy3"`` or ``"auto"`` (``.epw`` suffix = EPW, anything else = TMY3).

    Raises:
      FileNotFoundError: the file does not exist.
      ValueError: unknown format, or the file does not hold one year of hourly rows.
    """
    path = default_weather_path() if path is None else os.fspath(path)
    if not os.path.exists(path):
        raise FileNotFoundError(
            f"weather file not found: {path!r} (pass an EPW or TMY3 file, or None for the default)"
        )
    if fmt == "auto":
        fmt = "epw" if path.lower().endswith(".epw") else "tmy3"
    if fmt not in ("epw", "tmy3"):
        raise ValueError(f"weather format must be 'epw', 'tmy3' or 'auto', got {fmt!r}")
    cols = _columns_epw(path) if fmt == "epw" else _columns_tmy3(path)
    cols["rh"] = np.clip(cols["rh"], 1.0, 100.0)
    return Weather(**{k: jnp.asarray(_year_rows(v), jnp.float32) for k, v in cols.items()})
