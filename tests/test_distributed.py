"""``score-train --distributed`` with two processes on this machine (a localhost coordinator,
gloo CPU collectives, one XLA device and one seed per process) against a one-process run of
the same two seeds on two XLA devices (``--cpu-devices 2``).

Both runs compile the same program per device (one whole seed on each of two devices; the
seeds' runs never communicate), so the final parameters agree bit for bit; the test asserts
exact equality. Process 1 runs under an audit hook that records every file it opens for
writing, creates, moves or removes in the run directory: there must be none (process 0 writes
everything, and the run directory holds the same files as the one-process run's).
"""

import csv
import json
import os
import socket
import subprocess
import sys

import jax
import numpy as np
import orbax.checkpoint as ocp
import pytest

from tests.tiny import tiny_cli_args

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
STEPS = 400  # two epochs of 200 decisions: the second one updates
EXTRA = [
    *("--num-seeds", "2", "--checkpoint-every", "200", "--eval-every", "200"),
    *("--eval-episodes", "2", "--robustness-seeds", "0"),
]


def _gloo_available() -> bool:
    from jax._src.lib import xla_client

    return hasattr(xla_client._xla, "make_gloo_tcp_collectives")


pytestmark = [
    pytest.mark.slow,  # scheduled first (conftest)
    pytest.mark.skipif(not _gloo_available(), reason="jaxlib has no gloo collectives"),
]

# Process 1's wrapper: record every write-like file operation under the run directory (Python's
# audit events; orbax's own array writes happen only inside a save, which process 1 never
# starts), then run score-train.
WATCHED = r"""
import os, runpy, sys
run_dir, log_path = os.path.realpath(sys.argv[1]), sys.argv[2]
log = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
WRITE = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_APPEND | os.O_TRUNC
EVENTS = {"os.mkdir", "os.rename", "os.remove", "os.rmdir", "os.truncate", "os.chmod",
          "os.utime", "os.symlink", "os.link", "shutil.rmtree", "shutil.copyfile",
          "shutil.move"}

def inside(path):
    if not isinstance(path, (str, bytes, os.PathLike)):
        return False
    path = os.path.realpath(os.fsdecode(path))
    return path == run_dir or path.startswith(run_dir + os.sep)

def hook(event, args):
    if event == "open":
        flags = args[2] if len(args) > 2 and isinstance(args[2], int) else 0
        mode = args[1] if isinstance(args[1], str) else ""
        wrote = flags & WRITE or any(c in mode for c in "wax+")
        paths = args[:1] if wrote else ()
    else:
        paths = args if event in EVENTS else ()
    for path in paths:
        if inside(path):
            os.write(log, f"{event} {os.fsdecode(path)}\n".encode())

sys.addaudithook(hook)
sys.argv = ["score-train", *sys.argv[3:]]
runpy.run_path(os.path.join(os.getcwd(), "train.py"), run_name="__main__")
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _env() -> dict:
    env = {**os.environ, "PYTHONPATH": ROOT, "JAX_PLATFORMS": "cpu"}
    for name in ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID"):
        env.pop(name, None)
    return env


def _start(command, log_dir, name):
    return subprocess.Popen(
        command,
        cwd=ROOT,
        env=_env(),
        stdout=open(os.path.join(log_dir, f"{name}.out"), "w"),
        stderr=open(os.path.join(log_dir, f"{name}.err"), "w"),
        stdin=subprocess.DEVNULL,
    )


def _wait(proc, log_dir, name, timeout=600):
    try:
        rc = proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        rc = proc.wait()
    err = open(os.path.join(log_dir, f"{name}.err")).read()
    assert rc == 0, f"{name} exited {rc}:\n{err[-3000:]}"
    return open(os.path.join(log_dir, f"{name}.out")).read()


def _load(path):
    """A checkpoint's arrays as numpy, without a template (nothing to build)."""
    ck = ocp.PyTreeCheckpointer()
    tree = ck.metadata(path)
    tree = getattr(getattr(tree, "item_metadata", tree), "tree", tree)
    numpy = jax.tree.map(lambda _: ocp.RestoreArgs(restore_type=np.ndarray), tree)
    return ck.restore(path, restore_args=numpy)


def _metrics(path) -> list[dict]:
    """The rows of a metrics.csv without their wall-clock times."""
    with open(path) as f:
        return [{k: v for k, v in row.items() if k != "wall_s"} for row in csv.DictReader(f)]


