"""The robustness sweep in one jit call against a Python loop over the same settings.

Both evaluate the same SCORE policy over every (failed count 0..n-1) x (mode) x seed setting
with full episodes; the loop calls a jitted single-setting evaluator once per setting (it
compiles once, then runs S calls). Target: the one-call sweep >= 5x faster.

    python benchmarks/robustness_sweep.py --env greenhouse --seeds 10 [--run-dir RUN]
"""

from __future__ import annotations

import argparse
import json
import os
import time

import jax
import numpy as np

from score_jax import train_loop
from score_jax.config import TrainConfig
from score_jax.evaluation import evaluate
from score_jax.robustness import make_sweep, settings_grid
from score_jax.score import ScoreConfig

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


def timed(f, *args):
    t = time.time()
    out = jax.block_until_ready(f(*args))
    return out, time.time() - t


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env", default="greenhouse")
    p.add_argument("--seeds", type=int, default=10)
    p.add_argument("--run-dir", default="", help="a trained run (default: an untrained SCORE policy; speed does not depend on training)")
    args = p.parse_args()
    if args.run_dir:
        run = train_loop.restore_run(args.run_dir, log=lambda *a: None)
    else:
        cfg = TrainConfig(env=args.env, score=ScoreConfig(asrl_steps=10))
        run = train_loop.build(cfg, jax.random.PRNGKey(0), "/tmp/unused", log=lambda *a: None)
        run.state = run.trainer.init(jax.random.PRNGKey(1))
    act = run.algo.policy(run.state.agent)
    n = len(run.agent_index)
    settings = settings_grid(n, args.seeds)
    S = int(settings.n_failed.shape[0])
    key = jax.random.PRNGKey(0)

    sweep = jax.jit(make_sweep(run.env, act, run.agent_index))
    lowered = time.time()
    compiled = sweep.lower(settings, key).compile()
    sweep_compile = time.time() - lowered
    ref, sweep_run = timed(compiled, settings, key)
    _, sweep_run2 = timed(compiled, settings, key)

    single = jax.jit(lambda n_failed, mode, seed: evaluate(run.env, act, jax.random.fold_in(key, seed), 1, run.agent_index, n_failed, mode).returns)
    t = time.time()
    single_compiled = single.lower(settings.n_failed[0], settings.mode[0], settings.seed[0]).compile()
    loop_compile = time.time() - t
    t = time.time()
    loop_out = [single_compiled(settings.n_failed[i], settings.mode[i], settings.seed[i]) for i in range(S)]
    jax.block_until_ready(loop_out)
    loop_run = time.time() - t
    np.testing.assert_allclose(np.concatenate([np.asarray(x) for x in loop_out]), np.asarray(ref).ravel(), rtol=1e-4, atol=1e-3)

    sweep_best = min(sweep_run, sweep_run2)
    result = {
        "env": args.env, "settings": S, "episode_length": run.env.episode_length, "sweep_compile_s": sweep_compile, "sweep_run_s": sweep_best,
        "loop_compile_s": loop_compile, "loop_run_s": loop_run, "speedup_run": loop_run / sweep_best,
        "speedup_incl_compile": (loop_compile + loop_run) / (sweep_compile + sweep_best), "devices": [str(d) for d in jax.devices()],
    }
    os.makedirs(RESULTS, exist_ok=True)
    with open(os.path.join(RESULTS, f"robustness_sweep_{args.env}.json"), "w") as f:
        json.dump(result, f, indent=2)
    table = "\n".join([
        "| env | settings (episodes) | one-call sweep: compile / run (s) | Python loop: compile / run (s) | speed-up (run) | speed-up (incl. compile) |",
        "|---|---|---|---|---|---|",
        f"| {args.env} | {S} | {sweep_compile:.1f} / {sweep_best:.2f} | {loop_compile:.1f} / {loop_run:.2f} | {result['speedup_run']:.1f}x | {result['speedup_incl_compile']:.1f}x |",
    ])
    with open(os.path.join(RESULTS, f"robustness_sweep_{args.env}.md"), "w") as f:
        f.write(table + "\n")
    print(table)


if __name__ == "__main__":
    main()
