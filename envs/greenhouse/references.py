"""Strong reference schedules for the greenhouse: the best constant action and the best
open-loop (one action per day) season schedule, both found by the project's own search.

The weak references (default setpoints, random actions, the grower heuristic) say little
about how good a learned policy is; these two bound it from below with what planning on the
simulator itself achieves:

- ``best_constant_schedule``: the best single normalised action ``[n, max_dim]`` held every
  day of the season. A batched random search over the whole action space (every candidate a
  whole season, one vmapped, jitted call per batch), then rounds of local refinement around
  the best ones (Gaussian perturbations, whole-row shifts, and a coordinate sweep over every
  grid value of the hour dims), each round again one batched call. Hour dims stay on their
  grid. The season evaluator is compiled once per environment configuration: the
  environment's arrays and the candidate actions are arguments, the batch shape is fixed.
- ``best_open_loop_schedule``: one action per day (``[season_days, n, max_dim]``), by Adam
  gradient ascent through the differentiable simulator, starting from the best constant.
  The lamp and irrigation timers are discrete hours (the env snaps them, which has no
  gradient), so the optimisation runs on a smooth relaxation: continuous start hour and
  duration, and an on-fraction with logistic edges (``relaxed_on_fraction``). The result is
  rounded back to the hour grid and re-evaluated with the real ``env.step``; whichever of the
  rounded optimum and the starting constant is better is kept, so the open-loop reference is
  never below the constant one.
- ``evaluate_schedule`` / ``season_returns`` / ``schedule_trace``: the true season return
  (or the whole trace) of any constant or per-day schedule, through ``env.step``.
- ``greenhouse_references(env)``: both references' returns by name, with an on-disk JSON cache
  keyed by the environment (config, weather and parameter arrays) and the simulator's source
  code, so an end-of-run report pays the search once per environment and code version;
  ``reference_schedules(env, hold_days=K)`` the schedules themselves (same cache), which
  ``schedule_policy`` turns into reference policies (``GreenhouseEnv.planned_references``).

Pure JAX (with optax for Adam); of the project it imports only ``envs.greenhouse`` and
``score_jax.core.spaces``, so neither MuJoCo nor brax is loaded.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import tempfile
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from envs.greenhouse.env import GreenhouseEnv
from envs.greenhouse.season import FIRST_HARVEST_KG, SeasonTrace
from score_jax.core.spaces import CompositeSpace

HOURS = ("lighting", "irrigation")  # the two timer sub-spaces, (start, end) hours each
CONTINUOUS_ROWS = ("temperature", "co2")  # the two hourly setpoint sub-spaces
CACHE_FORMAT = 2  # bump when the cache entry's layout changes (2: the schedules too)


# --- true season evaluation (the real env.step) ---------------------------------------------------
def _season(env: GreenhouseEnv, schedule: jax.Array, key: jax.Array):
    """One season under ``schedule`` (``[n, max_dim]`` constant or ``[D, n, max_dim]`` per day):
    ``(metrics [D], reward [D])``. A per-day schedule shorter than the season holds its last row."""
    days = env.episode_length
    state = env.reset(key)
    if schedule.ndim == 2:

        def day(state, _):
            state = env.step(state, schedule)
            return state, (state.metrics, state.reward)

        xs = None
    else:
        idx = np.minimum(np.arange(days), schedule.shape[0] - 1)

        def day(state, action):
            state = env.step(state, action)
            return state, (state.metrics, state.reward)

        xs = schedule[idx]
    _, out = jax.lax.scan(day, state, xs, length=days)
    return out


@jax.jit
def _batched_returns(env: GreenhouseEnv, schedules: jax.Array, key: jax.Array) -> jax.Array:
    # env is a pytree argument: its arrays are inputs, its config and space the static part of
    # the cache key, so one compilation serves every call with the same config and batch shape.
    return jax.vmap(lambda s: jnp.sum(_season(env, s, key)[1]))(schedules)


@jax.jit
def _trace(env: GreenhouseEnv, schedule: jax.Array, key: jax.Array) -> SeasonTrace:
    metrics, reward = _season(env, schedule, key)
    reached = metrics.cumulative_yield >= FIRST_HARVEST_KG
    first = jnp.where(jnp.any(reached), jnp.argmax(reached) + 1, -1).astype(jnp.int32)
    return SeasonTrace(
        metrics=metrics, reward=reward, episode_return=jnp.sum(reward), first_harvest_day=first
    )


def _base_env(env) -> GreenhouseEnv:
    """The ``GreenhouseEnv`` below wrappers such as ``ActionRepeat`` (they keep it as ``.env``)."""
    while not isinstance(env, GreenhouseEnv) and hasattr(env, "env"):
        env = env.env
    if not isinstance(env, GreenhouseEnv):
        raise TypeError(f"expected a GreenhouseEnv (or a wrapper of one), got {type(env).__name__}")
    return env


def _key(key: jax.Array | None) -> jax.Array:
    return jax.random.PRNGKey(0) if key is None else key


def season_returns(env, schedules: jax.Array, key: jax.Array | None = None) -> jax.Array:
    """True season returns of a batch of schedules, through ``env.step``: ``[B]``.

    ``schedules``: normalised ``[B, n, max_dim]`` (each held every day) or
    ``[B, D, n, max_dim]`` (one action per day; fewer than ``season_days`` rows hold the last).
    ``key`` is the reset key shared by every candidate (default ``PRNGKey(0)``; it only matters
    with ``start_day_jitter``). Compiled once per env config and batch shape.
    """
    return _batched_returns(_base_env(env), jnp.asarray(schedules, jnp.float32), _key(key))


def evaluate_schedule(env, schedule: jax.Array, key: jax.Array | None = None) -> float:
    """True season return of one schedule (``[n, max_dim]`` or ``[D, n, max_dim]``)."""
    return float(season_returns(env, jnp.asarray(schedule)[None], key)[0])


def schedule_trace(env, schedule: jax.Array, key: jax.Array | None = None) -> SeasonTrace:
    """The whole ``SeasonTrace`` (metrics per day) of one schedule, for ``season.summarize``."""
    return _trace(_base_env(env), jnp.asarray(schedule, jnp.float32), _key(key))


# --- the best constant action ---------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class ConstantResult:
    """The best constant action found.

    action: normalised ``[n, max_dim]`` (what ``env.step`` receives every day).
    physical: ``[n, max_dim]`` in physical units (°C, ppm, hours), ``space.to_physical(action)``.
    season_return: its true season return. seasons_evaluated: candidate seasons simulated.
    seconds: wall time of the search, compilation included.
    """

    action: np.ndarray
    physical: np.ndarray
    season_return: float
    seasons_evaluated: int
    seconds: float


def _row_mask(space: CompositeSpace, names: tuple[str, ...]) -> np.ndarray:
    """``[n, max_dim]`` bool: the real dims of the sub-spaces called ``names`` (if present)."""
    rows = np.zeros((space.n, 1), bool)
    for name in names:
        if name in space.names:
            rows[space.index(name)] = True
    return rows & space.dim_mask


def _grid_values(space: CompositeSpace, n_grid: int) -> np.ndarray:
    """``[G]`` normalised grid values used by the coordinate sweep of the hour dims."""
    choices = int(space.n_choices.max())
    g = choices if choices > 0 else n_grid
    return np.linspace(-1.0, 1.0, g, dtype=np.float32)


def _random_candidates(space: CompositeSpace, key: jax.Array, batch: int) -> jax.Array:
    """``[batch, n, max_dim]``: half uniform over the whole space, half "level + noise" profiles.

    Uniform draws of 24 hourly setpoints almost never give a flat or near-flat profile, which
    is what a held action likely wants; the second half draws a level per row and hourly noise
    of a random scale (0 = flat), hour dims uniform on their grid in both halves.
    """
    k_uni, k_lvl, k_scale, k_noise, k_hours = jax.random.split(key, 5)
    uniform = space.sample(k_uni, (batch,))
    half = batch // 2
    level = jax.random.uniform(k_lvl, (half, space.n, 1), minval=-1.0, maxval=1.0)
    scale = jax.random.uniform(k_scale, (half, space.n, 1), maxval=0.5)
    noise = jax.random.normal(k_noise, (half, space.n, space.max_dim))
    profile = jnp.clip(level + scale * noise, -1.0, 1.0)
    hours = space.sample(k_hours, (half,))
    profile = jnp.where(_row_mask(space, CONTINUOUS_ROWS), profile, hours)
    out = uniform.at[:half].set(profile)
    return jnp.where(space.dim_mask, out, 0.0)


def _snap(space: CompositeSpace, a: jax.Array) -> jax.Array:
    """Clip to [-1, 1], discrete dims onto their grid, padded columns zero."""
    return space.from_physical(space.to_physical(jnp.clip(a, -1.0, 1.0)))


def _refine_candidates(
    space: CompositeSpace,
    key: jax.Array,
    elites: jax.Array,
    sigma: jax.Array,
    batch: int,
    n_grid: int,
) -> jax.Array:
    """``[batch, n, max_dim]`` candidates around ``elites`` ``[K, n, max_dim]`` (best first).

    Three kinds, every candidate snapped back into the space:
    - coordinate sweep: the best with one hour dim set to each grid value (hour dims interact
      with the season through thresholds, where small steps see nothing);
    - row shifts: the best with a whole setpoint row moved up or down by a multiple of sigma;
    - perturbations: a random elite with Gaussian noise (std ``sigma``) on a random ~quarter of
      its continuous dims, plus a random common shift of one row, and each hour dim moved by
      +-1 or +-2 grid steps with probability 0.15.
    """
    best = elites[0]
    grid = jnp.asarray(_grid_values(space, n_grid))
    hour_mask = _row_mask(space, HOURS)
    rows, cols = np.nonzero(hour_mask)
    n_dims, n_values = len(rows), grid.shape[0]
    coord = jnp.broadcast_to(best, (n_dims, n_values, space.n, space.max_dim))
    which_dim, which_value = np.arange(n_dims)[:, None], np.arange(n_values)[None, :]
    coord = coord.at[which_dim, which_value, rows[:, None], cols[:, None]].set(grid[None, :])
    coord = coord.reshape(-1, space.n, space.max_dim)
    cont_rows = [space.index(n) for n in CONTINUOUS_ROWS if n in space.names]
    deltas = jnp.asarray([-8.0, -4.0, -2.0, -1.0, -0.5, 0.5, 1.0, 2.0, 4.0, 8.0]) * sigma
    shifts = []
    for r in cont_rows:
        row = np.zeros((space.n, space.max_dim), np.float32)
        row[r] = space.dim_mask[r]
        shifts.append(best[None] + deltas[:, None, None] * row[None])
    shifts = jnp.concatenate(shifts) if shifts else jnp.zeros((0, space.n, space.max_dim))
    n_perturb = batch - coord.shape[0] - shifts.shape[0]
    if n_perturb < 1:
        fixed = coord.shape[0] + shifts.shape[0]
        raise ValueError(f"batch {batch} too small: the sweep and row shifts alone take {fixed}")
    k_pick, k_sel, k_noise, k_row, k_shift, k_hsel, k_step = jax.random.split(key, 7)
    parents = elites[jax.random.randint(k_pick, (n_perturb,), 0, elites.shape[0])]
    cont = jnp.asarray(_row_mask(space, CONTINUOUS_ROWS))
    chosen = jax.random.uniform(k_sel, parents.shape) < 0.25
    noise = sigma * jax.random.normal(k_noise, parents.shape) * (chosen & cont)
    which = jax.random.randint(k_row, (n_perturb,), 0, max(len(cont_rows), 1))
    row_of = jnp.asarray(cont_rows or [0])[which]
    row_hit = (jnp.arange(space.n)[None, :] == row_of[:, None])[:, :, None] & cont
    noise = noise + sigma * jax.random.normal(k_shift, (n_perturb, 1, 1)) * row_hit
    steps = jnp.maximum(space.n_choices - 1, 1).astype(jnp.float32)
    step_size = jnp.where(space.discrete_mask, 2.0 / steps, 2.0 / (n_grid - 1))
    move = jax.random.choice(k_step, jnp.asarray([-2.0, -1.0, 1.0, 2.0]), parents.shape)
    hour_hit = (jax.random.uniform(k_hsel, parents.shape) < 0.15) & hour_mask
    noise = noise + move * step_size * hour_hit
    out = jnp.concatenate([coord, shifts, parents + noise])
    return jax.vmap(lambda a: _snap(space, a))(out)


_random_candidates_jit = jax.jit(_random_candidates, static_argnums=(0, 2))
_refine_candidates_jit = jax.jit(_refine_candidates, static_argnums=(0, 4, 5))


def best_constant_schedule(
    env,
    key: jax.Array,
    *,
    n_random: int = 4096,
    rounds: int = 40,
    batch: int = 512,
    n_elites: int = 16,
    sigma: tuple[float, float] = (0.3, 0.03),
    n_grid: int = 25,
) -> ConstantResult:
    """Search the best constant action (held every day of a season).

    Args:
      env: a ``GreenhouseEnv`` (or a wrapper of one); its reward defines "best".
      key: PRNG key of the search (the result is a deterministic function of it).
      n_random: candidates of the random phase (rounded up to a multiple of ``batch``); the
        default action is always one of them.
      rounds: refinement rounds after it, ``batch`` candidates each.
      batch: seasons per compiled call (the one batch shape, hence one compilation).
      n_elites: best actions kept (over everything evaluated) to perturb around.
      sigma: (first, last) perturbation std in normalised units, geometric in between.
      n_grid: sweep points of continuous hour dims (``discrete_hours=False``); discrete hour
        dims sweep their own grid.
    Returns: ``ConstantResult`` (cost: ``rounds * batch + n_random`` seasons).
    """
    t0 = time.perf_counter()
    env = _base_env(env)
    space = env.space
    key_reset, key_random, key_refine = jax.random.split(key, 3)
    n_chunks = max(1, math.ceil(n_random / batch))

    pool_a, pool_r = [], []
    for i, k in enumerate(jax.random.split(key_random, n_chunks)):
        cand = _random_candidates_jit(space, k, batch)
        if i == 0:
            cand = cand.at[0].set(space.default_action())
        pool_a.append(np.asarray(cand))
        pool_r.append(np.asarray(season_returns(env, cand, key_reset)))
    actions, returns = _top(np.concatenate(pool_a), np.concatenate(pool_r), n_elites)
    evaluated = n_chunks * batch
    for r, k in enumerate(jax.random.split(key_refine, rounds)):
        s = sigma[0] * (sigma[1] / sigma[0]) ** (r / max(rounds - 1, 1))
        cand = _refine_candidates_jit(space, k, jnp.asarray(actions), jnp.float32(s), batch, n_grid)
        ret = np.asarray(season_returns(env, cand, key_reset))
        pooled = np.concatenate([actions, np.asarray(cand)])
        actions, returns = _top(pooled, np.concatenate([returns, ret]), n_elites)
        evaluated += batch
    best = jnp.asarray(actions[0])
    return ConstantResult(
        action=np.asarray(best),
        physical=np.asarray(space.to_physical(best)),
        season_return=float(returns[0]),
        seasons_evaluated=evaluated,
        seconds=time.perf_counter() - t0,
    )


def _top(actions: np.ndarray, returns: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` best distinct actions, best first (stable order: deterministic ties; NaN last)."""
    returns = np.where(np.isfinite(returns), returns, -np.inf)
    order = np.argsort(-returns, kind="stable")
    _, first = np.unique(actions[order].reshape(len(order), -1), axis=0, return_index=True)
    keep = order[np.sort(first)][:k]
    return actions[keep], returns[keep]


