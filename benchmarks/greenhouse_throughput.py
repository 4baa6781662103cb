"""Greenhouse simulation throughput: simulated days per second vs batch size.

One measurement = a full season (``episode_length`` days) of ``batch`` greenhouses as ONE
jitted function: ``lax.scan`` over days of ``vmap(env.step)`` with a fixed random action per
env and day (drawn inside the jit, so the action cost is included but tiny). Compile time is
measured separately (AOT ``lower().compile()``); every timed call ends with
``block_until_ready``.

    python benchmarks/greenhouse_throughput.py                      # 1, 64, 1024, 4096
    python benchmarks/greenhouse_throughput.py --batch-sizes 1 256 --repeats 5

Writes ``greenhouse_throughput.json`` and ``.md`` (a table) to ``--out`` (default
``runs/benchmarks``; the committed results: ``--out benchmarks/results``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import jax  # noqa: E402

from envs.greenhouse.env import make_greenhouse  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "runs", "benchmarks")  # the committed results: --out benchmarks/results


def make_season_fn(env, batch: int, days: int):
    """``key -> final EnvState [batch]``: a season of ``batch`` envs in one scan.

    The whole final state is returned (observation, reward, metrics, simulator state), so
    XLA cannot drop any part of the daily computation as dead code.
    """
    step = jax.vmap(env.step)

    def season(key):
        key_reset, key_act = jax.random.split(key)
        state = jax.vmap(env.reset)(jax.random.split(key_reset, batch))

        def day(state, k):
            return step(state, env.space.sample(k, (batch,))), None

        state, _ = jax.lax.scan(day, state, jax.random.split(key_act, days))
        return state

    return jax.jit(season)


def measure(env, batch: int, repeats: int) -> dict:
    days = env.episode_length
    fn = make_season_fn(env, batch, days)
    key = jax.random.PRNGKey(0)
    t0 = time.perf_counter()
    compiled = fn.lower(key).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(key))  # warm-up run (first-touch allocations)
    times = []
    for r in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(jax.random.PRNGKey(r + 1)))
        times.append(time.perf_counter() - t0)
    best, mean = min(times), sum(times) / len(times)
    return {
        "batch": batch,
        "days_per_season": days,
        "compile_s": round(compile_s, 3),
        "season_s_best": round(best, 4),
        "season_s_mean": round(mean, 4),
        "days_per_s_best": round(batch * days / best, 1),
        "days_per_s_mean": round(batch * days / mean, 1),
        "repeats": repeats,
    }


def to_markdown(rows: list[dict], meta: dict) -> str:
    lines = [
        "# Greenhouse throughput",
        "",
        f"{meta['device']} ({meta['cpu_count']} visible cores), jax {meta['jax']}, "
        f"substeps_per_hour={meta['substeps_per_hour']}, {meta['days']} days per season. "
        "Simulated days per second = batch x days / wall time of one jitted season "
        "(scan over days of vmap(step), random actions), best and mean of the repeats.",
        "",
        "| batch | compile (s) | season best (s) | season mean (s) | days/s best | days/s mean |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['batch']} | {r['compile_s']:.2f} | {r['season_s_best']:.3f} "
            f"| {r['season_s_mean']:.3f} "
            f"| {r['days_per_s_best']:,.0f} | {r['days_per_s_mean']:,.0f} |"
        )
    best = max(rows, key=lambda r: r["days_per_s_best"])
    lines += [
        "",
        f"Best: {best['days_per_s_best']:,.0f} simulated days/s at batch {best['batch']}.",
        "",
    ]
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--batch-sizes", type=int, nargs="+", default=[1, 64, 1024, 4096])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--substeps-per-hour", type=int, default=1)
    ap.add_argument(
        "--out",
        default=OUT,
        help="folder for greenhouse_throughput.{json,md} (default runs/benchmarks; the committed "
        "results: benchmarks/results); '' = do not write",
    )
    args = ap.parse_args(argv)

    env = make_greenhouse(substeps_per_hour=args.substeps_per_hour)
    meta = {
        "device": str(jax.devices()[0]),
        "platform": platform.platform(),
        "processor": platform.processor(),
        "cpu_count": os.cpu_count(),
        "jax": jax.__version__,
        "substeps_per_hour": args.substeps_per_hour,
        "days": env.episode_length,
    }
    rows = []
    print(
        f"{'batch':>6s} {'compile s':>10s} {'season s':>10s} "
        f"{'days/s best':>14s} {'days/s mean':>14s}",
        flush=True,
    )
    for b in args.batch_sizes:
        r = measure(env, b, args.repeats)
        rows.append(r)
        print(
            f"{b:>6d} {r['compile_s']:>10.2f} {r['season_s_best']:>10.3f} "
            f"{r['days_per_s_best']:>14,.0f} {r['days_per_s_mean']:>14,.0f}",
            flush=True,
        )
    md = to_markdown(rows, meta)
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        with open(os.path.join(args.out, "greenhouse_throughput.json"), "w") as f:
            json.dump({"meta": meta, "results": rows}, f, indent=2)
        with open(os.path.join(args.out, "greenhouse_throughput.md"), "w") as f:
            f.write(md)
    print(md)
    return rows


if __name__ == "__main__":
    main()
