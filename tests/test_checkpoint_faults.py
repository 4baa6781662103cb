"""A damaged checkpoint never costs the run: resume and restore take the newest checkpoint that
restores and passes its checks (skipped ones named in one warning line), a checkpoint of another
environment is named as such, a failed save (full disk, read-only directory) is a clear error that
keeps the previous checkpoint usable, read paths are never created, and ``--resume DIR
--total-steps N`` extends a run exactly as if it had been given N from the start."""

import csv
import errno
import json
import os
import shutil

import jax
import numpy as np
import orbax.checkpoint as ocp
import pytest

from score_jax.agents.marl.config import MarlConfig
from score_jax.cli import train as train_cli
from score_jax.networks.actor import ActorConfig
from score_jax.run.build import restore_run
from score_jax.run.checkpoint import Checkpointer, CheckpointError
from score_jax.run.config import TrainConfig
from score_jax.run.driver import train
from score_jax.run.validate import UsageError
from tests.tiny import tiny_config

TINY_MARL = MarlConfig(actor=ActorConfig(hidden=(32, 32)), critic_hidden=(32, 32))
quiet = lambda *a: None


def _config(run_dir, **overrides):
    """ISAC on the probe (the checkpoint machinery is the same for every in-process algorithm,
    and ISAC's programs trace and compile in a fraction of SCORE's time)."""
    return tiny_config(run_dir, algo="isac", marl=TINY_MARL, **overrides)


def _rows(run_dir):
    """metrics.csv without its wall-clock column."""
    with open(os.path.join(run_dir, "metrics.csv"), newline="") as f:
        return [{k: v for k, v in r.items() if k != "wall_s"} for r in csv.DictReader(f)]


def _params(state):
    return jax.device_get((state.agent.actor, state.agent.critic, state.agent.log_alpha))


def _assert_same(a, b):
    jax.tree.map(np.testing.assert_array_equal, _params(a), _params(b))


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """An uninterrupted run: 1000 decisions, checkpoints at 400, 800 and 1000."""
    return train(_config(tmp_path_factory.mktemp("runs") / "finished"), log=quiet)


@pytest.fixture
def copy(finished, tmp_path):
    run_dir = tmp_path / "copy"
    shutil.copytree(finished.run_dir, run_dir)
    return run_dir


def _corrupt(step_dir):
    for root, _, files in os.walk(os.path.join(step_dir, "state")):
        for f in files:
            path = os.path.join(root, f)
            if os.path.getsize(path) > 64:
                with open(path, "r+b") as fh:
                    fh.truncate(16)


def _set_meta_env(step_dir, env):
    path = os.path.join(step_dir, "meta", "metadata")
    with open(path) as f:
        meta = json.load(f)
    meta["env"] = env
    with open(path, "w") as f:
        json.dump(meta, f)


def test_corrupted_latest_checkpoint_falls_back_to_an_older_one(finished, copy):
    """Restore and resume skip the corrupted newest step with one warning line; the resumed
    run ends identical to the uninterrupted one (defect 8)."""
    assert Checkpointer(str(copy)).all_steps() == [400, 800, 1000]
    _corrupt(copy / "checkpoints" / "1000")
    logs = []
    restored = restore_run(str(copy), log=logs.append)
    assert int(restored.state.env_steps[0]) == 800
    warnings = [m for m in logs if m.startswith("warning:")]
    assert len(warnings) == 1 and "step 1000:" in warnings[0] and "using step 800" in warnings[0]
    logs.clear()
    resumed = train(TrainConfig(resume=str(copy), quiet=True), log=logs.append)
    assert any("resumed" in m and "at env step 800" in m for m in logs)
    assert int(resumed.state.env_steps[0]) == 1000
    _assert_same(resumed.state, finished.state)
    assert os.listdir(str(copy / "checkpoints.unusable"))[0].startswith("1000-")
    assert _rows(copy) == _rows(finished.run_dir)


def test_checkpoint_of_another_environment_is_named_as_such(copy):
    _set_meta_env(copy / "checkpoints" / "1000", "greenhouse")
    logs = []
    restored = restore_run(str(copy), log=logs.append)
    assert int(restored.state.env_steps[0]) == 800
    assert "step 1000: checkpoint was trained on env 'greenhouse', this run is 'probe'" in (
        "".join(logs)
    )
    for step in (400, 800):
        _set_meta_env(copy / "checkpoints" / str(step), "greenhouse")
    with pytest.raises(CheckpointError) as e:
        restore_run(str(copy), log=quiet)
    assert "trained on env 'greenhouse', this run is 'probe'" in str(e.value)
    assert "corrupted" not in str(e.value)