# --- the smooth relaxation of the hour timers -----------------------------------------------------
def _ramp_integral(x: jax.Array, width: float) -> jax.Array:
    """``int_{-inf}^{x} sigmoid(u / width) du = width * softplus(x / width)`` (-> max(x, 0))."""
    return width * jax.nn.softplus(x / width)


def relaxed_on_fraction(
    start: jax.Array, duration: jax.Array, substeps_per_hour: int, width: float
) -> jax.Array:
    """Smooth timer: fraction of every sub-step inside a window with logistic edges, ``[24, S]``.

    The window starts at ``start`` hours (any real number: the day is a circle, so it is
    taken modulo 24 and wraps past midnight) and lasts ``duration`` hours (0 = off, up to 24).
    Its indicator becomes ``sigmoid((t - a) / width) - sigmoid((t - a - duration) / width)``,
    integrated exactly over each sub-step (``_ramp_integral``), for the window and its
    copies one day earlier and later. As ``width -> 0`` this is exactly the hard timer
    ``actions.on_fraction(start, (start + duration) % 24)`` (tested); unlike the (start, end)
    form it is continuous everywhere, since the wrap at ``end == start`` (off <-> 24 h on)
    happens at the edges of the duration's range, not inside it.
    """
    dt = 1.0 / substeps_per_hour
    t0 = jnp.arange(24 * substeps_per_hour, dtype=jnp.float32).reshape(24, substeps_per_hour) * dt
    s = jnp.mod(start, 24.0)
    frac = jnp.zeros_like(t0)

    def g(x):
        return _ramp_integral(x, width)

    for k in (-1.0, 0.0, 1.0):
        a = s + 24.0 * k
        b = a + duration
        frac = frac + (g(t0 + dt - a) - g(t0 - a) - g(t0 + dt - b) + g(t0 - b)) / dt
    return jnp.clip(frac, 0.0, 1.0)


