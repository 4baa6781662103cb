"""score_jax.run.side_by_side: jobs in spawned processes, failures reported, the compilation
cache handed on."""

import os

import jax
import pytest

from score_jax.run.side_by_side import run_side_by_side


def _note_process(path: str) -> None:
    """Writes the process id and the compilation cache directory JAX uses there."""
    with open(path, "w") as f:
        f.write(f"{os.getpid()} {jax.config.jax_compilation_cache_dir}")


def _fail(message: str) -> None:
    raise ValueError(message)


def test_jobs_run_in_other_processes_and_failures_are_reported(tmp_path):
    paths = [str(tmp_path / name) for name in ("a", "b")]
    tasks = [("a", _note_process, (paths[0],)), ("bad", _fail, ("boom",))]
    tasks.append(("b", _note_process, (paths[1],)))
    lines = []
    errors = run_side_by_side(tasks, 2, log=lines.append)
    assert errors == {"bad": "ValueError: boom"}
    assert len(lines) == 3 and sum("failed (ValueError: boom)" in x for x in lines) == 1
    notes = [open(p).read().split() for p in paths]
    pids = {pid for pid, _ in notes}
    assert str(os.getpid()) not in pids and len(pids) == 2  # one fresh process per job
    cache = jax.config.jax_compilation_cache_dir  # set by conftest for every test
    assert cache and jax.config.jax_enable_compilation_cache
    assert all(dirname == cache for _, dirname in notes)  # the parent's cache, handed on


def test_one_worker_runs_here_and_reports_the_same_way(tmp_path):
    path = str(tmp_path / "a")
    errors = run_side_by_side(
        [("bad", _fail, ("x",)), ("a", _note_process, (path,))], 1, log=lambda m: None
    )
    assert errors == {"bad": "ValueError: x"}
    assert open(path).read().split()[0] == str(os.getpid())
    with pytest.raises(ValueError, match="workers"):
        run_side_by_side([], 0)
