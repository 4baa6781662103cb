"""How every command ends: each error a user can cause becomes ``error: ...`` lines on stderr and
an exit status, never a traceback.

- 2: a usage error (``run.validate.UsageError``: one line per problem, all of them at once);
- 1: a run error: a non-finite loss (``NonFiniteError``), a missing, corrupted or mismatched
  checkpoint (``CheckpointError``), a file the system refuses (``OSError``: missing file, full
  disk, read-only directory), a device out of memory, a bad value found while running;
- 130: interrupted (Ctrl-C); the run keeps its last checkpoint.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

from jax.errors import JaxRuntimeError

from score_jax.run.checkpoint import CheckpointError
from score_jax.run.recorder import NonFiniteError
from score_jax.run.validate import UsageError

USAGE, RUN_ERROR, INTERRUPTED = 2, 1, 130
RUN_ERRORS = (NonFiniteError, CheckpointError, OSError, MemoryError, JaxRuntimeError)
RUN_ERRORS += (ValueError, KeyError)


def one_line(error: BaseException | str, limit: int = 600) -> str:
    """An error as one line (its whitespace collapsed), cut at ``limit`` characters."""
    text = error if isinstance(error, str) else str(error)
    if isinstance(error, KeyError) and error.args:
        text = str(error.args[0])
    text = " ".join(text.split()) or type(error).__name__
    return text if len(text) <= limit else text[: limit - 3] + "..."


def guarded(work: Callable[[], object]) -> int:
    """Run ``work()``; 0 when it returns, else the exit status of the error it raised, with its
    ``error:`` lines printed to stderr."""
    try:
        work()
    except UsageError as e:
        for problem in e.problems:
            print(f"error: {one_line(problem)}", file=sys.stderr)
        return USAGE
    except KeyboardInterrupt:
        print(
            "error: interrupted; a run keeps its last checkpoint (continue it with --resume)",
            file=sys.stderr,
        )
        return INTERRUPTED
    except RUN_ERRORS as e:
        print(f"error: {one_line(e)}", file=sys.stderr)
        return RUN_ERROR
    return 0
