"""Commands that read a saved run split the CPU as its training had it (``cli.devices``), so a
transfer, evaluation or sweep from the command line compiles the programs that the benchmarks
compile for the same run, and gives the same numbers."""

import json
import os
import subprocess
import sys

import pytest

from score_jax.cli.devices import saved_run_devices, saved_run_seeds
from score_jax.run.cpu_split import devices_for

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _saved(tmp_path, name, **config) -> str:
    run_dir = tmp_path / name
    run_dir.mkdir()
    (run_dir / "config.json").write_text(json.dumps(config))
    return str(run_dir)


def _cpu(device_count, process_count=1):
    return {"backend": "cpu", "device_count": device_count, "process_count": process_count}


def test_the_recorded_device_count_wins_over_the_seed_rule(tmp_path):
    # A brax run trained inside the benchmarks had the split of the whole process.
    brax = _saved(tmp_path, "brax", algo="sac", num_seeds=6, provenance=_cpu(2))
    assert saved_run_devices(brax) == 2 and saved_run_seeds(brax) == 6
    one = _saved(tmp_path, "one", algo="score", num_seeds=6, provenance=_cpu(1))
    assert saved_run_devices(one) == 1
    # A GPU or multi-process run says nothing about a CPU split: score-train's rule decides.
    gpu = _saved(tmp_path, "gpu", algo="sac", num_seeds=6, provenance={"backend": "gpu"})
    assert saved_run_devices(gpu) == 1  # brax's loops: no split
    multi = _saved(tmp_path, "multi", algo="score", num_seeds=3, provenance=_cpu(4, 2))
    assert saved_run_devices(multi) == devices_for(3, os.cpu_count() or 1)
    asked = _saved(tmp_path, "asked", algo="score", num_seeds=4, cpu_devices=4)
    assert saved_run_devices(asked) == 4


def test_an_unreadable_run_changes_nothing(tmp_path):
    assert saved_run_devices(str(tmp_path / "missing")) is None
    assert saved_run_seeds(str(tmp_path / "missing")) == 1
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "config.json").write_text("[1, 2")
    assert saved_run_devices(str(bad)) is None


SCRIPT = r"""
import sys
from score_jax.cli import eval as eval_cli, robustness as robustness_cli, transfer as transfer_cli
which, run_dir = sys.argv[1], sys.argv[2]
module = {"transfer": transfer_cli, "eval": eval_cli, "robustness": robustness_cli}[which]
args = {
    "transfer": lambda: transfer_cli.TransferArgs(checkpoint=run_dir),
    "eval": lambda: eval_cli.EvalArgs(run_dir=run_dir),
    "robustness": lambda: robustness_cli.RobustnessArgs(run_dir=run_dir),
}[which]()
module.guarded = lambda work: print("DEVICES", __import__("jax").device_count()) or 0
module.enable_compile_cache = lambda enabled: None
sys.exit(module.main(args))
"""


def _run(command: str, run_dir: str, xla_flags: str | None = None):
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env.update(PYTHONPATH=ROOT, JAX_PLATFORMS="cpu")
    if xla_flags is not None:
        env["XLA_FLAGS"] = xla_flags
    return subprocess.run(
        [sys.executable, "-c", SCRIPT, command, run_dir],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.mark.parametrize("command", ["transfer", "eval", "robustness"])
def test_commands_on_a_saved_run_start_jax_with_its_devices(tmp_path, command):
    run_dir = _saved(tmp_path, "run", algo="score", num_seeds=6, provenance=_cpu(2))
    out = _run(command, run_dir)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "DEVICES 2" in out.stdout, out.stdout + out.stderr[-3000:]


def test_a_split_the_user_chose_stays_theirs(tmp_path):
    run_dir = _saved(tmp_path, "run", algo="score", num_seeds=6, provenance=_cpu(2))
    out = _run("transfer", run_dir, xla_flags="--xla_force_host_platform_device_count=1")
    assert "DEVICES 1" in out.stdout, out.stdout + out.stderr[-3000:]
