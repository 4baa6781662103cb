"""Seeds as a batch axis: SCORE's training throughput with K seeds in one compiled program.

For each environment and K in ``--seeds``: env steps per second summed over the K seeds (the
main job's settings: the environment's action repeat, 8 envs, batch 128, 2 updates per
vectorised step), the ratio to K = 1 measured in the same run, and memory per seed (the
training state's bytes, and the compiled epoch's temporary buffers). Best of 3 timed
stretches after a compiling epoch, like ``train_throughput.py``. The target on a 2-core CPU:
5 seeds at least 2x the summed throughput of 1 seed.

    python benchmarks/seed_throughput.py --envs greenhouse spider --seeds 1 2 5 10 \
        --out benchmarks/results
    python benchmarks/seed_throughput.py --split-cpu ...  # one XLA device per core (seeds
                                                          # sharded when K divides)
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def measure(env_name: str, k: int, epochs: int, chunks: int = 3) -> dict:
    import jax

    from score_jax.agents.score.config import ScoreConfig
    from score_jax.run.build import build, seed_keys
    from score_jax.run.config import TrainConfig

    cfg = TrainConfig(env=env_name, num_seeds=k, score=ScoreConfig(asrl_steps=10), quiet=True)
    # updates from the first step: every timed epoch does the full update schedule
    cfg = dataclasses.replace(
        cfg, off_policy=dataclasses.replace(cfg.off_policy, learning_starts=0)
    )
    run = build(cfg, None, "/tmp/unused-seed-throughput", log=lambda *a: None)
    state = run.trainer.init(seed_keys(run.seeds)[1], run.frozen)
    hyper = run.algo.off_policy.hyper
    t = time.time()
    compiled = run.trainer.epoch.lower(state, hyper).compile()
    compile_s = time.time() - t
    memory = compiled.memory_analysis()
    state, _ = compiled(state, hyper)
    jax.block_until_ready(state)
    per_epoch = cfg.off_policy.num_envs * cfg.off_policy.steps_per_epoch
    rates = []
    for _ in range(chunks):
        t = time.time()
        for _ in range(epochs):
            state, _ = compiled(state, hyper)
        jax.block_until_ready(state)
        rates.append(k * epochs * per_epoch / (time.time() - t))
    state_bytes = sum(x.nbytes for x in jax.tree.leaves(state))
    return {
        "env": env_name,
        "seeds": k,
        "decisions_per_s": max(rates),
        "env_steps_per_s": max(rates) * run.spec.action_repeat,
        "action_repeat": run.spec.action_repeat,
        "epoch_compile_s": compile_s,
        "state_mb_per_seed": state_bytes / k / 2**20,
        "temp_mb_per_seed": (memory.temp_size_in_bytes / k / 2**20) if memory is not None else None,
        "shards": run.trainer.shards,
        "devices": jax.device_count(),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--envs", nargs="+", default=["greenhouse", "spider"])
    p.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 5, 10])
    p.add_argument("--epochs", type=int, default=3, help="epochs per timed stretch")
    p.add_argument("--split-cpu", action="store_true", help="one XLA host device per core")
    p.add_argument(
        "--out", default=os.path.join(ROOT, "runs", "benchmarks"), help="where JSON/markdown go"
    )
    p.add_argument(
        "--one", help=argparse.SUPPRESS
    )  # internal: measure one (env, K) in this process
    args = p.parse_args(argv)
    if args.one:  # a fresh process per measurement, so one K's memory never inflates another's
        env_name, k = args.one.split(":")
        print("RESULT " + json.dumps(measure(env_name, int(k), args.epochs)), flush=True)
        return 0
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    if args.split_cpu:
        flag = f"--xla_force_host_platform_device_count={os.cpu_count()}"
        env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} {flag}".strip()
    results = []
    for env_name in args.envs:
        for k in args.seeds:
            out = subprocess.run(
                [
                    sys.executable,
                    __file__,
                    "--one",
                    f"{env_name}:{k}",
                    "--epochs",
                    str(args.epochs),
                ],
                env=env,
                capture_output=True,
                text=True,
                check=False,
            )
            line = [x for x in out.stdout.splitlines() if x.startswith("RESULT ")]
            if not line:
                print(out.stderr[-3000:], file=sys.stderr)
                return 1
            r = json.loads(line[0][len("RESULT ") :])
            results.append(r)
            print(
                f"{env_name:10s} K={k:<3d} {r['env_steps_per_s']:10.0f} env steps/s summed  "
                f"{r['state_mb_per_seed']:.0f} MB state/seed  "
                f"compile {r['epoch_compile_s']:.0f} s  ({r['shards']})",
                flush=True,
            )
    for r in results:
        base = next(x for x in results if x["env"] == r["env"] and x["seeds"] == min(args.seeds))
        r["ratio_to_fewest_seeds"] = r["env_steps_per_s"] / base["env_steps_per_s"]
    meta = {
        "machine": platform.platform(),
        "cpus": os.cpu_count(),
        "split_cpu": args.split_cpu,
        "commit": subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True
        ).stdout.strip(),
    }
    os.makedirs(args.out, exist_ok=True)
    name = "seed_throughput" + ("_split" if args.split_cpu else "")
    json.dump(
        {"meta": meta, "results": results},
        open(os.path.join(args.out, name + ".json"), "w"),
        indent=2,
    )
    lines = [
        f"| env | seeds | env steps/s (summed) | x K={min(args.seeds)} | MB state / seed "
        "| MB temp / seed | epoch compile s | sharded |",
        "|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in results:
        temp = "" if r["temp_mb_per_seed"] is None else f"{r['temp_mb_per_seed']:.0f}"
        lines.append(
            f"| {r['env']} | {r['seeds']} | {r['env_steps_per_s']:.0f} "
            f"| {r['ratio_to_fewest_seeds']:.2f} | {r['state_mb_per_seed']:.0f} | {temp} "
            f"| {r['epoch_compile_s']:.0f} | {r['shards']} |"
        )
    text = (
        "\n".join(lines)
        + f"\n\nMachine: {meta['machine']}, {meta['cpus']} CPUs, commit {meta['commit'][:10]}.\n"
    )
    open(os.path.join(args.out, name + ".md"), "w").write(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
