"""JAX's persistent compilation cache, on by default in every command.

XLA compiles a run's programs (ASRL, the training epoch, the evaluator) from scratch in every
new process, which costs about a minute on a CPU. With the persistent cache a second start of
the same configuration loads the executables from disk instead (README, "Compilation cache").

Where the cache goes, first match wins:
1. ``path`` given to ``enable_compile_cache``;
2. a cache directory already configured for JAX (``JAX_COMPILATION_CACHE_DIR`` in the
   environment, or ``jax.config.update`` by the caller, as the tests do): left as it is;
3. ``$SCORE_JAX_CACHE/xla``, else ``$XDG_CACHE_HOME/score-jax/xla``, else
   ``~/.cache/score-jax/xla`` (the greenhouse references cache sits next to it).

Programs that compile in under ``MIN_COMPILE_SECS`` are not stored (unless
``JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS`` says otherwise). ``--no-compile-cache`` turns
the cache off for the process, whatever the environment says.
"""

from __future__ import annotations

import os

import jax

MIN_COMPILE_SECS = 0.5
_MIN_TIME_ENV = "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"


def default_cache_dir() -> str:
    """``$SCORE_JAX_CACHE/xla``, else ``$XDG_CACHE_HOME/score-jax/xla``, else
    ``~/.cache/score-jax/xla``."""
    xdg = os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache")
    root = os.environ.get("SCORE_JAX_CACHE") or os.path.join(xdg, "score-jax")
    return os.path.join(root, "xla")


def enable_compile_cache(path: str | None = None, enabled: bool = True) -> str | None:
    """Turn JAX's persistent compilation cache on (see the module docstring for where it goes)
    and return its directory; with ``enabled=False`` turn it off and return None.

    Call it before the first compilation of the process: JAX decides whether to use the cache
    when it first compiles.
    """
    if not enabled:
        jax.config.update("jax_enable_compilation_cache", False)
        return None
    jax.config.update("jax_enable_compilation_cache", True)
    configured = jax.config.jax_compilation_cache_dir
    if path is None and configured:
        return configured
    path = os.path.abspath(os.path.expanduser(path or default_cache_dir()))
    os.makedirs(path, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", path)
    if _MIN_TIME_ENV not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECS)
    return path


def cache_status() -> str:
    """``"<dir>"``, ``"off"`` or ``"off (no directory)"``: what the header reports."""
    if not jax.config.jax_enable_compilation_cache:
        return "off"
    return jax.config.jax_compilation_cache_dir or "off (no directory)"
