"""Orbax checkpoints of the whole training state, with the metadata needed to trust a restore.

A checkpoint step directory holds two items:
- ``state``: every array of the training state (params, targets, optimiser states, alpha,
  rng, step counters, replay buffer, HVAE params, c_i), saved with ``StandardSave``;
- ``meta``: JSON with the format version, the environment name and options, the composite
  space spec, the agents' sub-spaces, the algorithm and its config.

Saves are synchronous (``wait_until_finished``) and orbax only lists a step once it is
committed, so a run killed mid-save keeps its previous checkpoint intact.
"""

from __future__ import annotations

import json
import os
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

from score_jax.core.spaces import CompositeSpace

FORMAT_VERSION = 2  # 2: EnvState.info (AutoReset keeps the final observation there)


class CheckpointError(RuntimeError):
    """A checkpoint is missing, corrupted or does not match what restores it."""


def _fill_empty(tree: Any) -> Any:
    """Orbax cannot write zero-size arrays (MJX data has some): store a 1-element stand-in;
    ``restore`` puts the template's empty array back."""
    return jax.tree.map(
        lambda x: np.zeros((1,), np.asarray(x).dtype) if np.size(x) == 0 else x, tree
    )


def checkpoint_dir(run_dir: str, name: str = "checkpoints") -> str:
    return os.path.join(os.path.abspath(run_dir), name)


class Checkpointer:
    """Saves/restores ``(state pytree, meta dict)`` pairs under ``run_dir/<name>``
    (``checkpoints``: the training state; ``best``: the best-evaluated agent state)."""

    def __init__(self, run_dir: str, max_to_keep: int = 3, name: str = "checkpoints"):
        self.directory = checkpoint_dir(run_dir, name)
        os.makedirs(self.directory, exist_ok=True)
        self.manager = ocp.CheckpointManager(
            self.directory, options=ocp.CheckpointManagerOptions(max_to_keep=max_to_keep)
        )

    def save(self, step: int, state: Any, meta: dict) -> None:
        meta = {**meta, "format_version": FORMAT_VERSION, "step": int(step)}
        state = _fill_empty(state)
        self.manager.save(
            int(step),
            args=ocp.args.Composite(
                state=ocp.args.StandardSave(state), meta=ocp.args.JsonSave(meta)
            ),
            force=True,
        )
        self.manager.wait_until_finished()

    def latest_step(self) -> int | None:
        return self.manager.latest_step()

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
        """Restore into the structure, shapes and dtypes of ``template`` (a state built fresh)."""
        step = self._step(step)
        meta = self.read_meta(step)
        abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, _fill_empty(template))
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
        state = jax.tree.map(lambda t, r: t if np.size(t) == 0 else r, template, restored.state)
        return state, meta

    def _step(self, step: int | None) -> int:
        step = self.latest_step() if step is None else step
        if step is None:
            raise CheckpointError(f"no checkpoint found in {self.directory}")
        return step

    def close(self) -> None:
        self.manager.close()


def check_space_matches(meta: dict, env_name: str, space: CompositeSpace) -> None:
    """Refuse a checkpoint written for another environment or composite space."""
    if meta.get("env") != env_name:
        raise CheckpointError(
            f"checkpoint was trained on env {meta.get('env')!r}, not {env_name!r}"
        )
    saved = CompositeSpace.from_dict(meta["space"])
    if saved != space:
        raise CheckpointError(
            "checkpoint's composite space does not match this environment's:\n"
            f"checkpoint:\n{saved.describe()}\nenvironment:\n{space.describe()}"
        )


def dump_json(path: str, obj: Any) -> None:
    with open(path, "w") as f:
        json.dump(obj, f, indent=2, default=str)
