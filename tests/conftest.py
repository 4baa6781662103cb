"""Shared test set-up: CPU only, a persistent compilation cache shared by all tests and their
subprocesses (the suite compiles each program once per machine, not once per test)."""

import ctypes.util
import os
import tempfile

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# Software rendering where libOSMesa is installed. Without it MUJOCO_GL=osmesa would make
# ``import mujoco`` itself fail (every Spider test, not just rendering); left unset, envs.spider
# keeps simulation working and the rendering tests skip.
if ctypes.util.find_library("OSMesa"):
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


def pytest_collection_modifyitems(config, items):
    """Modules holding a ``slow`` test first (in collection order), then the others, most tests
    first. scripts/test.sh runs ``--dist loadfile --no-loadscope-reorder``: each worker takes
    whole modules in this order, so a long module does not start last and leave one core
    working alone at the end (xdist's own order, by number of tests, put the one-test
    end-to-end modules last)."""
    modules: dict[str, list] = {}
    for item in items:
        modules.setdefault(item.nodeid.split("::")[0], []).append(item)

    def rank(entry):
        position, group = entry
        if any(item.get_closest_marker("slow") for item in group):
            return (0, 0, position)
        return (1, -len(group), position)

    order = sorted(enumerate(modules.values()), key=rank)
    items[:] = [item for _, group in order for item in group]
