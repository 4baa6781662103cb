"""Metric writers (experiment tracking) behind one interface.

``MetricWriter`` is anything with ``write(step, metrics, seed=None)`` and ``close()``; ``step`` is
the number of decisions per seed (environment steps when a decision is one step; with a
decision held ``action_repeat`` steps, as on the greenhouse, multiply by it). Implementations:

- ``CsvWriter``: one CSV file, columns ``env_steps``, ``seed`` (only when the first row gave a
  seed), then the metric names of the first row (or ``columns``). Appending to an existing file
  (a resumed run) keeps its header and refuses rows with keys it does not have; ``truncate``
  drops rows after a step. NaN is written as ``nan``, a column missing from a row as ``nan``.
- ``TensorBoardWriter``: tensorboardX event files. Each seed gets its own run directory
  ``<logdir>/seed_<k>`` (rows without a seed go to ``<logdir>`` itself), so TensorBoard overlays
  the seeds under the same tags. A metric name without ``/`` is tagged ``<prefix>/<name>``
  (``train/episode_return``); names with ``/`` are kept. NaN values are skipped.
- ``WandbWriter``: one Weights & Biases run, offline unless told otherwise (no network, no
  login; ``wandb sync`` uploads it later). Tags as for TensorBoard, with a ``seed_<k>/`` prefix
  for rows with a seed; ``env_steps`` is the x-axis of every metric. NaN values are skipped.
- ``NullWriter`` writes nothing (every process but process 0 of a distributed run).
- ``MultiWriter`` fans out to several writers; ``make_writers`` builds one from kind names and
  always includes the CSV writer.

tensorboardX and wandb are the optional ``tracking`` extra (``pip install -e .[tracking]``) and
are imported only by the writer that needs them.
"""

from __future__ import annotations

import csv
import math
import numbers
import os
from collections.abc import Mapping, Sequence
from typing import Any, Protocol, runtime_checkable

STEP_COLUMN = "env_steps"
SEED_COLUMN = "seed"
KNOWN_WRITERS = ("csv", "tensorboard", "wandb")
_INSTALL_HINT = 'pip install -e ".[tracking]"'


@runtime_checkable
class MetricWriter(Protocol):
    """Writes one row of scalar metrics at an env step, optionally for one seed."""

    def write(self, step: int, metrics: Mapping[str, float], seed: int | None = None) -> None: ...

    def close(self) -> None: ...


