"""Greenhouse reference policies: weak (default, random, expert) and strong (best constant,
best open-loop schedule), for both bundled climates and both rewards.

    python benchmarks/greenhouse_references.py                 # 2 climates x 2 rewards
    python benchmarks/greenhouse_references.py --climates greensboro --rewards cumulative

Per (climate, reward) it evaluates, each as a whole 160-day season through ``env.step``:
- ``default``: every controller at its default, every day;
- ``random``: uniform random actions, daily or held 8 days (10 seasons: mean ± std);
- ``expert``: the grower heuristic (``expert.py``), deciding daily or every 8 days from that
  day's weather (what ``ActionRepeat(env, 8)`` gives it; checked against it here);
- ``best constant``: ``references.best_constant_schedule`` at its defaults;
- ``open-loop``: ``references.best_open_loop_schedule`` from that constant, daily decisions
  and decisions held 8 days (``hold_days=8``, the learner's default action repeat).
Costs are wall seconds on this machine, compilation included.

Writes ``benchmarks/results/greenhouse_references.json`` (machine, commit, every number, the
constant actions) and ``.md`` (the tables).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from envs.greenhouse import references as refs  # noqa: E402
from envs.greenhouse.env import make_greenhouse  # noqa: E402
from envs.greenhouse.expert import expert_action  # noqa: E402
from envs.greenhouse.season import summarize  # noqa: E402
from envs.greenhouse.weather import bundled_weather_path  # noqa: E402
from envs.wrappers import ActionRepeat  # noqa: E402

OUT = os.path.join(ROOT, "runs", "benchmarks")  # the committed results: --out benchmarks/results
CLIMATES = {"greensboro": None, "sand_point": "703165TY.csv"}
LABELS = {
    "greensboro": "Greensboro NC (723170TYA.CSV)",
    "sand_point": "Sand Point AK (703165TY.csv)",
}
HOLD = 8  # days a decision is held in the "8-day" rows (the learner's default action repeat)
N_RANDOM = 10
QUICK_CONSTANT = {"n_random": 512, "rounds": 2}  # --quick: a smoke test of the script
QUICK_OPEN_LOOP = {"steps": 8, "snapshots": 2}


def expert_schedule_for_season(env, hold_days: int) -> jax.Array:
    """``[D, n, max_dim]``: the expert's action of each day, decided on the first day of its
    ``hold_days`` block (the expert reads only the day and the weather, so this is its
    season exactly)."""
    state = env.reset(jax.random.PRNGKey(0))
    days = np.arange(env.episode_length) // hold_days * hold_days

    def act(d):
        return expert_action(env, state.replace(sim=state.sim.replace(day=d)))

    return jax.vmap(act)(jnp.asarray(days, jnp.int32))


def action_repeat_return(env, hold_days: int) -> float:
    """The expert through ``envs.wrappers.ActionRepeat``, as the learner's report evaluates it."""
    wrapped = ActionRepeat(env, hold_days)

    def season(key):
        def step(state, _):
            state = wrapped.step(state, wrapped.expert_action(state))
            return state, state.reward

        _, rewards = jax.lax.scan(step, wrapped.reset(key), None, wrapped.episode_length)
        return jnp.sum(rewards)

    return float(jax.jit(season)(jax.random.PRNGKey(0)))


