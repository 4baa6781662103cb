"""Orbax checkpoints of the whole training state, with the metadata needed to trust a restore.

A checkpoint step directory holds two items:
- ``state``: every array of the training state (params, targets, optimiser states, alpha,
  rng, step counters, replay buffer, HVAE params, c_i), saved with ``StandardSave``;
- ``meta``: JSON with the format version, the environment name and options, the composite
  space spec, the agents' sub-spaces, the algorithm and its config.

Saves are synchronous (``wait_until_finished``) and orbax only lists a step once it is
committed, so a run killed mid-save keeps its previous checkpoint intact; a save that fails
(full disk, read-only directory) is a ``CheckpointError`` that says so and names the previous
one. Reading never creates anything (``Checkpointer(..., create=False)``), and
``restore_usable`` takes the newest step that restores and passes its checks, naming the
skipped ones in one warning line.

In a distributed run (``run.distributed``) only process 0 writes: a save gathers the state to
numpy on every process and process 0 saves it (orbax with ``active_processes={0}``), then tells
the others whether it succeeded; a restore reads the numpy arrays on every process, which puts
its own shards of them on its devices with the template's shardings. The run directory must be
on a filesystem every process shares.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Callable
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

from score_jax.core.spaces import CompositeSpace
from score_jax.run import distributed

FORMAT_VERSION = 2  # 2: EnvState.info (AutoReset keeps the final observation there)


class CheckpointError(RuntimeError):
    """A checkpoint is missing, corrupted or does not match what restores it."""


def _fill_empty(tree: Any) -> Any:
    """Orbax cannot write zero-size arrays (MJX data has some): store a 1-element stand-in;
    ``restore`` puts the template's empty array back."""
    return jax.tree.map(lambda x: np.zeros((1,), np.dtype(x.dtype)) if np.size(x) == 0 else x, tree)


def checkpoint_dir(run_dir: str, name: str = "checkpoints") -> str:
    return os.path.join(os.path.abspath(run_dir), name)


def _one_line(text: str, limit: int = 200) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