@struct.dataclass
class RelaxedSchedule:
    """Unconstrained parameters of a relaxed schedule (leading axes: decisions).

    setpoints: ``[..., n_rows, 24]`` pre-tanh normalised setpoints of the temperature and CO2
      rows (``tanh`` maps them into [-1, 1], then the space's bounds apply).
    start: ``[..., n_timers]`` timer start in units of ``START_SCALE`` hours (periodic).
    duration: ``[..., n_timers]`` pre-sigmoid duration (``max_duration * sigmoid``).
    """

    setpoints: jax.Array
    start: jax.Array
    duration: jax.Array


# Hours per unit of RelaxedSchedule.start: Adam moves every parameter by about its learning
# rate per step, which in hours would be far slower than in the squashed setpoints.
START_SCALE = 4.0
_EDGE = 1e-3  # keeps tanh / sigmoid preimages finite for values on the bounds


def _max_duration(space: CompositeSpace) -> float:
    """Longest timer window: 23 h on the 0..23 grid (start == end is off), 24 h continuous."""
    s = space.subspaces[space.index(HOURS[0])]
    return float(s.n_choices - 1) if s.kind == "discrete" else float(s.high[0] - s.low[0])


def relax(space: CompositeSpace, action: jax.Array) -> RelaxedSchedule:
    """Normalised actions ``[..., n, max_dim]`` -> the ``RelaxedSchedule`` that reproduces them."""
    x = space.to_physical(action)
    a = jnp.clip(jnp.asarray(action, jnp.float32), -1.0 + _EDGE, 1.0 - _EDGE)
    rows = [space.index(n) for n in CONTINUOUS_ROWS]
    setpoints = jnp.arctanh(jnp.stack([a[..., r, :24] for r in rows], axis=-2))
    timers = jnp.stack([x[..., space.index(n), :2] for n in HOURS], axis=-2)  # [..., 2, 2]
    start, end = timers[..., 0], timers[..., 1]
    # The env's timer: end > start is [start, end), end < start wraps, end == start is off.
    wrapped = jnp.where(end < start, end - start + 24.0, 0.0)
    duration = jnp.where(end > start, end - start, wrapped)
    frac = jnp.clip(duration / _max_duration(space), _EDGE, 1.0 - _EDGE)
    logit = jnp.log(frac) - jnp.log1p(-frac)
    return RelaxedSchedule(setpoints=setpoints, start=start / START_SCALE, duration=logit)


