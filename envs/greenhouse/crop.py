"""Reduced TOMGRO: the five-state tomato crop model of Jones, Kenig & Vallejos (1999).

Jones, J. W., Kenig, A., Vallejos, C. E. (1999). Reduced state-variable tomato growth model.
Transactions of the ASAE 42(1): 255-265. Auxiliary functions (temperature responses, root
partitioning) come from the full TOMGRO, Jones et al. (1991), Trans. ASAE 34(2): 663-672,
as the 1999 paper prescribes.

State (per m² of floor): ``n`` main-stem node number (per plant), ``lai`` leaf area index,
``w`` above-ground dry weight (g/m², includes harvested fruit), ``wf`` fruit dry weight
(g/m², includes harvested fruit), ``wm`` mature (= harvested) fruit dry weight (g/m²).

Time stepping: photosynthesis, maintenance respiration and node initiation are evaluated
every sub-step from the hourly indoor climate and summed over the day; the states are then
updated once per day with those sums, as in the 1999 model (Euler, one day).

Equations (numbers = Jones et al. 1999):
  (1)  dN/dt   = N_m f_N(T)
  (2)  dLAI/dt = rho delta lambda(T) exp(beta(N-N_b)) / (1 + exp(beta(N-N_b))) dN/dt,  LAI < LAI_max
  (5)  GR_net  = E (P_g - R_m) (1 - f_R(N))
       P_g     = D/K L_fmax PGRED(T)
                 ln{[(1-m) L_fmax + Q_e K PPFD] / [(1-m) L_fmax + Q_e K PPFD e^{-K LAI}]}
                 (Acock et al. 1978 canopy integral), L_fmax = tau C
  (6)  R_m     = Q10^((T-20)/10) r_m (W - W_m)
  (7)  dW_f/dt = GR_net alpha_F f_F(T) (1 - e^{-nu (N - N_FF)}) g(T_daytime),  N > N_FF
  (8)  g(T_d)  = 1 - 0.154 (T_daytime - T_crit)   (clipped to [0, 1])
  (9-10) dW/dt = min(GR_net - p1 rho dN/dt,  dW_f/dt + (V_max - p1) rho dN/dt),
                 p1 = 0 while LAI < LAI_max
  (11) dW_m/dt = D_F(T) (W_f - W_m),  N > N_FF + K_F

Our additions (documented deviations):
  - Water stress ``f_w`` (0..1, from ``water.py``) multiplies hourly P_g (stomatal closure)
    and the daily leaf expansion (the most drought-sensitive process).
  - L_fmax may rise with a second slope ``tau2`` above 350 ppm (the 1999 model's
    spreadsheet version saturates that way); the default tau2 = tau keeps the paper's
    linear L_fmax = tau C.
  - Long photoperiods injure tomato leaves: beyond ~17 h of light a day (sun or lamps) leaves
    turn chlorotic and photosynthesis falls (Demers & Gosselin 2002, Acta Hort. 580;
    Velez-Ramirez et al. 2014, Front. Plant Sci. 5:540). The day's photosynthesis is
    multiplied by ``photoperiod_factor`` = 1 - ``photoperiod_injury`` per hour of light
    beyond ``photoperiod_max`` (floor 0.5), so lighting has an interior optimum as in practice
    (tomato growers light at most 16-18 h).
  - Fruit never shrinks (fruit growth uses max(GR_net, 0)) and the vegetative mass
    ``W - W_f`` cannot become negative (a starving crop loses leaves and stems, not fruit).
  - Harvest is the maturation flux: fresh yield = W_m / dry-matter content (0.055 g/g, tomato
    fruit 5-7 % dry matter, Heuvelink 2005); fruit number = fresh yield / mean fruit mass
    (100 g, round truss tomato).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

# Jones et al. (1991) Table 3: fraction of growth partitioned to roots vs node number.
_ROOT_N = (1.0, 2.0, 9.0, 12.0, 15.0, 21.0, 30.0, 50.0, 90.0)
_ROOT_F = (0.20, 0.20, 0.20, 0.15, 0.15, 0.10, 0.07, 0.07, 0.07)


@struct.dataclass
class CropParams:
    """Reduced TOMGRO parameters (a pytree: vmap or swap them like any array).

    Values are Jones et al. (1999)'s calibrated set unless marked; units per m² of floor.
    """

    plant_density: float = 3.1  # rho, plants/m² (Jones et al. 1999 experiments)
    node_rate_max: float = 0.5  # N_m, nodes/day (Jones et al. 1991)
    delta: float = 0.038  # m² leaf per node, maximum leaf area expansion
    beta: float = 0.169  # 1/node, shape of the LAI-vs-node logistic
    n_b: float = 16.0  # nodes, inflection of the LAI-vs-node logistic
    lai_max: float = 4.0  # maximum LAI (leaf pruning keeps it there)
    growth_efficiency: float = 0.717  # E, g dry matter per g CH2O
    quantum_efficiency: float = 0.0645  # Q_e, µmol CO2 per µmol photons
    extinction: float = 0.58  # K, canopy light extinction coefficient
    leaf_transmission: float = 0.1  # m, leaf light transmission coefficient
    tau1: float = 0.0693  # tau, µmol CO2 m^-2 s^-1 per ppm (leaf L_fmax = tau C) up to 350 ppm
    tau2: float = 0.0693  # slope above 350 ppm (default = tau: the paper's linear form)
    d_conv: float = 2.593  # D, g CH2O m^-2 d^-1 per µmol CO2 m^-2 s^-1 (= 3600*24*30e-6)
    maintenance: float = 0.016  # r_m, g CH2O per g dry matter per day at 20 °C
    q10: float = 1.4  # Q10 of maintenance respiration
    alpha_f: float = 0.80  # alpha_F, maximum partitioning of new growth to fruit
    nu: float = 0.135  # nu, transition coefficient of fruit partitioning (per node)
    n_ff: float = 22.0  # N_FF, nodes per plant when the first fruit appears
    t_crit: float = 24.4  # T_crit, °C mean daytime temperature above which fruit set fails
    k_f: float = 5.0  # K_F, nodes between first fruit and first mature fruit
    v_max: float = 8.0  # V_max, g dry matter per node, maximum vegetative growth
    p1: float = 2.0  # p1, g leaf dry weight removed per node by pruning at LAI_max
    # Maturation D_F(T) = df_max * clip(0.0714 (T_avg - 9), 0, 1) (the 1999 spreadsheet's
    # temperature form, after Marcelis & Koning 1995). df_max (1/day) is our calibration: at a
    # 20 °C mean, fruit dry matter stays ~25 days on the plant (1 / D_F), consistent with the
    # 50-60 day anthesis-to-harvest period of tomato fruit (Heuvelink 2005).
    df_max: float = 0.05
    # f_F(T) = clip(0.0625 (T_avg - t_min_fruit), 0, 1) (1999 spreadsheet form); the
    # threshold is our assumption: full fruit partitioning from a 20 °C daily mean.
    t_min_fruit: float = 4.0
    photoperiod_max: float = 17.0  # h of light per day tolerated without injury
    photoperiod_injury: float = 0.05  # photosynthesis lost per hour of light beyond that
    dry_matter_content: float = (
        0.055  # g dry / g fresh fruit (round tomato; Heuvelink 2005: 0.05-0.07)
    )
    fruit_mass: float = 100.0  # g fresh per fruit (round truss tomato)
    # Initial state at transplanting (late December): young plants with ~6 nodes.
    n0: float = 10.0
    w0: float = 30.0  # g/m² (~10 g dry weight per transplant)


@struct.dataclass
class CropState:
    """Reduced TOMGRO state, every field ``[]`` float32 (see module doc for units)."""

    n: jax.Array
    lai: jax.Array
    w: jax.Array
    wf: jax.Array
    wm: jax.Array


def initial_crop(p: CropParams) -> CropState:
    """Transplants: ``n0`` nodes, LAI from the integral of eq. (2) at ``n0``, ``w0`` dry weight."""
    n0 = jnp.asarray(p.n0, jnp.float32)
    lai0 = p.plant_density * p.delta / p.beta * jnp.log1p(jnp.exp(p.beta * (n0 - p.n_b)))
    zero = jnp.zeros((), jnp.float32)
    return CropState(
        n=n0, lai=jnp.asarray(lai0, jnp.float32), w=jnp.asarray(p.w0, jnp.float32), wf=zero, wm=zero
    )


# --- temperature responses (vectorised, cheap: clipped ramps instead of table look-ups) -------
def node_rate_factor(temp: jax.Array) -> jax.Array:
    """f_N(T) of Jones et al. (1991) Table 3 (as used by Heuvelink 1994): 0 below 12 °C,
    0.55 -> 1 from 12 to 28 °C, falling to 0 at 50 °C."""
    rise = 1.0 + 0.0281 * (temp - 28.0)
    fall = 1.0 - 0.0455 * (temp - 28.0)
    return jnp.where((temp > 12.0) & (temp < 50.0), jnp.minimum(rise, fall), 0.0)


def photosynthesis_temperature_factor(temp: jax.Array) -> jax.Array:
    """PGRED(T) of Jones et al. (1991) Table 3: 0 at 0 °C, 0.67 at 9, 1 from 12 to 28, 0 at 35.

    Written as a sum of clipped ramps (exactly the piecewise-linear table).
    """
    return (
        jnp.clip(temp * (0.67 / 9.0), 0.0, 0.67)
        + jnp.clip((temp - 9.0) * (0.33 / 3.0), 0.0, 0.33)
        - jnp.clip((temp - 28.0) / 7.0, 0.0, 1.0)
    )


def leaf_max_photosynthesis(co2: jax.Array, p: CropParams) -> jax.Array:
    """L_fmax, µmol CO2 m^-2 s^-1: tau1 C up to 350 ppm, slope tau2 above. ``co2`` in ppm."""
    co2 = jnp.maximum(co2, 0.0)
    return p.tau1 * jnp.minimum(co2, 350.0) + p.tau2 * jnp.maximum(co2 - 350.0, 0.0)


def gross_photosynthesis(
    par: jax.Array, co2: jax.Array, temp: jax.Array, lai: jax.Array, p: CropParams
) -> jax.Array:
    """Canopy gross photosynthesis (Acock et al. 1978; Jones 1999 eq. 5), µmol CO2 m^-2 s^-1.

    Args (broadcastable): ``par`` PPFD at the canopy top, µmol m^-2 s^-1; ``co2`` ppm;
      ``temp`` °C; ``lai`` m²/m².
    Non-decreasing in ``par`` and in ``co2`` (tested): the log term increases with PPFD, and
    L_fmax ln(1 + k/(L_fmax + ...)) increases with L_fmax.
    Multiply by ``d_conv / 24`` for g CH2O m^-2 h^-1.
    """
    lfmax = leaf_max_photosynthesis(co2, p)
    a = (1.0 - p.leaf_transmission) * lfmax
    b = p.quantum_efficiency * p.extinction * jnp.maximum(par, 0.0)
    transmitted = jnp.exp(-p.extinction * jnp.maximum(lai, 0.0))
    # log1p form: ln[(a + b)/(a + b e)] = ln(1 + b (1 - e) / (a + b e)); a tiny floor keeps
    # the ratio finite when both light and CO2 are zero (then b (1 - e) = 0 as well).
    ratio = b * (1.0 - transmitted) / jnp.maximum(a + b * transmitted, 1e-6)
    return lfmax / p.extinction * photosynthesis_temperature_factor(temp) * jnp.log1p(ratio)


def photoperiod_factor(light_hours: jax.Array, p: CropParams) -> jax.Array:
    """Photosynthesis multiplier for a day with ``light_hours`` hours of light (see module doc)."""
    return jnp.clip(1.0 - p.photoperiod_injury * (light_hours - p.photoperiod_max), 0.5, 1.0)


def maintenance_respiration(temp: jax.Array, w_living: jax.Array, p: CropParams) -> jax.Array:
    """Eq. (6) per hour: g CH2O m^-2 h^-1 at ``temp`` °C for living dry weight ``w_living`` g/m²."""
    return p.maintenance / 24.0 * jnp.power(p.q10, (temp - 20.0) / 10.0) * w_living


def root_fraction(n: jax.Array) -> jax.Array:
    """f_R(N): fraction of net growth to the roots (Jones et al. 1991 Table 3)."""
    return jnp.interp(n, jnp.asarray(_ROOT_N), jnp.asarray(_ROOT_F))


# --- daily update ---------------------------------------------------------------------------
@struct.dataclass
class CropDay:
    """What one simulated day feeds into the daily crop update (all ``[]`` float32).

    pg, rm: day sums of gross photosynthesis and maintenance respiration, g CH2O/m².
    dn: node increment of the day (sum over sub-steps of N_m f_N(T) dt), nodes/plant.
    t_avg: mean air temperature °C; t_daytime: mean over daylight hours °C.
    water: mean water-stress factor f_w (1 = no stress).
    """

    pg: jax.Array
    rm: jax.Array
    dn: jax.Array
    t_avg: jax.Array
    t_daytime: jax.Array
    water: jax.Array


def crop_update(s: CropState, d: CropDay, p: CropParams) -> CropState:
    """Advance the reduced TOMGRO state by one day (Jones et al. 1999, eqs. 1-11)."""
    rho = p.plant_density
    # (2) leaf area follows node initiation; lambda(T) = 1 as in the 1999 paper.
    sig = jax.nn.sigmoid(p.beta * (s.n - p.n_b))
    dlai = jnp.where(s.lai < p.lai_max, rho * p.delta * sig * d.dn * d.water, 0.0)
    # (5) net above-ground growth rate, g dry matter m^-2 d^-1.
    gr_net = p.growth_efficiency * (d.pg - d.rm) * (1.0 - root_fraction(s.n))
    # (7-8) fruit growth after the first fruit; cool days partition less to fruit, hot days
    # (mean daytime above T_crit) abort fruit.
    f_f = jnp.clip(0.0625 * (d.t_avg - p.t_min_fruit), 0.0, 1.0)
    g_hot = jnp.clip(1.0 - 0.154 * (d.t_daytime - p.t_crit), 0.0, 1.0)
    fruit_sink = 1.0 - jnp.exp(-p.nu * jnp.maximum(s.n - p.n_ff, 0.0))
    dwf = jnp.maximum(gr_net, 0.0) * p.alpha_f * f_f * fruit_sink * g_hot
    # (9-10) total growth: source-limited, or sink-limited by V_max per node; pruning at LAI_max.
    p1 = jnp.where(s.lai >= p.lai_max, p.p1, 0.0)
    dw = jnp.minimum(gr_net - p1 * rho * d.dn, dwf + (p.v_max - p1) * rho * d.dn)
    # (11) maturation (= harvest) after K_F more nodes; rate rises with mean temperature.
    d_f = p.df_max * jnp.clip(0.0714 * (d.t_avg - 9.0), 0.0, 1.0)
    dwm = jnp.where(s.n > p.n_ff + p.k_f, d_f * (s.wf - s.wm), 0.0)
    wf = s.wf + dwf
    return CropState(
        n=s.n + d.dn,
        lai=jnp.minimum(s.lai + dlai, p.lai_max),
        w=jnp.maximum(s.w + dw, wf),
        wf=wf,
        wm=s.wm + dwm,
    )


def fresh_yield_kg(wm: jax.Array, p: CropParams) -> jax.Array:
    """Harvested fruit fresh weight, kg/m², from mature fruit dry weight ``wm`` g/m²."""
    return wm / p.dry_matter_content / 1000.0


def fruit_number(wm: jax.Array, p: CropParams) -> jax.Array:
    """Harvested fruits per m² (fresh yield / mean fruit mass)."""
    return wm / p.dry_matter_content / p.fruit_mass