def _files(run_dir) -> set[str]:
    """Files and directories down to a checkpoint's items (``checkpoints/400/state``; orbax's
    array files inside them have content-hashed names)."""
    out = set()
    for d, dirs, names in os.walk(run_dir):
        for name in dirs + names:
            path = os.path.relpath(os.path.join(d, name), run_dir)
            if path.count(os.sep) < 3:
                out.add(path)
    return out


def test_two_processes_equal_one_process(tmp_path):
    one_dir, two_dir = tmp_path / "one", tmp_path / "two"
    port = _free_port()
    launch = ["--distributed", "--coordinator-address", f"127.0.0.1:{port}", "--num-processes"]
    two = [*tiny_cli_args(two_dir, STEPS), *EXTRA, *launch, "2"]
    writes = tmp_path / "process1-writes.txt"
    procs = {
        "one": _start(
            [sys.executable, "train.py", *tiny_cli_args(one_dir, STEPS), *EXTRA]
            + ["--cpu-devices", "2"],
            tmp_path,
            "one",
        ),
        "p0": _start([sys.executable, "train.py", *two, "--process-id", "0"], tmp_path, "p0"),
        "p1": _start(
            [sys.executable, "-c", WATCHED, str(two_dir), str(writes), *two, "--process-id", "1"],
            tmp_path,
            "p1",
        ),
    }
    out = {name: _wait(proc, tmp_path, name) for name, proc in procs.items()}

    assert "2 x cpu over 2 processes, seeds sharded" in out["p0"]
    said = [line for line in out["p1"].splitlines() if not line.startswith("[Gloo]")]
    assert said == []  # process 0 speaks for the run (gloo's own connection line aside)
    assert writes.read_text() == ""  # ... and writes every file
    assert _files(two_dir) == _files(one_dir)
    assert {"config.json", "metrics.csv", "evaluation.json", "learning_curve.png"} <= _files(
        two_dir
    )

    for what in (f"checkpoints/{STEPS}/state", "best"):
        if what == "best":  # the newest step of the best policies
            step = max(int(s) for s in os.listdir(one_dir / "best") if s.isdigit())
            what = f"best/{step}/state"
        mine, ref = _load(str(two_dir / what)), _load(str(one_dir / what))
        assert jax.tree.structure(mine) == jax.tree.structure(ref)
        for a, b in zip(jax.tree.leaves(mine), jax.tree.leaves(ref), strict=True):
            np.testing.assert_array_equal(a, b)  # same per-device program: bit-exact
    assert int(np.asarray(_load(str(two_dir / f"checkpoints/{STEPS}/state"))["updates"]).min()) > 0

    rows = [_metrics(d / "metrics.csv") for d in (two_dir, one_dir)]
    assert rows[0] == rows[1] and len(rows[0]) == 4  # 2 seeds x 2 epochs, every metric equal

    evaluations = [json.loads((d / "evaluation.json").read_text()) for d in (two_dir, one_dir)]
    assert evaluations[0]["seeds"] == [0, 1]
    assert evaluations[0]["returns"]["score"] == evaluations[1]["returns"]["score"]


def test_bad_launches_are_usage_errors(tmp_path):
    """No coordinator anywhere, and seeds that do not divide over the processes' devices: one
    ``error:`` line, exit 2, nothing written (the latter on both processes, which joined)."""
    run_dir = tmp_path / "run"
    base = [sys.executable, "train.py", *tiny_cli_args(run_dir, STEPS)]
    alone = _start([*base, "--distributed"], tmp_path, "alone")
    port = _free_port()
    launch = ["--distributed", "--coordinator-address", f"127.0.0.1:{port}", "--num-processes"]
    odd = [*base, "--num-seeds", "3", *launch, "2", "--process-id"]
    pair = [_start([*odd, str(i)], tmp_path, f"odd{i}") for i in range(2)]
    cases = {"alone": (alone, "coordinator_address should be defined")}
    cases |= {
        f"odd{i}": (p, "--num-seeds 3 must be a multiple of the 2 devices")
        for i, p in enumerate(pair)
    }
    for name, (proc, problem) in cases.items():
        assert proc.wait(timeout=300) == 2, name
        err = open(os.path.join(tmp_path, f"{name}.err")).read()
        lines = [line for line in err.splitlines() if line.startswith("error: ")]
        assert len(lines) == 1 and problem in lines[0] and "Traceback" not in err, err[-2000:]
    assert not run_dir.exists()
