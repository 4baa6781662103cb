"""Spider physics throughput: MJX (jit of scan of vmap of env.step) vs plain MuJoCo, same model.

Physics steps/s = env steps x frame_skip x batch / seconds. MJX runs ``envs.spider.rollout.
make_rollout`` (the same compiled rollout the tests use) on random actions; plain MuJoCo runs
``mujoco.mj_step`` in one Python thread on ``env.mj_model`` (one env, random controls held for
``frame_skip`` steps, as the env does). Both are measured in the same process, interleaved and
best-of-``--repeats``, so machine load hits both alike. Also measured at the largest batch:
the env with ``lean_step=False`` (plain ``mjx.step``), to show what ``envs.spider.physics``
buys; its states must equal the lean ones.

XLA's CPU backend runs one fused program on one core, whereas a batch of independent envs
wants every core. The script therefore splits the CPU into one XLA host device per core
(``--xla_force_host_platform_device_count``, set before jax starts) and measures each batch
twice: on one device, and sharded over all of them on a ``data`` mesh axis (the same
``jax.sharding`` layout the trainer uses). Plain MuJoCo stays one C thread, as the issue asks.

    python benchmarks/spider_throughput.py  # writes runs/benchmarks/spider_throughput.{json,md}
    python benchmarks/spider_throughput.py --out benchmarks/results   # the committed results
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import time
from pathlib import Path

import cpu_devices  # noqa: F401  (before jax: one XLA host device per core)
import jax
import mujoco
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from envs.spider.env import make_spider
from envs.spider.rollout import make_rollout, reset_batch


def time_mjx(env, batch: int, steps: int, repeats: int, mesh: Mesh | None = None) -> dict:
    """Compile time and best physics steps/s of ``steps`` env steps on ``batch`` envs; with
    ``mesh``, the env axis is sharded over its ``data`` axis (one CPU device per core)."""
    rollout = make_rollout(env)
    states = reset_batch(env, jax.random.PRNGKey(0), batch)
    actions = env.space.sample(jax.random.PRNGKey(1), (steps, batch))
    if mesh is not None:
        states = jax.device_put(states, NamedSharding(mesh, PartitionSpec("data")))
        actions = jax.device_put(actions, NamedSharding(mesh, PartitionSpec(None, "data")))
    t0 = time.perf_counter()
    compiled = rollout.lower(states, actions).compile()
    compile_s = time.perf_counter() - t0
    final, _ = compiled(states, actions)  # warm-up run
    jax.block_until_ready(final)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        out, traj = compiled(states, actions)
        jax.block_until_ready((out, traj))
        best = min(best, time.perf_counter() - t0)
    return {
        "compile_s": compile_s,
        "seconds": best,
        "physics_steps_per_s": steps * env.config.frame_skip * batch / best,
        "final_qpos": np.asarray(out.sim.data.qpos),
    }


def time_mujoco(
    model: mujoco.MjModel, frame_skip: int, steps: int, repeats: int, seed: int = 0
) -> float:
    """Best physics steps/s of plain ``mj_step`` (one env, one thread) with random controls."""
    rng = np.random.default_rng(seed)
    ctrls = rng.uniform(-1.0, 1.0, (steps, model.nu))
    data = mujoco.MjData(model)
    best = np.inf
    for _ in range(repeats):
        mujoco.mj_resetData(model, data)
        t0 = time.perf_counter()
        for k in range(steps):
            data.ctrl[:] = ctrls[k]
            for _ in range(frame_skip):
                mujoco.mj_step(model, data)
            if not 0.2 <= data.qpos[2] <= 1.0:  # reset like an RL loop would (cost included)
                mujoco.mj_resetData(model, data)
        best = min(best, time.perf_counter() - t0)
    return steps * frame_skip / best


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 256, 512, 1024])
    parser.add_argument("--steps", type=int, default=100, help="env steps per timed MJX call")
    parser.add_argument(
        "--mujoco-steps", type=int, default=2000, help="env steps per timed MuJoCo run"
    )
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--out",
        "--out-dir",
        dest="out_dir",
        default=str(Path(__file__).resolve().parent.parent / "runs" / "benchmarks"),
        help="folder for spider_throughput.{json,md} (default runs/benchmarks; the committed "
        "results: benchmarks/results)",
    )
    args = parser.parse_args(argv)

    env = make_spider()
    fs = env.config.frame_skip
    n_dev = jax.device_count()
    mesh = Mesh(np.array(jax.devices()), ("data",)) if n_dev > 1 else None
    rows = []
    mujoco_rates = []
    for batch in args.batches:
        steps = args.steps if batch > 1 else 4 * args.steps
        for devices in [1, n_dev] if n_dev > 1 and batch % n_dev == 0 else [1]:
            mujoco_rates.append(time_mujoco(env.mj_model, fs, args.mujoco_steps, args.repeats))
            r = time_mjx(env, batch, steps, args.repeats, mesh if devices > 1 else None)
            mujoco_rates.append(time_mujoco(env.mj_model, fs, args.mujoco_steps, args.repeats))
            rows.append(
                {
                    "variant": "lean_step",
                    "devices": devices,
                    "batch": batch,
                    "env_steps": steps,
                    "compile_s": r["compile_s"],
                    "physics_steps_per_s": r["physics_steps_per_s"],
                    "_qpos": r["final_qpos"],
                }
            )
            print(
                f"MJX batch {batch:5d} on {devices} device(s): "
                f"{r['physics_steps_per_s']:>10,.0f} physics steps/s  "
                f"(compile {r['compile_s']:.1f} s)",
                flush=True,
            )

    # A/B: plain mjx.step at the largest batch.
    big = max(args.batches)
    plain = make_spider(lean_step=False)
    r = time_mjx(plain, big, args.steps, args.repeats)
    lean_row = next(x for x in rows if x["batch"] == big and x["devices"] == 1)
    same = bool(np.allclose(r["final_qpos"], lean_row["_qpos"], atol=1e-4, equal_nan=True))
    sharded_row = next((x for x in rows if x["batch"] == big and x["devices"] > 1), None)
    sharded_same = (
        None
        if sharded_row is None
        else bool(np.allclose(sharded_row["_qpos"], lean_row["_qpos"], atol=1e-4, equal_nan=True))
    )
    rows.append(
        {
            "variant": "mjx.step",
            "devices": 1,
            "batch": big,
            "env_steps": args.steps,
            "compile_s": r["compile_s"],
            "physics_steps_per_s": r["physics_steps_per_s"],
            "_qpos": None,
        }
    )
    print(
        f"MJX batch {big:5d} with plain mjx.step: {r['physics_steps_per_s']:,.0f} physics steps/s "
        f"(states equal to lean_step: {same})"
    )
    mujoco_rates.append(time_mujoco(env.mj_model, fs, args.mujoco_steps, args.repeats))

    mujoco_rate = float(np.median(mujoco_rates))
    for row in rows:
        row.pop("_qpos")
        row["ratio_vs_mujoco"] = row["physics_steps_per_s"] / mujoco_rate
    best = max(
        (x for x in rows if x["variant"] == "lean_step"), key=lambda x: x["physics_steps_per_s"]
    )
    result = {
        "benchmark": "spider_throughput",
        "model": {
            "legs": [leg.name for leg in env.legs],
            "nq": env.mj_model.nq,
            "nv": env.mj_model.nv,
            "nu": env.mj_model.nu,
            "contacts": "9 sphere-plane (8 feet + torso)",
            "physics": dataclasses.asdict(env.config.physics),
            "frame_skip": fs,
        },
        "mujoco_physics_steps_per_s": mujoco_rate,
        "mujoco_runs": mujoco_rates,
        "mjx": rows,
        "best": {
            "batch": best["batch"],
            "devices": best["devices"],
            "ratio_vs_mujoco": best["ratio_vs_mujoco"],
        },
        "lean_equals_mjx_step": same,
        "sharded_equals_single_device": sharded_same,
        "machine": {
            "platform": platform.platform(),
            "processor": platform.processor(),
            "cpu_count": os.cpu_count(),
            "jax_devices": [str(d) for d in jax.devices()],
            "load_average": os.getloadavg(),
        },
        "versions": {"jax": jax.__version__, "mujoco": mujoco.__version__},
    }
    out_dir = Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "spider_throughput.json").write_text(json.dumps(result, indent=2, default=str))
    table = markdown_table(result)
    (out_dir / "spider_throughput.md").write_text(table)
    print(table)
    return result


def markdown_table(result: dict) -> str:
    m = result["machine"]
    lines = [
        "# Spider throughput: MJX vs plain MuJoCo",
        "",
        (
            f"Machine: {m['cpu_count']} CPU cores, {m['jax_devices']}, "
            f"load average {tuple(round(x, 2) for x in m['load_average'])}; "
            f"jax {result['versions']['jax']}, mujoco {result['versions']['mujoco']}."
        ),
        (
            "Plain MuJoCo (`mj_step`, one env, one Python thread): "
            f"**{result['mujoco_physics_steps_per_s']:,.0f}** physics steps/s "
            f"(median of {len(result['mujoco_runs'])} interleaved runs)."
        ),
        "",
        "| variant | devices | batch | physics steps/s | MJX / MuJoCo | compile (s) |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for r in result["mjx"]:
        lines.append(
            f"| {r['variant']} | {r.get('devices', 1)} | {r['batch']} "
            f"| {r['physics_steps_per_s']:,.0f} | {r['ratio_vs_mujoco']:.2f} "
            f"| {r['compile_s']:.1f} |"
        )
    b = result["best"]
    lines += [
        "",
        (
            f"Best: batch {b['batch']} on {b.get('devices', 1)} device(s), "
            f"ratio {b['ratio_vs_mujoco']:.2f}. "
            f"`lean_step` states equal `mjx.step` states: {result['lean_equals_mjx_step']}; "
            "sharded states equal single-device states within 1e-4 after "
            f"{result['mjx'][0]['env_steps'] // 4} chaotic env steps: "
            f"{result.get('sharded_equals_single_device')}."
        ),
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
