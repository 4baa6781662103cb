"""Start-up of ``score-train`` on the greenhouse with an empty and with a warm persistent
compilation cache.

Runs the same short ``score-train`` (greenhouse defaults, one training epoch, no periodic
evaluation or robustness sweep) ``1 + --warm-runs`` times in fresh processes that share one
new, empty cache directory (``SCORE_JAX_CACHE``): the first start compiles everything and fills
the cache, the later ones load it. Measured per start, from launching the process:
- ``first_row_s``: until ``metrics.csv`` has its first row (imports, environment, ASRL stage,
  compilation and the first epoch: what a user waits for before training shows progress);
- ``total_s``: until the process exits (adds the end-of-run evaluation table).

    python benchmarks/startup.py                       # writes runs/benchmarks/startup.{json,md}
    python benchmarks/startup.py --out benchmarks/results   # the committed results

Nothing of the caller's JAX set-up is inherited: ``JAX_COMPILATION_CACHE_DIR`` and ``XLA_FLAGS``
are removed from the children's environment, so they use score-train's own default cache
(under ``SCORE_JAX_CACHE``) and XLA's default optimisation level.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "runs", "benchmarks")  # the committed results: --out benchmarks/results
TRAIN_ARGS = (
    "--env",
    "greenhouse",
    "--total-steps",
    "160",
    "--eval-every",
    "0",
    "--eval-episodes",
    "1",
    "--robustness-seeds",
    "0",
    "--quiet",
)


def command(run_dir: str) -> list[str]:
    """``score-train`` through the interpreter running this script (no install needed)."""
    return [sys.executable, "-m", "score_jax.cli.train", *TRAIN_ARGS, "--run-dir", run_dir]


def _rows(path: str) -> int:
    if not os.path.exists(path):
        return 0
    with open(path) as f:
        return max(0, sum(1 for line in f if line.strip()) - 1)


def one_start(run_dir: str, env: dict, log_path: str) -> dict:
    """Launch one ``score-train``; the seconds until its first metrics row and until it exits."""
    csv = os.path.join(run_dir, "metrics.csv")
    t0 = time.perf_counter()
    with open(log_path, "w") as log:
        proc = subprocess.Popen(command(run_dir), cwd=ROOT, env=env, stdout=log, stderr=log)
        first = None
        while proc.poll() is None:
            if first is None and _rows(csv) >= 1:
                first = time.perf_counter() - t0
            time.sleep(0.05)
    total = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"score-train exited with {proc.returncode}; see {log_path}")
    if first is None and _rows(csv) >= 1:
        first = total
    return {"first_row_s": round(first, 2), "total_s": round(total, 2)}


def cache_size(path: str) -> tuple[int, int]:
    files = [os.path.join(d, f) for d, _, fs in os.walk(path) for f in fs]
    return len(files), sum(os.path.getsize(f) for f in files)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--warm-runs", type=int, default=1, help="starts after the cold one")
    ap.add_argument(
        "--out",
        default=OUT,
        help="folder for startup.{json,md} (default runs/benchmarks; the committed results: "
        "benchmarks/results); '' = do not write",
    )
    args = ap.parse_args(argv)
    work = tempfile.mkdtemp(prefix="score-jax-startup-")
    env = {
        k: v for k, v in os.environ.items() if k not in ("JAX_COMPILATION_CACHE_DIR", "XLA_FLAGS")
    }
    env.update(SCORE_JAX_CACHE=os.path.join(work, "cache"), PYTHONPATH=ROOT, JAX_PLATFORMS="cpu")
    starts = []
    for i in range(1 + args.warm_runs):
        kind = "cold" if i == 0 else "warm"
        r = one_start(os.path.join(work, f"run{i}"), env, os.path.join(work, f"run{i}.log"))
        r["cache"] = kind
        starts.append(r)
        print(
            f"{kind} start: first metrics row {r['first_row_s']:.1f} s, exit {r['total_s']:.1f} s"
        )
    cold, warm = starts[0], starts[1:]
    best = min(warm, key=lambda r: r["first_row_s"]) if warm else None
    n_files, n_bytes = cache_size(os.path.join(work, "cache"))
    meta = {
        "command": "score-train " + " ".join(TRAIN_ARGS) + " --run-dir DIR",
        "platform": platform.platform(),
        "processor": platform.processor(),
        "cpu_count": os.cpu_count(),
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "date": time.strftime("%Y-%m-%d %H:%M:%S %z"),
        "cache_files": n_files,
        "cache_mb": round(n_bytes / 1e6, 1),
    }
    result = {"meta": meta, "starts": starts}
    lines = [
        f"`{meta['command']}`, a fresh cache directory, {os.cpu_count()} CPU cores "
        f"(load average {meta['load_average'][0]}):",
        "",
        "| start | first metrics row (s) | process exit (s) |",
        "|---|---:|---:|",
    ]
    lines += [f"| {r['cache']} | {r['first_row_s']:.1f} | {r['total_s']:.1f} |" for r in starts]
    if best is not None:
        result["ratio_first_row"] = round(cold["first_row_s"] / best["first_row_s"], 2)
        result["ratio_total"] = round(cold["total_s"] / best["total_s"], 2)
        lines += [
            "",
            f"Warm / cold: first row {best['first_row_s'] / cold['first_row_s']:.2f} "
            f"({result['ratio_first_row']:.1f}x faster), exit "
            f"{best['total_s'] / cold['total_s']:.2f}; cache {n_files} files, "
            f"{meta['cache_mb']} MB.",
        ]
    md = "\n".join(lines) + "\n"
    print(md)
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        with open(os.path.join(args.out, "startup.json"), "w") as f:
            json.dump(result, f, indent=2)
        with open(os.path.join(args.out, "startup.md"), "w") as f:
            f.write(md)
    return result


if __name__ == "__main__":
    main()