def _hours(space: CompositeSpace, p: RelaxedSchedule) -> tuple[jax.Array, jax.Array]:
    """Start in [0, 24) and duration in (0, max) hours of the two timers, ``[..., 2]`` each."""
    start = jnp.mod(p.start * START_SCALE, 24.0)
    return start, _max_duration(space) * jax.nn.sigmoid(p.duration)


def relaxed_schedule(
    space: CompositeSpace, p: RelaxedSchedule, substeps_per_hour: int, width: float
) -> dict[str, jax.Array]:
    """One day's relaxed parameters (no leading axes) -> the hourly schedule that
    ``env.step_schedule`` reads: ``temp_sp [24]``, ``co2_sp [24]``, ``lamp [24, S]``,
    ``irrigation [24, S]``."""
    out = {}
    for j, (name, key) in enumerate(zip(CONTINUOUS_ROWS, ("temp_sp", "co2_sp"), strict=True)):
        r = space.index(name)
        lo, hi = space.low[r, :24], space.high[r, :24]
        out[key] = lo + (jnp.tanh(p.setpoints[j]) + 1.0) * 0.5 * (hi - lo)
    start, duration = _hours(space, p)
    out["lamp"] = relaxed_on_fraction(start[0], duration[0], substeps_per_hour, width)
    out["irrigation"] = relaxed_on_fraction(start[1], duration[1], substeps_per_hour, width)
    return out


