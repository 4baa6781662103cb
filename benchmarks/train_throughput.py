"""Training throughput of SCORE against brax's own SAC on the same environment, same run.

Both use the same number of parallel environments, batch size and gradient updates per
vectorised environment step; brax SAC sees the environment through ``BraxFlatEnv`` (a flat
action). Reported: env steps/s and gradient updates/s after compilation (best of 3 timed
stretches for both, brax's being its evaluation intervals), SCORE's update-step compile time,
and the ratio SCORE / brax SAC (target >= 0.5).

    python benchmarks/train_throughput.py --envs greenhouse spider [--out DIR]

Writes ``train_throughput.{json,md}`` to ``--out`` (default ``runs/benchmarks``; the committed
results: ``--out benchmarks/results``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import jax

import envs
from score_jax.agents.score.config import ScoreConfig
from score_jax.run.build import build
from score_jax.run.config import OffPolicyConfig, TrainConfig

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "runs", "benchmarks")  # the committed results: --out benchmarks/results


def score_throughput(
    env_name: str, num_envs: int, batch: int, epochs: int, steps_per_epoch: int, chunks: int = 3
) -> dict:
    # action_repeat=1 and one update per vectorised step: the same env steps and update schedule
    # as brax SAC below.
    cfg = TrainConfig(
        env=env_name,
        action_repeat=1,
        off_policy=OffPolicyConfig(
            num_envs=num_envs,
            batch_size=batch,
            learning_starts=0,
            steps_per_epoch=steps_per_epoch,
            updates_per_step=1,
        ),
        score=ScoreConfig(asrl_steps=10),
    )
    run = build(cfg, jax.random.PRNGKey(0), "/tmp/unused", log=lambda *a: None).for_seed(0)
    state = run.trainer.init(jax.random.PRNGKey(1))
    hyper = run.algo.off_policy.hyper
    t = time.time()
    update = (
        jax.jit(run.algo.off_policy.update)
        .lower(
            state.agent,
            jax.tree.map(lambda x: x[:batch], state.buffer.data),
            jax.random.PRNGKey(0),
            hyper,
        )
        .compile()
    )
    update_compile = time.time() - t
    del update
    t = time.time()
    state, _ = run.trainer.epoch(state, hyper)
    jax.block_until_ready(state)
    epoch_compile = time.time() - t
    # Best of ``chunks`` timed stretches of ``epochs`` epochs, as brax SAC's figure below is the
    # best of its evaluation intervals (the shared machine's speed drifts between runs).
    rates = []
    for _ in range(chunks):
        t = time.time()
        for _ in range(epochs):
            state, _ = run.trainer.epoch(state, hyper)
        jax.block_until_ready(state)
        rates.append(epochs * steps_per_epoch / (time.time() - t))
    updates_per_s = max(rates)
    return {
        "env_steps_per_s": updates_per_s * num_envs,
        "updates_per_s": updates_per_s,
        "update_compile_s": update_compile,
        "epoch_compile_s": epoch_compile,
    }


def brax_sac_throughput(
    env_name: str, num_envs: int, batch: int, epochs: int, steps_per_epoch: int
) -> dict:
    from brax.training.agents.sac import train as sac

    from score_jax.agents.brax.flat_env import BraxFlatEnv

    env = BraxFlatEnv(envs.make(env_name))
    sps = []
    steps_per_eval = epochs * steps_per_epoch * num_envs
    t = time.time()
    sac.train(
        environment=env,
        num_timesteps=steps_per_eval * 3,
        episode_length=envs.make(env_name).episode_length,
        num_envs=num_envs,
        batch_size=batch,
        num_evals=4,
        num_eval_envs=num_envs,
        min_replay_size=batch,
        grad_updates_per_step=1,
        seed=0,
        progress_fn=lambda step, m: sps.append(m.get("training/sps")),
    )
    total = time.time() - t
    measured = [s for s in sps if s is not None][1:]  # the first epoch includes compilation
    best = max(measured) if measured else float("nan")
    return {
        "env_steps_per_s": best,
        "updates_per_s": best / num_envs,
        "total_s_incl_compile_and_eval": total,
    }


def main():
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--envs", nargs="+", default=["greenhouse", "spider"])
    p.add_argument("--num-envs", type=int, default=8)
    p.add_argument("--batch-size", type=int, default=128)
    p.add_argument("--epochs", type=int, default=5)
    p.add_argument("--steps-per-epoch", type=int, default=50)
    p.add_argument(
        "--out",
        default=OUT,
        help="folder for train_throughput.{json,md} (default runs/benchmarks; the committed "
        "results: benchmarks/results)",
    )
    args = p.parse_args()
    results = []
    for name in args.envs:
        s = score_throughput(
            name, args.num_envs, args.batch_size, args.epochs, args.steps_per_epoch
        )
        b = brax_sac_throughput(
            name, args.num_envs, args.batch_size, args.epochs, args.steps_per_epoch
        )
        row = {
            "env": name,
            "score": s,
            "brax_sac": b,
            "ratio_env_steps": s["env_steps_per_s"] / b["env_steps_per_s"],
        }
        results.append(row)
        print(
            f"{name}: SCORE {s['env_steps_per_s']:.0f} env steps/s "
            f"({s['updates_per_s']:.0f} updates/s), "
            f"brax SAC {b['env_steps_per_s']:.0f} env steps/s, ratio {row['ratio_env_steps']:.2f}; "
            f"SCORE update compile {s['update_compile_s']:.1f} s"
        )
    meta = {
        "num_envs": args.num_envs,
        "batch_size": args.batch_size,
        "updates_per_env_step": 1,
        "machine": platform.processor() or platform.machine(),
        "devices": [str(d) for d in jax.devices()],
        "cpu_count": os.cpu_count(),
    }
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "train_throughput.json"), "w") as f:
        json.dump({"meta": meta, "results": results}, f, indent=2)
    lines = [
        (
            "| env | SCORE env steps/s | SCORE updates/s | brax SAC env steps/s | ratio "
            "| SCORE update compile (s) |"
        ),
        "|---|---|---|---|---|---|",
    ]
    for r in results:
        lines.append(
            f"| {r['env']} | {r['score']['env_steps_per_s']:.0f} "
            f"| {r['score']['updates_per_s']:.0f} | {r['brax_sac']['env_steps_per_s']:.0f} | "
            f"{r['ratio_env_steps']:.2f} | {r['score']['update_compile_s']:.1f} |"
        )
    table = "\n".join(lines)
    with open(os.path.join(args.out, "train_throughput.md"), "w") as f:
        f.write(
            f"num_envs={args.num_envs}, batch={args.batch_size}, 1 update per vectorised env step, "
            f"{meta['devices']}\n\n{table}\n"
        )
    print(table)


if __name__ == "__main__":
    main()
