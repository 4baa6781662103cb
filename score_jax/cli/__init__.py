"""The command-line entry points (console scripts of ``pyproject.toml``): ``score-train``,
``score-transfer``, ``score-robustness``, ``score-eval``. The top layer: each imports what it
needs from the layers below and turns every error a user can cause into one line."""
