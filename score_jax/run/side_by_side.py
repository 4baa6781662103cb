"""Independent jobs (whole runs, sweeps) in a few fresh processes at once.

A small run on a CPU spends much of its wall time compiling, and XLA compiles a program on
about one core; two runs side by side keep both cores of a small machine busy (one compiles
while the other trains). The benchmarks use it to fill their caches (every job writes its own
result file, which the benchmark then reads as if it had run the job itself).

Jobs run in spawned processes (JAX cannot be forked once it has started), one process per job
so that nothing a run caches or leaks carries over, with the parent's persistent compilation
cache and its environment (``XLA_FLAGS``: the CPU split into one device per core).
"""

from __future__ import annotations

import multiprocessing
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed

import jax

from score_jax.run.compile_cache import enable_compile_cache

Task = tuple[str, Callable, tuple]  # (name, module-level function, its picklable arguments)


def _call(fn: Callable, args: tuple, cache_dir: str | None) -> float:
    enable_compile_cache(cache_dir, enabled=cache_dir is not None)
    t0 = time.time()
    fn(*args)
    return time.time() - t0


def _cache_dir() -> str | None:
    on = jax.config.jax_enable_compilation_cache and jax.config.jax_compilation_cache_dir
    return jax.config.jax_compilation_cache_dir if on else None


def run_side_by_side(tasks: Sequence[Task], workers: int, log=print) -> dict[str, str]:
    """Call ``fn(*args)`` of every task, ``workers`` processes at a time, in the order given
    (put the longest first); one line through ``log`` as each one ends.

    Returns ``{name: "ExceptionType: message"}`` of the tasks that raised; the others ran to
    the end. ``workers <= 1`` or a single task: called here, one after another, exceptions
    reported the same way.
    """
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    errors: dict[str, str] = {}
    t0 = time.time()

    def done(name: str, seconds: float | None, error: BaseException | None, n: int) -> None:
        what = f"failed ({type(error).__name__}: {str(error)[:200]})" if error else "done"
        took = "" if seconds is None else f" in {seconds:.0f} s"
        log(f"  [{n}/{len(tasks)}] {name}: {what}{took} ({time.time() - t0:.0f} s in all)")
        if error is not None:
            errors[name] = f"{type(error).__name__}: {error}"

    if workers == 1 or len(tasks) <= 1:
        for n, (name, fn, args) in enumerate(tasks, 1):
            t = time.time()
            try:
                fn(*args)
            except Exception as e:  # reported; the other tasks still run
                done(name, None, e, n)
                continue
            done(name, time.time() - t, None, n)
        return errors
    cache = _cache_dir()
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=context, max_tasks_per_child=1) as pool:
        futures = {pool.submit(_call, fn, args, cache): name for name, fn, args in tasks}
        for n, future in enumerate(as_completed(futures), 1):
            try:
                seconds = future.result()
            except Exception as e:  # a raising job (or a dead worker) is reported, not raised
                done(futures[future], None, e, n)
                continue
            done(futures[future], seconds, None, n)
    return errors
