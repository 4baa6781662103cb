#!/usr/bin/env bash
# Set up a fresh machine and run the test suite (the README's test command).
#   - Debian's libosmesa6 for off-screen rendering tests (installed when running as root);
#   - a virtual environment in .venv with the pinned dependencies and the dev extras;
#   - ruff (format and lint) and import-linter (the one-way layers of pyproject.toml);
#   - pytest on both cores.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! ldconfig -p 2>/dev/null | grep -q libOSMesa; then
  if [ "$(id -u)" = 0 ]; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libosmesa6 >/dev/null) \
      || echo "warning: could not install libosmesa6; rendering tests will be skipped"
  else
    echo "note: install Debian's libosmesa6 (sudo apt-get install libosmesa6) to run the rendering tests"
  fi
fi
[ -x .venv/bin/python ] || python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[dev]"
# Style and architecture first: seconds, and a failure names the file and line.
.venv/bin/ruff format --check .
.venv/bin/ruff check .
.venv/bin/lint-imports
export JAX_PLATFORMS="${JAX_PLATFORMS:-cpu}"
# MUJOCO_GL: tests/conftest.py picks osmesa where libOSMesa is installed (and test subprocesses
# inherit it); without the library it stays unset, so only the rendering tests skip.
# Whole modules per worker (module fixtures compile once), slow modules first (tests/conftest.py).
exec .venv/bin/python -m pytest -n 2 --dist loadfile --no-loadscope-reorder --durations=15 "$@"
