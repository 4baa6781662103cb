"""A run killed with SIGKILL at random moments, 20 times and more in a row (during start-up,
training, checkpoint and best-policy saves, and the end-of-run report), each time continued with
``--resume``, ends with the parameters, best policy, ``metrics.csv`` and end-of-run evaluation of
an uninterrupted run."""

import csv
import json
import os
import random
import signal
import subprocess
import sys
import time

import jax
import numpy as np
import pytest
import tyro

from score_jax.cli import train as train_cli
from score_jax.run.build import restore_run
from score_jax.run.config import TrainConfig
from tests.tiny import tiny_cli_args

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
KILLS = 20
# Where each attempt is killed, in order. "early": a random moment of the start-up (imports,
# building, restoring); "save": while the (1st or 2nd) checkpoint or best-policy save of the
# process is being written; "row": right after a metrics row, before its checkpoint; "late": a
# random moment later on; "report": a random moment of the end-of-run report.
SCHEDULE = (
    "early save early early save early row early early save "
    "early early early early report early early report early early"
).split()


def _args(run_dir) -> list[str]:
    """ISAC on the probe (the run machinery is every in-process algorithm's; ISAC starts fastest):
    5 epochs of 200 decisions, a checkpoint after each, evaluations (and best-policy saves) every
    400, a short report."""
    args = tiny_cli_args(run_dir, total_steps=1000)
    args[args.index("--checkpoint-every") + 1] = "200"
    return args + [
        "--algo",
        "isac",
        "--marl.actor.hidden",
        "32",
        "32",
        "--marl.critic-hidden",
        "32",
        "32",
        "--eval-every",
        "400",
        "--eval-episodes",
        "2",
        "--robustness-seeds",
        "1",
    ]


def _saves(run_dir) -> set:
    """The temporary directories of orbax saves under way (or cut short) in the run."""
    out = set()
    for name in ("checkpoints", "best"):
        try:
            out |= {f"{name}/{e.name}" for e in os.scandir(os.path.join(run_dir, name))}
        except FileNotFoundError:
            pass
    return {p for p in out if "tmp" in p}


def _rows(path):
    with open(path, newline="") as f:
        return [{k: v for k, v in r.items() if k != "wall_s"} for r in csv.DictReader(f)]


def _lines(path) -> int:
    try:
        with open(path) as f:
            return sum(1 for _ in f)
    except FileNotFoundError:
        return 0


def _attempt(run_dir, mode: str, rng: random.Random, log_dir) -> tuple[str, int]:
    """Start (or resume) the run and kill it as ``mode`` says; returns ``(what happened,
    returncode)``: what happened is ``mode`` when it was killed so, else ``"finished"``."""
    resume = os.path.exists(os.path.join(run_dir, "config.json"))
    command = ["--resume", str(run_dir), "--quiet"] if resume else _args(run_dir)
    out = open(os.path.join(log_dir, "stdout.txt"), "w")
    err = open(os.path.join(log_dir, "stderr.txt"), "w")
    proc = subprocess.Popen(
        [sys.executable, "train.py", *command],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": ROOT},
        stdout=out,
        stderr=err,
        stdin=subprocess.DEVNULL,
    )
    metrics = os.path.join(run_dir, "metrics.csv")
    start, rows0, saves, skip = time.time(), None, 0, rng.randint(0, 1)
    stale = _saves(run_dir)  # left by an earlier kill, until this process cleans them up
    delay = {"early": rng.uniform(0.0, 4.0), "late": rng.uniform(4.0, 10.0)}.get(mode)
    report_at = None
    killed = False
    while proc.poll() is None and time.time() - start < 300:
        now = time.time() - start
        if delay is not None and now >= delay:
            killed = True
        elif mode == "save" and _saves(run_dir) - stale:
            saves += 1
            if saves > skip:
                killed = True
            else:
                while _saves(run_dir) - stale and proc.poll() is None:
                    time.sleep(0.001)
        elif mode == "row":
            rows = _lines(metrics)
            rows0 = rows if rows0 is None else rows0
            killed = rows > rows0 > 0
        elif mode == "report":
            if report_at is None and "run directory:" in open(out.name).read():
                report_at = time.time() + rng.uniform(0.0, 2.5)
            killed = report_at is not None and time.time() >= report_at
        if killed:
            proc.send_signal(signal.SIGKILL)
            break
        time.sleep(0.002)
    proc.wait(timeout=60)
    out.close()
    err.close()
    if proc.returncode not in (0, -signal.SIGKILL):
        raise AssertionError(
            f"attempt ({mode}) exited {proc.returncode}:\n{open(err.name).read()[-3000:]}"
        )
    if not (killed and proc.returncode == -signal.SIGKILL):
        return "finished", proc.returncode
    if mode == "save" and not _saves(run_dir) - stale:  # the save had just been committed
        return "after save", proc.returncode
    return mode, proc.returncode


def _params(state):
    return jax.device_get((state.agent.actor, state.agent.critic, state.agent.log_alpha))


@pytest.mark.slow
def test_many_sigkills_then_resume_equal_an_uninterrupted_run(tmp_path, capsys):
    reference = tmp_path / "reference"
    assert train_cli.main(tyro.cli(TrainConfig, args=_args(reference))) == 0
    capsys.readouterr()

    run_dir = tmp_path / "killed"
    rng = random.Random(18)
    kills: list[str] = []
    schedule = list(SCHEDULE)
    attempts = 0
    while (len(kills) < KILLS or "save" not in kills or "report" not in kills) and attempts < 60:
        mode = schedule.pop(0) if schedule else rng.choice(["early", "report", "late"])
        t = time.time()
        happened, _ = _attempt(run_dir, mode, rng, tmp_path)
        attempts += 1
        print(f"attempt {attempts} ({mode}): {happened} after {time.time() - t:.1f} s")
        if happened != "finished":
            kills.append(happened)
    assert len(kills) >= KILLS and kills.count("save") >= 2 and "report" in kills, kills

    happened, code = _attempt(run_dir, "finish", rng, tmp_path)  # the last one runs to its end
    assert happened == "finished" and code == 0
    assert "Traceback" not in open(tmp_path / "stderr.txt").read()

    killed, straight = restore_run(str(run_dir), log=print), restore_run(str(reference), log=print)
    assert int(killed.state.env_steps[0]) == 1000
    jax.tree.map(np.testing.assert_array_equal, _params(killed.state), _params(straight.state))
    best = lambda d: restore_run(str(d), log=print, policy="best").state
    jax.tree.map(np.testing.assert_array_equal, _params(best(run_dir)), _params(best(reference)))
    assert _rows(run_dir / "metrics.csv") == _rows(reference / "metrics.csv")
    for name in ("evaluation.json", "robustness.json"):
        a, b = (json.load(open(d / name)) for d in (run_dir, reference))
        a.pop("seconds", None), b.pop("seconds", None)
        assert a == b, name