class Checkpointer:
    """Saves/restores ``(state pytree, meta dict)`` pairs under ``run_dir/<name>``
    (``checkpoints``: the training state; ``best``: the best-evaluated agent state).

    ``create=False`` opens it for reading only: nothing is created, and a missing directory is a
    ``CheckpointError`` ("no run in ...").

    In a distributed run every process opens it (at the same point: with ``create`` they wait
    for process 0 to have created the directory), each with an orbax manager of its own process
    only; ``writes`` is True on process 0 alone."""

    def __init__(
        self, run_dir: str, max_to_keep: int = 3, name: str = "checkpoints", create: bool = True
    ):
        self.directory = checkpoint_dir(run_dir, name)
        self.shared = distributed.multiprocess()
        self.writes = not self.shared or distributed.is_primary()
        if not create and not os.path.isdir(self.directory):
            what = "no run" if name == "checkpoints" else f"no {name} checkpoint"
            raise CheckpointError(f"{what} in {run_dir} (no {self.directory})")
        if create and self.writes:
            os.makedirs(self.directory, exist_ok=True)
        options = dict(max_to_keep=max_to_keep, create=create, cleanup_tmp_directories=create)
        if self.shared:
            if create:
                distributed.barrier(f"created {self.directory}")
                if not distributed.all_true(os.path.isdir(self.directory)):
                    raise CheckpointError(
                        f"{self.directory}, created by process 0, is not visible to every "
                        "process: a --distributed run needs its run directory on a filesystem "
                        "all processes share"
                    )
            me = jax.process_index()  # orbax syncs nothing when a manager is one process's
            options.update(
                create=False,
                cleanup_tmp_directories=create and self.writes,
                multiprocessing_options=ocp.options.MultiprocessingOptions(
                    primary_host=me, active_processes={me}
                ),
            )
        self.manager = ocp.CheckpointManager(
            self.directory, options=ocp.CheckpointManagerOptions(**options)
        )

    def save(self, step: int, state: Any, meta: dict) -> None:
        """Save and wait until committed; a failure (full disk, read-only directory, ...) is a
        ``CheckpointError`` naming the previous checkpoint, which stays usable. Distributed:
        every process calls it (the state is gathered), process 0 saves, and a failed save is
        a ``CheckpointError`` on every process."""
        meta = {**meta, "format_version": FORMAT_VERSION, "step": int(step)}
        if self.shared:
            state = distributed.to_host(state)
        state = _fill_empty(state)
        error = None
        if self.writes:
            try:
                self.manager.save(
                    int(step),
                    args=ocp.args.Composite(
                        state=ocp.args.StandardSave(state), meta=ocp.args.JsonSave(meta)
                    ),
                    force=True,
                )
                self.manager.wait_until_finished()
            except Exception as e:  # orbax passes OSError through or wraps it
                error = e
        failed = distributed.broadcast(int(error is not None)) if self.shared else error is not None
        if not failed:
            return
        previous = [s for s in self.all_steps() if s != int(step)]
        kept = (
            f"the previous checkpoint (step {previous[-1]}) is kept"
            if previous
            else "there is no earlier checkpoint"
        )
        why = "process 0 failed" if error is None else f"{type(error).__name__}: {_one_line(error)}"
        raise CheckpointError(
            f"could not save the checkpoint of step {step} in {self.directory} ({why}); {kept}"
        ) from error

    def _refresh(self) -> None:
        if not self.writes:  # process 0 saves: see its steps
            self.manager.reload()

    def latest_step(self) -> int | None:
        self._refresh()
        return self.manager.latest_step()

    def all_steps(self) -> list[int]:
        """The committed steps, oldest first."""
        self._refresh()
        return sorted(int(s) for s in self.manager.all_steps())

    def read_meta(self, step: int | None = None) -> dict:
        step = self._step(step)
        try:
            meta = self.manager.restore(
                step, args=ocp.args.Composite(meta=ocp.args.JsonRestore())
            ).meta
        except Exception as e:  # orbax raises several types for unreadable files
            raise CheckpointError(
                f"checkpoint {self.directory}/{step} has unreadable metadata "
                f"({type(e).__name__}: {e})"
            ) from e
        if meta.get("format_version") != FORMAT_VERSION:
            raise CheckpointError(
                f"checkpoint format version {meta.get('format_version')} is not supported "
                f"(expected {FORMAT_VERSION})"
            )
        return meta

    def restore(self, template: Any, step: int | None = None) -> tuple[Any, dict]:
        """Restore into the structure, shapes and dtypes of ``template`` (a state built fresh).
        Distributed: every process reads the arrays and places its shards of them with the
        template's shardings."""
        step = self._step(step)
        meta = self.read_meta(step)
        abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, _fill_empty(template))
        if self.shared:  # read into numpy (no devices of other processes involved)
            abstract = jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype), abstract)
        try:
            restored = self.manager.restore(
                step, args=ocp.args.Composite(state=ocp.args.StandardRestore(abstract))
            )
        except Exception as e:
            raise CheckpointError(
                f"checkpoint {self.directory}/{step} could not be restored into the current "
                f"training state ({type(e).__name__}: {str(e)[:300]}); it is corrupted or was "
                "written by a different configuration"
            ) from e
        state = restored.state
        if self.shared:
            state = jax.tree.map(
                lambda t, r: distributed.place(r, t.sharding) if isinstance(t, jax.Array) else r,
                template,
                state,
            )
        state = jax.tree.map(lambda t, r: t if np.size(t) == 0 else r, template, state)
        return state, meta

    def restore_usable(
        self,
        template: Any,
        check: Callable[[dict], None] | None = None,
        log=print,
        set_aside: bool = False,
    ) -> tuple[Any, dict]:
        """The newest checkpoint that restores into ``template`` and passes ``check(meta)``
        (which raises ``CheckpointError``; it runs on the metadata before any array is read).

        Unusable steps are skipped and named in one warning line through ``log``; with
        ``set_aside`` (a run that goes on writing here) the skipped steps newer than the one used
        are moved to ``<dir>.unusable/`` so the run can save those steps again. Raises
        ``CheckpointError`` naming every step's problem when none is usable.
        """
        steps = self.all_steps()[::-1]
        if not steps:
            raise CheckpointError(f"no checkpoint found in {self.directory}")
        skipped = []
        for step in steps:
            try:
                meta = self.read_meta(step)
                if meta.get("step", step) != step:
                    raise CheckpointError(f"its metadata says step {meta.get('step')}")
                if check is not None:
                    check(meta)
                state, meta = self.restore(template, step)
            except CheckpointError as e:
                skipped.append((step, _one_line(e, 160)))
                continue
            if skipped:
                log(
                    f"warning: skipped unusable checkpoint(s) in {self.directory}: "
                    + "; ".join(f"step {s}: {why}" for s, why in skipped)
                    + f"; using step {step}"
                )
                if set_aside:
                    self._set_aside([s for s, _ in skipped if s > step])
            return state, meta
        raise CheckpointError(
            f"no usable checkpoint in {self.directory}: "
            + "; ".join(f"step {s}: {why}" for s, why in skipped)
        )

    def _set_aside(self, steps: list[int]) -> None:
        if not steps:
            return
        if self.writes:
            aside = self.directory + ".unusable"
            os.makedirs(aside, exist_ok=True)
            for step in steps:
                shutil.move(
                    os.path.join(self.directory, str(step)),
                    os.path.join(aside, f"{step}-{time.strftime('%Y%m%d-%H%M%S')}"),
                )
        if self.shared:
            distributed.barrier(f"set aside {self.directory} {steps}")
        self.manager.reload()

    def _step(self, step: int | None) -> int:
        step = self.latest_step() if step is None else step
        if step is None:
            raise CheckpointError(f"no checkpoint found in {self.directory}")
        return step

    def close(self) -> None:
        self.manager.close()


