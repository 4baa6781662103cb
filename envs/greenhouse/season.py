"""Whole seasons: run a policy for a season in one ``lax.scan``, summarise and plot it.

    env = make_greenhouse()
    traces = {name: run_season(env, policy, key) for name, policy in standard_policies(env).items()}
    print(format_summary(traces))
    plot_season(traces, "season.png")

A policy is ``policy_fn(env, state, key) -> action`` (normalised ``[n, max_dim]``), pure jnp.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs.base import EnvState
from envs.greenhouse.expert import expert_action

Policy = Callable[[object, EnvState, jax.Array], jax.Array]
FIRST_HARVEST_KG = (
    0.1  # kg/m²: a season's first harvest = cumulative yield reaching ~one fruit per m²
)


@struct.dataclass
class SeasonTrace:
    """One season (or a batch of seasons: add leading axes).

    metrics: ``GreenhouseMetrics`` with ``[days]`` fields; reward: ``[days]``;
    episode_return: ``[]`` sum of rewards; first_harvest_day: ``[]`` int32 day (1-based days
    planted) when the cumulative yield first reaches ``FIRST_HARVEST_KG``, -1 if never.
    """

    metrics: object
    reward: jax.Array
    episode_return: jax.Array
    first_harvest_day: jax.Array


# --- policies ---------------------------------------------------------------------------------
def expert_policy(env, state: EnvState, key: jax.Array) -> jax.Array:
    """The grower heuristic (``expert.py``)."""
    del key
    return expert_action(env, state)


def default_policy(env, state: EnvState, key: jax.Array) -> jax.Array:
    """Every controller at its default (19 °C, 550 ppm, lamps 6-18, irrigation 7-17)."""
    del state, key
    return env.space.default_action()


def random_policy(env, state: EnvState, key: jax.Array) -> jax.Array:
    """Uniformly random sub-actions every day."""
    del state
    return env.space.sample(key)


def standard_policies() -> dict[str, Policy]:
    """The reference policies a user compares a learner with."""
    return {"expert": expert_policy, "default": default_policy, "random": random_policy}


# --- running ------------------------------------------------------------------------------------
def _run_season(env, policy_fn: Policy, key: jax.Array, num_days: int) -> SeasonTrace:
    key_reset, key_policy = jax.random.split(key)
    state = env.reset(key_reset)

    def day(state, key_day):
        state = env.step(state, policy_fn(env, state, key_day))
        return state, (state.metrics, state.reward)

    _, (metrics, reward) = jax.lax.scan(day, state, jax.random.split(key_policy, num_days))
    reached = metrics.cumulative_yield >= FIRST_HARVEST_KG
    first = jnp.where(jnp.any(reached), jnp.argmax(reached) + 1, -1).astype(jnp.int32)
    return SeasonTrace(
        metrics=metrics, reward=reward, episode_return=jnp.sum(reward), first_harvest_day=first
    )


@functools.partial(jax.jit, static_argnames=("policy_fn", "num_days"))
def _run_season_jit(env, policy_fn, key, num_days):
    return _run_season(env, policy_fn, key, num_days)


@functools.partial(jax.jit, static_argnames=("policy_fn", "num_days"))
def _run_seasons_jit(env, policy_fn, keys, num_days):
    return jax.vmap(lambda k: _run_season(env, policy_fn, k, num_days))(keys)


def run_season(env, policy_fn: Policy, key: jax.Array, num_days: int | None = None) -> SeasonTrace:
    """Run one season (``env.episode_length`` days unless ``num_days``) as one jitted scan.

    ``policy_fn(env, state, key) -> action`` must be hashable (a module-level function or a
    ``functools.partial``); a new one compiles once.
    """
    return _run_season_jit(env, policy_fn, key, int(num_days or env.episode_length))


def run_seasons(
    env, policy_fn: Policy, keys: jax.Array, num_days: int | None = None
) -> SeasonTrace:
    """``run_season`` for a batch of keys ``[B, 2]`` (vmapped): fields get a leading ``B`` axis."""
    return _run_seasons_jit(env, policy_fn, keys, int(num_days or env.episode_length))


# --- reporting ----------------------------------------------------------------------------------
def summarize(trace: SeasonTrace) -> dict[str, float]:
    """Season totals (averaged over a leading batch axis if any)."""
    m = jax.tree.map(np.asarray, trace.metrics)

    def total(x):
        return float(np.mean(np.sum(x, axis=-1)))

    return {
        "yield_kg_m2": float(np.mean(m.cumulative_yield[..., -1])),
        "return": float(np.mean(np.asarray(trace.episode_return))),
        "first_harvest_day": float(np.mean(np.asarray(trace.first_harvest_day))),
        "heating_mj_m2": total(m.heating_mj),
        "co2_kg_m2": total(m.co2_kg),
        "electricity_kwh_m2": total(m.electricity_kwh),
        "profit_eur_m2": total(m.profit),
        "mean_temp_in": float(np.mean(m.temp_in)),
        "water_stress": float(np.mean(m.water_stress)),
    }


def format_summary(traces: Mapping[str, SeasonTrace]) -> str:
    """A plain-text table, one row per policy."""
    cols = (
        "yield_kg_m2",
        "return",
        "first_harvest_day",
        "heating_mj_m2",
        "co2_kg_m2",
        "electricity_kwh_m2",
        "profit_eur_m2",
        "mean_temp_in",
    )
    head = f"{'policy':<10s}" + "".join(f"{c:>20s}" for c in cols)
    rows = [head]
    for name, tr in traces.items():
        s = summarize(tr)
        rows.append(f"{name:<10s}" + "".join(f"{s[c]:>20.2f}" for c in cols))
    return "\n".join(rows)


def plot_season(
    traces: SeasonTrace | Mapping[str, SeasonTrace], path: str, title: str | None = None
) -> str:
    """Save a 2x2 figure: cumulative yield, indoor vs outdoor temperature, indoor CO2, energy.

    ``traces``: one trace or ``{policy name: trace}``; batched traces are averaged over seeds.
    Returns ``path``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if isinstance(traces, SeasonTrace):
        traces = {"policy": traces}
    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5), sharex=True)
    (ax_y, ax_t), (ax_c, ax_e) = axes
    outdoor_drawn = False
    for name, tr in traces.items():
        m = jax.tree.map(lambda x: np.asarray(x).reshape(-1, np.shape(x)[-1]).mean(0), tr.metrics)
        days = np.arange(1, m.cumulative_yield.shape[-1] + 1)
        (line,) = ax_y.plot(days, m.cumulative_yield, label=name)
        ax_t.plot(days, m.temp_in, color=line.get_color(), label=f"{name} indoor")
        if not outdoor_drawn:
            ax_t.plot(days, m.temp_out, color="0.5", lw=0.8, label="outdoor")
            outdoor_drawn = True
        ax_c.plot(days, m.co2_in, color=line.get_color(), label=name)
        ax_e.plot(days, np.cumsum(m.heating_mj), color=line.get_color(), label=f"{name} heat (MJ)")
        ax_e.plot(
            days,
            np.cumsum(m.electricity_kwh) * 3.6,
            color=line.get_color(),
            ls="--",
            label=f"{name} lamps (MJ el.)",
        )
    ax_y.set_ylabel("cumulative harvest (kg/m²)")
    ax_t.set_ylabel("daily mean temperature (°C)")
    ax_c.set_ylabel("daily mean CO2 (ppm)")
    ax_e.set_ylabel("cumulative energy (MJ/m²)")
    for ax in axes[1]:
        ax.set_xlabel("days after planting")
    for ax in axes.flat:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(title or "Greenhouse tomato season")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
