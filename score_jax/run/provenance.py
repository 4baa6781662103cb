"""Where a run came from: package versions, Python, platform, JAX backend and devices, and the
git commit of the code when it runs from a git checkout. Written into every run's
``config.json`` and checkpoint metadata, so a result can be traced to what produced it."""

from __future__ import annotations

import datetime
import functools
import importlib.metadata
import os
import platform
import shutil
import subprocess
import sys

import jax

# The distributions whose versions decide a run's numbers (and the rest of the pinned stack).
PACKAGES = (
    "score-jax",
    "jax",
    "jaxlib",
    "flax",
    "optax",
    "chex",
    "orbax-checkpoint",
    "brax",
    "mujoco",
    "mujoco-mjx",
    "numpy",
    "scipy",
)
_PACKAGE_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def package_versions(names=PACKAGES) -> dict[str, str | None]:
    """``{distribution: version}`` of the installed distributions (None where one is absent)."""
    out = {}
    for name in names:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = None
    return out


def _git(*args: str) -> str | None:
    git = shutil.which("git")
    if git is None:
        return None
    try:
        done = subprocess.run(
            [git, "-C", _PACKAGE_ROOT, *args],
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


@functools.lru_cache(maxsize=1)
def git_info() -> dict | None:
    """``{"commit", "dirty"}`` of the checkout this package runs from, or None when it is not
    a git checkout's root (an installed wheel, or no ``git`` on the path). ``dirty``: tracked
    files differ from the commit."""
    top = _git("rev-parse", "--show-toplevel")
    if top is None or os.path.realpath(top) != os.path.realpath(_PACKAGE_ROOT):
        return None  # e.g. site-packages inside some other repository
    commit = _git("rev-parse", "HEAD")
    if commit is None:
        return None
    status = _git("status", "--porcelain", "--untracked-files=no")
    return {"commit": commit, "dirty": bool(status)}


# CPU features that change the machine code XLA emits for the host (vector width, fused
# multiply-add), hence the rounding of a run's floats: RL training amplifies a last-bit
# difference, so the same settings and seeds give other per-seed returns on another CPU kind.
VECTOR_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512bw", "avx512_bf16", "amx_tile")


def cpu_info(cpuinfo: str = "/proc/cpuinfo") -> dict:
    """``{"model", "vector_flags"}`` of this machine's CPU from Linux's ``/proc/cpuinfo``
    (elsewhere: ``platform.processor()`` and no flags)."""
    model, flags = None, set()
    try:
        with open(cpuinfo) as f:
            for line in f:
                key, _, value = line.partition(":")
                if key.strip() == "model name" and model is None:
                    model = value.strip()
                elif key.strip() == "flags":
                    flags = set(value.split())
                    break
    except OSError:
        pass
    return {
        "model": model or platform.processor() or None,
        "vector_flags": [f for f in VECTOR_FLAGS if f in flags],
    }


def device_info() -> dict:
    """The JAX backend, device count and device kinds of this process."""
    devices = jax.devices()
    return {
        "backend": jax.default_backend(),
        "device_count": len(devices),
        "local_device_count": jax.local_device_count(),
        "process_count": jax.process_count(),
        "device_kinds": sorted({d.device_kind for d in devices}),
    }


def provenance() -> dict:
    """Everything above in one JSON-ready dict, with the UTC time it was taken."""
    return {
        "time_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "packages": package_versions(),
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "cpu": cpu_info(),
        **device_info(),
        "git": git_info(),
    }