def _space_difference(saved: CompositeSpace, space: CompositeSpace) -> str:
    a = {s.name: s for s in saved.subspaces}
    b = {s.name: s for s in space.subspaces}
    parts = []
    if [n for n in a if n not in b]:
        parts.append(f"only in the checkpoint: {', '.join(n for n in a if n not in b)}")
    if [n for n in b if n not in a]:
        parts.append(f"only in this environment: {', '.join(n for n in b if n not in a)}")
    changed = [n for n in a if n in b and a[n] != b[n]]
    if changed:
        parts.append(f"different: {', '.join(changed)}")
    if not parts:
        parts.append(f"order {list(a)} vs {list(b)}")
    return "; ".join(parts)


def check_space_matches(meta: dict, env_name: str, space: CompositeSpace) -> None:
    """Refuse a checkpoint written for another environment or composite space."""
    if meta.get("env") != env_name:
        raise CheckpointError(
            f"checkpoint was trained on env {meta.get('env')!r}, this run is {env_name!r}"
        )
    saved = CompositeSpace.from_dict(meta["space"])
    if saved != space:
        raise CheckpointError(
            "checkpoint's composite space does not match this environment's "
            f"({_space_difference(saved, space)})"
        )


def checks_for(config: dict, space: CompositeSpace) -> Callable[[dict], None]:
    """``check(meta)`` for ``Checkpointer.restore_usable``: the checkpoint must be of the run
    described by ``config`` (its saved ``TrainConfig`` as a dict): the same environment, algorithm
    and controlled sub-spaces, on ``space``."""

    def check(meta: dict) -> None:
        check_space_matches(meta, config["env"], space)
        saved = meta.get("config", {})
        for key, what in (("algo", "algorithm"), ("subspaces", "sub-spaces")):
            if key in saved and saved.get(key) != config.get(key):
                raise CheckpointError(
                    f"checkpoint was trained with {what} {saved.get(key)!r}, "
                    f"this run has {config.get(key)!r}"
                )

    return check


CONFIG_JSON = "config.json"


def saved_run_config(run_dir: str) -> tuple[dict, dict | None]:
    """``(config, transfer)`` of the run in ``run_dir`` as saved: its ``config.json`` (the
    ``TrainConfig`` as a dict with ``resolved``, ``transfer`` and any ``extensions``), else the
    config in the newest checkpoint whose metadata reads. Creates nothing; a
    ``CheckpointError`` when there is neither."""
    saved = read_json(os.path.join(run_dir, CONFIG_JSON))
    if isinstance(saved, dict) and "env" in saved and "algo" in saved:
        return saved, saved.get("transfer")
    try:
        ckpt = Checkpointer(run_dir, create=False)
    except CheckpointError:
        raise CheckpointError(
            f"no run in {run_dir} (no {CONFIG_JSON} and no checkpoints)"
        ) from None
    try:
        for step in reversed(ckpt.all_steps()):
            try:
                meta = ckpt.read_meta(step)
            except CheckpointError:
                continue
            return {**meta["config"], "resolved": meta.get("resolved")}, meta.get("transfer")
    finally:
        ckpt.close()
    raise CheckpointError(f"no run in {run_dir} (no {CONFIG_JSON} and no readable checkpoint)")


def dump_json(path: str, obj: Any) -> None:
    """Write ``obj`` as JSON atomically (a temporary file renamed over ``path``), so a run killed
    while writing leaves the old file or the new one, never half of one."""
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as f:
        json.dump(obj, f, indent=2, default=str)
    os.replace(tmp, path)


def read_json(path: str) -> Any | None:
    """The JSON in ``path``, or None when it is missing or unreadable."""
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None