def random_schedules(env, key: jax.Array, n: int, hold_days: int) -> jax.Array:
    """``[n, D, n_sub, max_dim]`` uniform random actions, each held ``hold_days`` days."""
    n_dec = -(-env.episode_length // hold_days)
    acts = env.space.sample(key, (n, n_dec))
    return acts[:, np.arange(env.episode_length) // hold_days]


def row(env, name: str, schedule, cost: dict | None = None) -> dict:
    """Season summary (``season.summarize``) of one schedule, plus its search cost if any."""
    s = summarize(refs.schedule_trace(env, schedule))
    out = {"policy": name, **{k: round(v, 3) for k, v in s.items()}}
    if cost:
        out["cost"] = cost
    return out


def random_row(env, name: str, schedules) -> dict:
    """Mean summary of several schedules, and the std of their returns."""
    summaries = [summarize(refs.schedule_trace(env, s)) for s in schedules]
    mean = {k: round(float(np.mean([x[k] for x in summaries])), 3) for k in summaries[0]}
    std = round(float(np.std([x["return"] for x in summaries])), 3)
    return {"policy": name, **mean, "return_std": std}


def _decisions(hold: int) -> str:
    return "daily" if hold == 1 else f"{hold}-day"


def evaluate_climate(climate: str, reward: str, quick: bool = False, log=print) -> dict:
    """Every reference of one (climate, reward) pair."""
    path = CLIMATES[climate]
    weather_path = None if path is None else bundled_weather_path(path)
    env = make_greenhouse(weather_path=weather_path, reward=reward)
    key = jax.random.PRNGKey(0)
    rows = [row(env, "default", env.space.default_action())]
    for hold in (1, HOLD):
        schedules = random_schedules(env, jax.random.PRNGKey(1), N_RANDOM, hold)
        rows.append(random_row(env, f"random ({_decisions(hold)})", schedules))
    for hold in (1, HOLD):
        r = row(env, f"expert ({_decisions(hold)})", expert_schedule_for_season(env, hold))
        if hold > 1:  # the same policy through ActionRepeat, as the learner's report runs it
            wrapped = action_repeat_return(env, hold)
            assert abs(wrapped - r["return"]) <= 1e-3 * max(1.0, abs(wrapped)), (wrapped, r)
        rows.append(r)
    const = refs.best_constant_schedule(env, key, **(QUICK_CONSTANT if quick else {}))
    log(
        f"  best constant {const.season_return:.2f} "
        f"({const.seasons_evaluated} seasons, {const.seconds:.1f} s)"
    )
    cost = {"seconds": round(const.seconds, 1), "seasons": const.seasons_evaluated}
    rows.append(row(env, "best constant", const.action, cost))
    loops = {}
    for hold in (1, HOLD):
        kwargs = QUICK_OPEN_LOOP if quick else {}
        loop = refs.best_open_loop_schedule(env, key, constant=const, hold_days=hold, **kwargs)
        loops[hold] = loop
        log(
            f"  open-loop ({_decisions(hold)}) {loop.season_return:.2f}: relaxed "
            f"{loop.relaxed_return:.2f}, rounded {loop.rounded_return:.2f}, kept {loop.source} "
            f"({loop.steps} Adam steps, {loop.seconds:.1f} s)"
        )
        cost = {
            "seconds": round(loop.seconds, 1),
            "adam_steps": loop.steps,
            "relaxed_return": round(loop.relaxed_return, 3),
            "rounded_return": round(loop.rounded_return, 3),
            "source": loop.source,
            "grad_finite": loop.grad_finite,
        }
        rows.append(row(env, f"open-loop ({_decisions(hold)})", loop.schedule, cost))
    return {
        "climate": climate,
        "weather": LABELS[climate],
        "reward": reward,
        "rows": rows,
        "best_constant_physical": np.round(const.physical, 2).tolist(),
        "open_loop_daily_summary": _schedule_summary(loops[1].physical),
    }


def _schedule_summary(physical: np.ndarray) -> dict:
    """Compact description of a per-day physical schedule ``[D, 4, 24]``, per 30 days."""
    blocks = [physical[i : i + 30] for i in range(0, len(physical), 30)]
    return {
        "temperature_mean": [round(float(b[:, 0, :24].mean()), 2) for b in blocks],
        "co2_mean": [round(float(b[:, 1, :24].mean()), 1) for b in blocks],
        "lamp_start_end_median": [[int(h) for h in np.median(b[:, 2, :2], axis=0)] for b in blocks],
    }


def _git(*args: str) -> str:
    try:
        done = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return ""
    return done.stdout.strip()


def _cost(r: dict) -> str:
    if "cost" not in r:
        return ""
    c = r["cost"]
    what = f"{c['seasons']} seasons" if "seasons" in c else f"{c['adam_steps']} Adam steps"
    return f"{c['seconds']:.0f} s, {what}"


def to_markdown(results: list[dict], meta: dict) -> str:
    dirty = " (dirty)" if meta["dirty"] else ""
    lines = [
        "# Greenhouse references",
        "",
        f"{meta['processor'] or meta['platform']} ({meta['cpu_count']} visible cores), "
        f"jax {meta['jax']}, commit {meta['commit'][:10]}{dirty}, {meta['total_seconds']:.0f} s "
        "in all. Whole 160-day seasons through `env.step`; return = the env's reward summed "
        "over the season (cumulative: kg/m²·day; profit: EUR/m²). Random: mean ± std of "
        f"{N_RANDOM} seasons. Cost: wall seconds, compilation included.",
    ]
    head = (
        "| policy | return | yield kg/m² | first harvest (day) | heat MJ/m² | CO2 kg/m² "
        "| lamps kWh/m² | profit EUR/m² | cost |"
    )
    for res in results:
        lines += ["", f"## {res['weather']}, reward `{res['reward']}`", "", head]
        lines.append("|---|---:|---:|---:|---:|---:|---:|---:|---|")
        for r in res["rows"]:
            ret = f"{r['return']:.2f}" + (f" ± {r['return_std']:.2f}" if "return_std" in r else "")
            lines.append(
                f"| {r['policy']} | {ret} | {r['yield_kg_m2']:.2f} | {r['first_harvest_day']:.0f} "
                f"| {r['heating_mj_m2']:.0f} | {r['co2_kg_m2']:.1f} "
                f"| {r['electricity_kwh_m2']:.0f} | {r['profit_eur_m2']:.2f} | {_cost(r)} |"
            )
    lines.append("")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--climates", nargs="+", default=list(CLIMATES), choices=list(CLIMATES))
    rewards = ["cumulative", "profit"]
    ap.add_argument("--rewards", nargs="+", default=rewards, choices=rewards)
    ap.add_argument(
        "--out",
        default=None,
        help="folder for greenhouse_references.{json,md}: default runs/benchmarks (none with "
        "--quick; the committed results: benchmarks/results); '' = do not write",
    )
    ap.add_argument("--quick", action="store_true", help="tiny budgets: tests the script only")
    args = ap.parse_args(argv)
    out = args.out if args.out is not None else ("" if args.quick else OUT)
    meta = {
        "device": str(jax.devices()[0]),
        "platform": platform.platform(),
        "processor": platform.processor(),
        "cpu_count": os.cpu_count(),
        "jax": jax.__version__,
        "commit": _git("rev-parse", "HEAD"),
        "dirty": bool(_git("status", "--porcelain", "--untracked-files=no")),
        "date": time.strftime("%Y-%m-%d %H:%M:%S %z"),
    }
    t0 = time.perf_counter()
    results = []
    for climate in args.climates:
        for reward in args.rewards:
            print(f"{LABELS[climate]}, reward {reward}", flush=True)
            results.append(evaluate_climate(climate, reward, args.quick))
    meta["total_seconds"] = round(time.perf_counter() - t0, 1)
    md = to_markdown(results, meta)
    if out:
        os.makedirs(out, exist_ok=True)
        with open(os.path.join(out, "greenhouse_references.json"), "w") as f:
            json.dump({"meta": meta, "results": results}, f, indent=2)
        with open(os.path.join(out, "greenhouse_references.md"), "w") as f:
            f.write(md)
    print(md)
    return results


if __name__ == "__main__":
    main()
