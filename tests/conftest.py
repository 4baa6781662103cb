"""Shared test set-up: CPU only, a persistent compilation cache shared by all tests and their
subprocesses (the suite compiles each program once per machine, not once per test)."""

import os
import tempfile

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("MUJOCO_GL", "osmesa")
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")
# Tests run tiny programs, where XLA's backend optimisation costs more compile time than it
# saves at run time (the README gives the measured suite times). Subprocesses inherit it.
if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=0"
    ).strip()
CACHE_DIR = os.environ.setdefault(
    "SCORE_JAX_TEST_CACHE", os.path.join(tempfile.gettempdir(), "score-jax-test-jax-cache")
)
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", CACHE_DIR)
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")

import jax  # noqa: E402

jax.config.update("jax_compilation_cache_dir", CACHE_DIR)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