def test_read_paths_are_never_created(tmp_path):
    typo = tmp_path / "typo"
    with pytest.raises(CheckpointError, match="no run in"):
        restore_run(str(typo), log=quiet)
    with pytest.raises(CheckpointError, match="no run in"):
        Checkpointer(str(typo), create=False)
    assert not typo.exists()


def test_resume_with_more_steps_extends_the_run_exactly(finished, copy):
    """A run of 600 decisions killed at 400, resumed with ``--total-steps 1000``, goes on to
    1000 (the saved budget was kept before, defect 6), records the extension, and ends equal to
    a run given 1000 from the start."""
    saved = json.load(open(copy / "config.json"))
    saved["total_steps"] = saved["resolved"]["total_steps"] = 600
    json.dump(saved, open(copy / "config.json", "w"))
    for step in (800, 1000):
        shutil.rmtree(copy / "checkpoints" / str(step))
    extended = train(TrainConfig(resume=str(copy), total_steps=1000, quiet=True), log=quiet)
    assert int(extended.state.env_steps[0]) == 1000
    saved = json.load(open(copy / "config.json"))
    assert saved["total_steps"] == 1000 and saved["resolved"]["total_steps"] == 1000
    assert saved["extensions"] == [
        {"at_step": 400, "from_total_steps": 600, "to_total_steps": 1000}
    ]
    _assert_same(extended.state, finished.state)
    assert _rows(copy) == _rows(finished.run_dir)
    with pytest.raises(UsageError, match="already done 1000 decisions"):
        train(TrainConfig(resume=str(copy), total_steps=900), log=quiet)


def _failing_saves(monkeypatch, fail_from: int, error: int):
    """Checkpoint saves from the ``fail_from``-th on raise ``OSError(error)`` (a full disk or a
    read-only file system, as the kernel reports them)."""
    calls = []
    save = ocp.CheckpointManager.save

    def failing(self, step, *args, **kwargs):
        calls.append(step)
        if len(calls) >= fail_from:
            raise OSError(error, os.strerror(error), str(self.directory))
        return save(self, step, *args, **kwargs)

    monkeypatch.setattr(ocp.CheckpointManager, "save", failing)


def test_full_disk_during_a_save_is_a_clear_error_and_keeps_the_previous_checkpoint(
    tmp_path, monkeypatch, capsys
):
    run_dir = tmp_path / "run"
    _failing_saves(monkeypatch, fail_from=2, error=errno.ENOSPC)  # the save at step 800
    assert train_cli.main(_config(run_dir)) == 1
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: could not save the checkpoint of step")
    assert "No space left on device" in lines[0]
    assert "the previous checkpoint (step 400) is kept" in lines[0]
    monkeypatch.undo()
    assert int(restore_run(str(run_dir), log=quiet).state.env_steps[0]) == 400


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes through a read-only mode")
def test_read_only_checkpoint_directory_is_a_clear_error(tmp_path, monkeypatch, capsys):
    run_dir = tmp_path / "run"
    save = Checkpointer.save

    def then_read_only(self, step, state, meta):  # read-only after the first checkpoint
        save(self, step, state, meta)
        if self.directory.endswith("checkpoints"):
            os.chmod(self.directory, 0o555)

    monkeypatch.setattr(Checkpointer, "save", then_read_only)
    try:
        assert train_cli.main(_config(run_dir)) == 1
    finally:
        os.chmod(run_dir / "checkpoints", 0o755)
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and "could not save the checkpoint of step 800" in lines[0]
    assert "the previous checkpoint (step 400) is kept" in lines[0]
    monkeypatch.undo()
    assert int(restore_run(str(run_dir), log=quiet).state.env_steps[0]) == 400


def test_damaged_best_policy_never_stops_the_run(tmp_path, capsys):
    """A corrupted best policy: restoring it falls back to the last policy, and a resume starts a
    new best instead of stopping, each with a warning."""
    run_dir = tmp_path / "run"
    last = train(_config(run_dir, total_steps=400, eval_every=200, eval_episodes=2), log=quiet)
    step = [d for d in os.listdir(run_dir / "best") if d.isdigit()][0]
    _corrupt(run_dir / "best" / step)
    logs = []
    best = restore_run(str(run_dir), log=logs.append, policy="best")
    assert any(m.startswith("warning: the best policy") for m in logs), logs
    _assert_same(best.state, last.state)
    with open(run_dir / "best" / step / "meta" / "metadata", "w") as f:
        f.write("{not json")
    capsys.readouterr()
    resumed = train(TrainConfig(resume=str(run_dir), total_steps=600, quiet=True), log=print)
    assert int(resumed.state.env_steps[0]) == 600
    assert "a new best policy from here on" in capsys.readouterr().out
