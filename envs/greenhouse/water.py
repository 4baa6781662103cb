"""Root-zone water balance of a substrate (rock-wool) crop: irrigation, transpiration, drainage.

Per m² of floor, water in L/m² (= mm = kg/m²):

  d(theta)/dt = irrigation - transpiration,   drainage = excess above the slab's capacity.

- Irrigation: drip at a fixed rate ``irrigation_rate`` L m^-2 h^-1 while the irrigation
  schedule is on (``actions.on_fraction``).
- Transpiration (a radiation + vapour-pressure-deficit model of the Stanghellini / de Graaf
  family, reduced to two coefficients): the canopy intercepts ``1 - exp(-K LAI)`` of the
  indoor radiation and uses ``rad_coef`` of it to evaporate water; a VPD term transpires
  ``vpd_coef`` kg m^-2 s^-1 kPa^-1 at full cover (night transpiration). With the defaults a
  full canopy transpires ~3-4 L/m² on a bright spring day, ~1 L/m² on a dark winter day,
  the range measured in Dutch tomato greenhouses.
- Water stress (Feddes-type reduction): ``f_w = clip((theta - wilt) / (crit - wilt), 0, 1)``
  with the two thresholds as fractions of capacity; it multiplies photosynthesis (``crop.py``)
  and transpiration (stomata close together). No irrigation empties the slab in a few days
  and then stops growth.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

LATENT_HEAT = 2.45e6  # J/kg, vaporisation of water at ~20 °C


@struct.dataclass
class WaterParams:
    """Substrate and irrigation parameters (a pytree)."""

    irrigation_rate: float = 0.5  # L m^-2 h^-1 while irrigating (drip, ~2 L/h per 4 m² emitter set)
    capacity: float = 8.0  # L/m²: water held by the slabs at container capacity
    crit_fraction: float = 0.5  # stress starts below this fraction of capacity
    wilt_fraction: float = 0.15  # no uptake below this fraction
    rad_coef: float = 0.6  # fraction of intercepted radiation used for transpiration
    vpd_coef: float = 1.5e-5  # kg m^-2 s^-1 kPa^-1 at full canopy cover
    extinction: float = 0.7  # canopy extinction for radiation interception (short + near-IR)


def stress_factor(theta: jax.Array, p: WaterParams) -> jax.Array:
    """Water-stress factor f_w in [0, 1] (1 = unstressed) for slab water ``theta`` L/m²."""
    crit, wilt = p.crit_fraction * p.capacity, p.wilt_fraction * p.capacity
    return jnp.clip((theta - wilt) / (crit - wilt), 0.0, 1.0)


def potential_transpiration(
    radiation: jax.Array, vpd_kpa: jax.Array, lai: jax.Array, p: WaterParams
) -> jax.Array:
    """Unstressed canopy transpiration, kg m^-2 s^-1.

    ``radiation``: indoor short-wave radiation at the canopy (sun + lamps), W/m²;
    ``vpd_kpa``: air vapour-pressure deficit, kPa; ``lai``: leaf area index.
    """
    cover = 1.0 - jnp.exp(-p.extinction * lai)
    return cover * (
        p.rad_coef * jnp.maximum(radiation, 0.0) / LATENT_HEAT
        + p.vpd_coef * jnp.maximum(vpd_kpa, 0.0)
    )


def water_update(theta: jax.Array, irrigation: jax.Array, transpiration: jax.Array, p: WaterParams):
    """One sub-step of the slab balance; all amounts in L/m² over the sub-step.

    Transpiration cannot take more than the slab holds. Returns
    ``(theta_new, transpired, drained)``.
    """
    transpired = jnp.minimum(transpiration, theta)
    theta = theta + irrigation - transpired
    drained = jnp.maximum(theta - p.capacity, 0.0)
    return theta - drained, transpired, drained