def round_schedule(space: CompositeSpace, p: RelaxedSchedule) -> jax.Array:
    """Relaxed parameters ``[...]`` -> normalised actions ``[..., n, max_dim]`` for ``env.step``.

    Setpoints go through tanh (within ``2 * _EDGE`` of a bound: onto it, so that ``relax``
    followed by this returns the action it started from); discrete timers round start and
    duration to whole hours (end = start + duration modulo 24), continuous timers keep them.
    """
    start, duration = _hours(space, p)
    if space.subspaces[space.index(HOURS[0])].kind == "discrete":
        # whole hours 0..23: end = start + duration wraps modulo 24 (23 + 1 -> 0, not 24)
        start = jnp.mod(jnp.round(start), 24.0)
        end = jnp.mod(start + jnp.round(duration), 24.0)
    else:  # hours in [0, 24]: keep end = 24 (a window to midnight), wrap beyond it
        end = start + duration
        end = jnp.where(end > 24.0, end - 24.0, end)
    lead = p.setpoints.shape[:-2]
    x = jnp.zeros((*lead, space.n, space.max_dim), jnp.float32)
    a = space.from_physical(x)
    for j, name in enumerate(CONTINUOUS_ROWS):
        v = jnp.tanh(p.setpoints[..., j, :])
        v = jnp.where(jnp.abs(v) > 1.0 - 2.0 * _EDGE, jnp.sign(v), v)
        a = a.at[..., space.index(name), :24].set(v)
    phys = space.to_physical(a)
    for j, name in enumerate(HOURS):
        r = space.index(name)
        phys = phys.at[..., r, 0].set(start[..., j]).at[..., r, 1].set(end[..., j])
    hours = space.from_physical(phys)
    return jnp.where(_row_mask(space, CONTINUOUS_ROWS), a, hours)