class _Writer:
    """Context-manager support shared by the writers."""

    def write(self, step: int, metrics: Mapping[str, float], seed: int | None = None) -> None:
        raise NotImplementedError

    def flush(self) -> None:
        """Make everything written so far durable (a no-op where writes already are)."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _scalar(name: str, value: Any) -> float | int:
    """A Python int (for integer values) or float; ValueError naming the metric otherwise."""
    if isinstance(value, numbers.Integral):  # Python and numpy integers (and bools)
        return int(value)
    try:
        return float(value)
    except (TypeError, ValueError) as e:
        raise ValueError(f"metric {name!r} is not a scalar number: {value!r}") from e


def _is_nan(value: float | int) -> bool:
    return isinstance(value, float) and math.isnan(value)


def _tag(name: str, prefix: str) -> str:
    """``train/episode_return`` for ``episode_return``; names with ``/`` unchanged."""
    return name if "/" in name or not prefix else f"{prefix}/{name}"


def _metric_items(
    step: int, metrics: Mapping[str, Any], seed: int | None
) -> dict[str, float | int]:
    """The metrics as scalars, without ``env_steps``/``seed`` keys that repeat the arguments."""
    out = {}
    for name, value in metrics.items():
        v = _scalar(name, value)
        if name in (STEP_COLUMN, SEED_COLUMN):
            expected = step if name == STEP_COLUMN else seed
            if expected is None or v != expected:
                raise ValueError(
                    f"metrics[{name!r}] = {v!r} contradicts the {name} argument ({expected!r})"
                )
            continue
        out[name] = v
    return out


# --- CSV --------------------------------------------------------------------------------------


def _format(value: float | int) -> str:
    return "nan" if _is_nan(value) else str(value)


def _read_header(path: str) -> list[str] | None:
    """The first row of an existing non-empty CSV file, else None."""
    if not os.path.exists(path) or os.path.getsize(path) == 0:
        return None
    with open(path, newline="") as f:
        header = next(csv.reader(f), None)
    if not header or header[0] != STEP_COLUMN:
        raise ValueError(
            f"{path} exists but its header {header} does not start with "
            f"{STEP_COLUMN!r}; not a metrics file written by CsvWriter"
        )
    return header


def _step_at_most(text: str, max_step: int) -> bool:
    try:
        return int(float(text)) <= max_step
    except ValueError:
        return False


def truncate_csv(path: str, max_step: int) -> int:
    """Drop the rows of ``path`` whose ``env_steps`` is above ``max_step`` (on resume, the rows
    after the checkpoint are produced again), and any row cut short (a write interrupted by a
    full disk); keeps the header. Returns the rows kept."""
    header = _read_header(path)
    if header is None:
        return 0
    with open(path, newline="") as f:
        rows = [r for r in csv.reader(f)][1:]
    kept = [r for r in rows if len(r) == len(header) and _step_at_most(r[0], max_step)]
    tmp = path + ".tmp"
    with open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(kept)
    os.replace(tmp, path)
    return len(kept)


class CsvWriter(_Writer):
    """Rows of metrics in one CSV file; see the module docstring for the column rules.

    ``columns`` fixes the metric columns (and their order) of a new file instead of the first
    row's keys. An existing non-empty file is appended to unless ``overwrite``.
    """

    def __init__(self, path: str, columns: Sequence[str] | None = None, overwrite: bool = False):
        self.path = path
        self._columns = None
        if columns is not None:
            self._columns = [c for c in columns if c not in (STEP_COLUMN, SEED_COLUMN)]
        if overwrite and os.path.exists(path):
            os.remove(path)
        self.header = _read_header(path)
        if self.header is not None and self._columns is not None:
            have = [c for c in self.header if c not in (STEP_COLUMN, SEED_COLUMN)]
            if have != self._columns:
                raise ValueError(
                    f"{path} has metric columns {have}, not the requested {self._columns}"
                )
        self._file = None
        self._writer = None

    def _open(self) -> None:
        if self._file is None:
            parent = os.path.dirname(self.path)
            if parent:
                os.makedirs(parent, exist_ok=True)
            self._file = open(self.path, "a", newline="")
            self._writer = csv.writer(self._file)

    def _new_header(self, metrics: Mapping[str, Any], seed: int | None) -> list[str]:
        lead = [STEP_COLUMN] + ([SEED_COLUMN] if seed is not None else [])
        return lead + (self._columns if self._columns is not None else list(metrics))

    def _check(self, header: list[str], metrics: Mapping[str, Any], seed: int | None) -> None:
        has_seed = SEED_COLUMN in header
        if (seed is not None) != has_seed:
            raise ValueError(
                f"{self.path} {'has' if has_seed else 'has no'} {SEED_COLUMN!r} column; "
                f"write {'with' if has_seed else 'without'} a seed"
            )
        unknown = [k for k in metrics if k not in header]
        if unknown:
            raise ValueError(
                f"{self.path}: keys {unknown} are not among the file's columns "
                f"{header}; write them to another file or start a new one"
            )

    def write(self, step: int, metrics: Mapping[str, float], seed: int | None = None) -> None:
        """Append one row; ValueError for keys the header lacks (nothing is written then)."""
        items = _metric_items(int(step), metrics, seed)
        new = self.header is None
        header = self._new_header(items, seed) if new else self.header
        self._check(header, items, seed)
        self._open()
        if new:
            self._writer.writerow(header)
            self.header = header
        row = {STEP_COLUMN: int(step), SEED_COLUMN: seed, **items}
        self._writer.writerow([_format(row[c]) if c in row else "nan" for c in self.header])
        self._file.flush()

    def truncate(self, max_step: int) -> int:
        """Drop rows after ``max_step`` (see ``truncate_csv``); returns the rows kept."""
        self.close()
        return truncate_csv(self.path, max_step)

    def flush(self) -> None:
        if self._file is not None:
            self._file.flush()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file, self._writer = None, None


def read_csv(path: str) -> list[dict[str, float]]:
    """The rows of a CsvWriter file as floats (``nan`` for NaN), for tests and reports."""
    with open(path, newline="") as f:
        return [{k: float(v) for k, v in r.items()} for r in csv.DictReader(f)]


# --- TensorBoard ------------------------------------------------------------------------------


class TensorBoardWriter(_Writer):
    """Scalars into tensorboardX event files under ``logdir`` (``seed_<k>/`` per seed)."""

    def __init__(self, logdir: str, prefix: str = "train", flush_secs: int = 30):
        try:
            import tensorboardX
        except ImportError as e:
            raise ImportError(f"TensorBoardWriter needs tensorboardX: {_INSTALL_HINT}") from e
        self._summary_writer = tensorboardX.SummaryWriter
        self.logdir = logdir
        self.prefix = prefix
        self.flush_secs = flush_secs
        self._writers: dict[int | None, Any] = {}

    def run_dir(self, seed: int | None) -> str:
        """The event-file directory of ``seed``."""
        return self.logdir if seed is None else os.path.join(self.logdir, f"seed_{seed}")

    def _writer(self, seed: int | None):
        if seed not in self._writers:
            self._writers[seed] = self._summary_writer(
                logdir=self.run_dir(seed), flush_secs=self.flush_secs
            )
        return self._writers[seed]

    def write(self, step: int, metrics: Mapping[str, float], seed: int | None = None) -> None:
        """One scalar per metric at ``step``; NaN values are skipped."""
        items = _metric_items(int(step), metrics, seed)
        w = self._writer(seed)
        for name, value in items.items():
            if not _is_nan(value):
                w.add_scalar(_tag(name, self.prefix), value, global_step=int(step))

    def flush(self) -> None:
        for w in self._writers.values():
            w.flush()

    def close(self) -> None:
        for w in self._writers.values():
            w.close()
        self._writers.clear()


# --- Weights & Biases -------------------------------------------------------------------------


def _import_wandb():
    try:
        import wandb
    except ImportError as e:
        hint = f"WandbWriter needs wandb, which is not installed: {_INSTALL_HINT}"
        raise ImportError(hint) from e
    return wandb


class WandbWriter(_Writer):
    """One W&B run in ``run_dir/wandb``.

    ``mode``: ``"offline"`` (needs no network or login), ``"online"`` or ``"disabled"``; None
    takes ``WANDB_MODE`` from the environment and otherwise ``"offline"``, so that a training
    job never waits on a login prompt. ``config`` is stored as the run's config.
    """

    def __init__(
        self,
        project: str,
        run_dir: str,
        config: Mapping[str, Any] | None = None,
        mode: str | None = None,
        name: str | None = None,
        group: str | None = None,
        prefix: str = "train",
    ):
        wandb = _import_wandb()
        self.mode = mode or os.environ.get("WANDB_MODE") or "offline"
        self.prefix = prefix
        os.makedirs(run_dir, exist_ok=True)
        self.run = wandb.init(
            project=project,
            dir=run_dir,
            config=dict(config or {}),
            mode=self.mode,
            name=name,
            group=group,
            reinit="create_new",
            settings=wandb.Settings(silent=True),
        )
        self.run.define_metric(STEP_COLUMN)
        self.run.define_metric("*", step_metric=STEP_COLUMN)
        self._closed = False

    def write(self, step: int, metrics: Mapping[str, float], seed: int | None = None) -> None:
        """Log the non-NaN metrics with ``env_steps`` as their x-axis."""
        items = _metric_items(int(step), metrics, seed)
        head = "" if seed is None else f"seed_{seed}/"
        data = {head + _tag(k, self.prefix): v for k, v in items.items() if not _is_nan(v)}
        if data:
            self.run.log({STEP_COLUMN: int(step), **data})

    def close(self) -> None:
        """Finish the run (wandb's service process may write the last records out just after
        this returns)."""
        if not self._closed:
            self.run.finish()
            self._closed = True


class NullWriter(_Writer):
    """Writes nothing (the metric writer of every process but process 0 in a distributed run)."""

    def write(self, step: int, metrics: Mapping[str, float], seed: int | None = None) -> None:
        _metric_items(int(step), metrics, seed)  # the same checks as the real writers

    def close(self) -> None:
        pass


# --- fan-out ----------------------------------------------------------------------------------


class MultiWriter(_Writer):
    """Writes every row to each of ``writers``; ``close`` closes all of them, then re-raises the
    first error one of them raised."""

    def __init__(self, writers: Sequence[MetricWriter]):
        self.writers = list(writers)

    def write(self, step: int, metrics: Mapping[str, float], seed: int | None = None) -> None:
        for w in self.writers:
            w.write(step, metrics, seed=seed)

    def flush(self) -> None:
        for w in self.writers:
            getattr(w, "flush", lambda: None)()

    def close(self) -> None:
        errors = []
        for w in self.writers:
            try:
                w.close()
            except Exception as e:  # noqa: BLE001 - close the others, then report
                errors.append(e)
        if errors:
            raise errors[0]


# the module each kind needs, beyond the standard library
_REQUIRES = {"tensorboard": "tensorboardX", "wandb": "wandb"}


def check_kinds(kinds: Sequence[str], installed: bool = False) -> None:
    """ValueError for an unknown kind and, with ``installed``, for a kind whose package is not
    installed (the message says how to install it): a run checks this before it starts, not
    after minutes of set-up."""
    unknown = [k for k in kinds if k not in KNOWN_WRITERS]
    if unknown:
        raise ValueError(f"unknown writer kind(s) {unknown}; known: {', '.join(KNOWN_WRITERS)}")
    if installed:
        import importlib.util

        for kind in kinds:
            module = _REQUIRES.get(kind)
            if module is not None and importlib.util.find_spec(module) is None:
                raise ValueError(
                    f"--track {kind} needs the {module} package, which is not installed: "
                    f"{_INSTALL_HINT}"
                )


def make_writers(
    kinds: Sequence[str],
    run_dir: str,
    *,
    csv_name: str = "metrics.csv",
    csv_columns: Sequence[str] | None = None,
    project: str = "score-jax",
    config: Mapping[str, Any] | None = None,
    wandb_mode: str | None = None,
    name: str | None = None,
) -> MultiWriter:
    """A MultiWriter of the named kinds (``csv``, ``tensorboard``, ``wandb``) for ``run_dir``;
    the CSV writer (``run_dir/csv_name``) is always included. TensorBoard writes to
    ``run_dir/tensorboard``, W&B to ``run_dir/wandb`` (a run called ``name``). ValueError for an
    unknown kind."""
    check_kinds(kinds)
    wanted = {"csv", *kinds}
    writers: list[MetricWriter] = [CsvWriter(os.path.join(run_dir, csv_name), csv_columns)]
    try:
        if "tensorboard" in wanted:
            writers.append(TensorBoardWriter(os.path.join(run_dir, "tensorboard")))
        if "wandb" in wanted:
            writers.append(WandbWriter(project, run_dir, config=config, mode=wandb_mode, name=name))
    except Exception:
        MultiWriter(writers).close()
        raise
    return MultiWriter(writers)