# --- the best open-loop schedule ------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class OpenLoopResult:
    """The best open-loop schedule found.

    schedule: normalised ``[season_days, n, max_dim]``, hours on the grid (what ``env.step``
      receives day by day). physical: the same in physical units.
    season_return: its true season return (``env.step``), >= ``constant_return``.
    relaxed_return: the relaxed objective at the end of the ascent (fractional hours).
    rounded_return: true return of the best rounded snapshot of the ascent (may be below the
      constant's; then the constant is kept and ``source == "constant"``).
    constant_return: the starting constant's return. source: ``"open-loop"`` or ``"constant"``.
    history: ``[steps]`` relaxed objective before each Adam step.
    grad_finite: every gradient of the ascent was finite.
    steps, hold_days: Adam steps; days each decision is held (1 = daily decisions).
    seconds: wall time (constant search excluded), compilation included.
    """

    schedule: np.ndarray
    physical: np.ndarray
    season_return: float
    relaxed_return: float
    rounded_return: float
    constant_return: float
    source: str
    history: np.ndarray
    grad_finite: bool
    steps: int
    hold_days: int
    seconds: float


def _expand(p: RelaxedSchedule, days: int, hold_days: int) -> RelaxedSchedule:
    """Decisions ``[N, ...]`` -> days ``[days, ...]``: decision ``d // hold_days`` on day ``d``."""
    idx = np.arange(days) // hold_days
    return jax.tree.map(lambda x: x[idx], p)


def relaxed_return(
    env: GreenhouseEnv, p: RelaxedSchedule, key: jax.Array, width: float, hold_days: int = 1
) -> jax.Array:
    """The relaxed season objective: ``[]`` sum of rewards of ``env.step_schedule`` under the
    relaxed schedule of the decisions ``p`` (leading axis ``ceil(season_days / hold_days)``)."""
    days = env.episode_length
    per_day = _expand(p, days, hold_days)
    sub = env.config.substeps_per_hour

    def day(state, q):
        state = env.step_schedule(state, relaxed_schedule(env.space, q, sub, width))
        return state, state.reward

    _, rewards = jax.lax.scan(day, env.reset(key), per_day)
    return jnp.sum(rewards)


def _ascent_chunk(env, params, opt_state, key, width, *, n_steps, hold_days, learning_rate):
    """``n_steps`` Adam steps of gradient ascent on the relaxed return (one ``lax.scan``)."""
    opt = optax.adam(learning_rate)
    value_and_grad = jax.value_and_grad(lambda q: relaxed_return(env, q, key, width, hold_days))

    def step(carry, _):
        q, s = carry
        value, grad = value_and_grad(q)
        finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(g)) for g in jax.tree.leaves(grad)]))
        # Ascent: minimise the negative. A non-finite gradient entry contributes nothing, so
        # one bad step cannot poison Adam's moments; ``finite`` reports it.
        grad = jax.tree.map(lambda g: -jnp.nan_to_num(g, posinf=0.0, neginf=0.0), grad)
        updates, s = opt.update(grad, s)
        return (optax.apply_updates(q, updates), s), (value, finite)

    carry = (params, opt_state)
    (params, opt_state), (values, finite) = jax.lax.scan(step, carry, None, length=n_steps)
    return params, opt_state, values, finite


_ascent_chunk_jit = jax.jit(
    _ascent_chunk, static_argnames=("n_steps", "hold_days", "learning_rate")
)
_relaxed_return_jit = jax.jit(relaxed_return, static_argnames=("hold_days",))


def best_open_loop_schedule(
    env,
    key: jax.Array,
    *,
    constant: ConstantResult | None = None,
    steps: int = 200,
    snapshots: int = 8,
    learning_rate: float = 0.1,
    width: float = 0.5,
    hold_days: int = 1,
    constant_kwargs: dict[str, Any] | None = None,
) -> OpenLoopResult:
    """Gradient ascent (Adam) on a per-day schedule through the differentiable simulator.

    Args:
      env: a ``GreenhouseEnv`` (or a wrapper of one).
      key: PRNG key: reset key of the season, and of the constant search if ``constant`` is None.
      constant: the starting point (``best_constant_schedule``'s result); searched if None
        (with ``constant_kwargs``).
      steps: Adam steps in all (rounded up to a multiple of ``snapshots``).
      snapshots: the ascent is cut into this many equal chunks; each chunk's end is rounded to
        the hour grid and all of them are re-evaluated with ``env.step`` in one batched call.
      learning_rate: Adam's step size in the unconstrained parameters.
      width: logistic edge width of the relaxed timers, hours.
      hold_days: days one decision is held (1 = daily decisions; 8 = the learner's default
        action repeat), so ``ceil(season_days / hold_days)`` decisions are optimised.
    Returns: ``OpenLoopResult``; its schedule is the better of the rounded optimum and the
      constant, so ``season_return >= constant.season_return``.
    """
    env = _base_env(env)
    key_reset = jax.random.split(key, 3)[0]  # the same reset key as best_constant_schedule's
    if constant is None:
        constant = best_constant_schedule(env, key, **(constant_kwargs or {}))
    t0 = time.perf_counter()
    space, days = env.space, env.episode_length
    n_dec = -(-days // hold_days)
    start = jnp.broadcast_to(jnp.asarray(constant.action), (n_dec, space.n, space.max_dim))
    params = relax(space, start)
    opt_state = optax.adam(learning_rate).init(params)
    chunk = -(-steps // snapshots)
    width = jnp.float32(width)
    snaps, history, finite = [], [], []
    for _ in range(snapshots):
        params, opt_state, values, ok = _ascent_chunk_jit(
            env,
            params,
            opt_state,
            key_reset,
            width,
            n_steps=chunk,
            hold_days=hold_days,
            learning_rate=learning_rate,
        )
        snaps.append(params)
        history.append(np.asarray(values))
        finite.append(np.asarray(ok))
    final_relaxed = float(_relaxed_return_jit(env, params, key_reset, width, hold_days=hold_days))
    # Every snapshot rounded to the grid and re-evaluated with the real env.step, one call.
    stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *snaps)
    expand = jax.vmap(lambda q: round_schedule(space, _expand(q, days, hold_days)))
    rounded = expand(stacked)  # [snapshots, D, n, max_dim]
    true = np.asarray(season_returns(env, rounded, key_reset))
    best = int(np.argmax(np.where(np.isfinite(true), true, -np.inf)))
    rounded_return = float(true[best])
    if rounded_return > constant.season_return:
        schedule, value, source = np.asarray(rounded[best]), rounded_return, "open-loop"
    else:
        schedule = np.broadcast_to(constant.action, (days, space.n, space.max_dim)).copy()
        value, source = constant.season_return, "constant"
    return OpenLoopResult(
        schedule=schedule,
        physical=np.asarray(space.to_physical(jnp.asarray(schedule))),
        season_return=value,
        relaxed_return=final_relaxed,
        rounded_return=rounded_return,
        constant_return=constant.season_return,
        source=source,
        history=np.concatenate(history),
        grad_finite=bool(np.all(np.concatenate(finite))),
        steps=chunk * snapshots,
        hold_days=hold_days,
        seconds=time.perf_counter() - t0,
    )


# --- cached references for reports ----------------------------------------------------------------
# The modules whose code decides a reference's value (the expert's does not).
_SOURCE_MODULES = ("references", "env", "simulate", "climate", "crop", "water", "actions")


def code_version() -> str:
    """Hash of the sources that determine a reference's value (this module and the simulator)."""
    h = hashlib.sha256()
    here = os.path.dirname(os.path.abspath(__file__))
    for name in _SOURCE_MODULES:
        with open(os.path.join(here, f"{name}.py"), "rb") as f:
            h.update(f.read())
    return h.hexdigest()[:16]


def _env_fingerprint(env: GreenhouseEnv) -> str:
    """Hash of everything that defines the environment: config, space and every array leaf."""
    h = hashlib.sha256()
    h.update(repr(sorted(dataclasses.asdict(env.config).items())).encode())
    h.update(repr(env.space).encode())
    for leaf in jax.tree.leaves(env):
        x = np.asarray(leaf)
        h.update(str((x.dtype, x.shape)).encode())
        h.update(np.ascontiguousarray(x).tobytes())
    return h.hexdigest()


def _key_data(key: jax.Array) -> jax.Array:
    """Raw uint32 data of a legacy or typed PRNG key."""
    return jax.random.key_data(key) if jnp.issubdtype(key.dtype, jax.dtypes.prng_key) else key


def default_cache_dir() -> str:
    """``$SCORE_JAX_CACHE/references``, else ``$XDG_CACHE_HOME/score-jax/references``, else
    ``~/.cache/score-jax/references``."""
    xdg = os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache")
    root = os.environ.get("SCORE_JAX_CACHE") or os.path.join(xdg, "score-jax")
    return os.path.join(root, "references")


REFERENCE_NAMES = ("best constant", "open-loop")


def _read_cache(path: str, cache_key: str) -> dict | None:
    """The cached entry at ``path`` if it is valid for ``cache_key``, else None (never raises)."""
    try:
        with open(path) as f:
            entry = json.load(f)
        returns = entry["returns"]
        ok = entry.get("format") == CACHE_FORMAT and entry.get("cache_key") == cache_key
        ok = ok and isinstance(returns, dict) and set(returns) == set(REFERENCE_NAMES)
        ok = ok and all(isinstance(v, (int, float)) and math.isfinite(v) for v in returns.values())
        ok = ok and set(entry["schedules"]) == set(REFERENCE_NAMES)
        return entry if ok else None
    except Exception:  # unreadable, not JSON, wrong layout: recompute
        return None


def _write_cache(path: str, entry: dict) -> None:
    """Atomic write (temp file + rename): a concurrent reader never sees half a file."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(path), suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(entry, f, indent=1)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def greenhouse_references(
    env,
    key: jax.Array | None = None,
    *,
    cache_dir: str | None = None,
    use_cache: bool = True,
    constant_kwargs: dict[str, Any] | None = None,
    open_loop_kwargs: dict[str, Any] | None = None,
) -> dict[str, float]:
    """``{"best constant": return, "open-loop": return}`` for ``env`` (wrappers are looked through).

    Cached as JSON under ``cache_dir`` (default ``default_cache_dir()``), one file per
    (environment fingerprint, key, search settings, code version); a missing, corrupt or
    mismatching file is recomputed and rewritten. ``use_cache=False`` neither reads nor writes.
    """
    entry = _reference_entry(env, key, cache_dir, use_cache, constant_kwargs, open_loop_kwargs)
    return {k: float(entry["returns"][k]) for k in REFERENCE_NAMES}


def reference_schedules(
    env,
    key: jax.Array | None = None,
    *,
    hold_days: int = 1,
    cache_dir: str | None = None,
    use_cache: bool = True,
    constant_kwargs: dict[str, Any] | None = None,
    open_loop_kwargs: dict[str, Any] | None = None,
) -> dict[str, np.ndarray]:
    """The two references as schedules, by name: ``"best constant"`` normalised ``[n, max_dim]``
    and ``"open-loop"`` ``[season_days, n, max_dim]`` optimised for decisions held ``hold_days``
    days (the open-loop rows are constant over each decision). Same cache as
    ``greenhouse_references`` (``hold_days`` is part of the search settings)."""
    loop = {**(open_loop_kwargs or {}), "hold_days": int(hold_days)}
    entry = _reference_entry(env, key, cache_dir, use_cache, constant_kwargs, loop)
    return {k: np.asarray(entry["schedules"][k], np.float32) for k in REFERENCE_NAMES}


def schedule_policy(schedule: np.ndarray):
    """A ``ReferencePolicy`` that plays ``schedule`` (``[n, max_dim]`` every day, or
    ``[D, n, max_dim]`` indexed by the state's day planted, the last row held after ``D``)."""
    table = jnp.asarray(schedule, jnp.float32)
    if table.ndim == 2:
        return lambda state: table
    return lambda state: table[jnp.minimum(state.sim.day, table.shape[0] - 1)]


def _reference_entry(env, key, cache_dir, use_cache, constant_kwargs, open_loop_kwargs) -> dict:
    """The cache entry (returns and schedules) of both searches, searched when not cached."""
    env = _base_env(env)
    key = _key(key)
    settings = {"constant": constant_kwargs or {}, "open_loop": open_loop_kwargs or {}}
    ident = {
        "env": _env_fingerprint(env),
        "key": np.asarray(_key_data(key)).tolist(),
        "settings": json.loads(json.dumps(settings, sort_keys=True, default=str)),
        "code": code_version(),
    }
    cache_key = hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest()
    path = os.path.join(cache_dir or default_cache_dir(), f"{cache_key[:32]}.json")
    if use_cache:
        entry = _read_cache(path, cache_key)
        if entry is not None:
            return entry
    const = best_constant_schedule(env, key, **(constant_kwargs or {}))
    loop = best_open_loop_schedule(env, key, constant=const, **(open_loop_kwargs or {}))
    entry = {
        "format": CACHE_FORMAT,
        "cache_key": cache_key,
        "ident": ident,
        "config": dataclasses.asdict(env.config),
        "returns": {"best constant": const.season_return, "open-loop": loop.season_return},
        "schedules": {"best constant": const.action.tolist(), "open-loop": loop.schedule.tolist()},
        "constant_physical": const.physical.tolist(),
        "cost_s": {"best constant": const.seconds, "open-loop": loop.seconds},
        "seasons_evaluated": const.seasons_evaluated,
        "open_loop_source": loop.source,
    }
    if use_cache:
        try:
            _write_cache(path, entry)
        except OSError:  # a read-only or full disk costs the next call a search, not this one
            pass
    return entry
