"""Training stability per seed: does the training return collapse after it has been good?

A learning curve that climbs past a reference and then falls far below it (a "collapse") is
what a mean over seeds hides. For each seed, take the moving mean of the training episode
return (``metrics.csv``'s ``episode_return``, the same smoothing as the learning-curve plot),
find the first point where it exceeds ``threshold`` (the report uses the default setpoints'
return) and report the lowest moving mean from there on. A seed "held" when that lowest value
stays above the threshold; a seed that never exceeded it has no value.
"""

from __future__ import annotations

import numpy as np

from score_jax.evaluation.curves import read_rows, seed_curves


def lowest_after_exceeding(csv_path: str, threshold: float) -> dict[int, dict]:
    """``seed -> {"first_above": env step or None, "lowest_after": value or None,
    "lowest_at": env step or None, "held": bool}`` (see the module docstring)."""
    out = {}
    for seed, (steps, values) in seed_curves(read_rows(csv_path), "episode_return", True).items():
        above = np.flatnonzero(values > threshold)
        if not len(above):
            out[seed] = {"first_above": None, "lowest_after": None, "lowest_at": None}
            out[seed]["held"] = False
            continue
        i = int(above[0])
        j = i + int(np.argmin(values[i:]))
        out[seed] = {
            "first_above": float(steps[i]),
            "lowest_after": float(values[j]),
            "lowest_at": float(steps[j]),
            "held": bool(values[j] > threshold),
        }
    return out


def format_stability(stability: dict[int, dict], threshold: float, name: str) -> str:
    """One line per seed, for the end-of-run report."""
    lines = [
        f"training stability (moving-mean training return after it first exceeds {name}, "
        f"{threshold:.1f}):"
    ]
    for seed, s in stability.items():
        if s["first_above"] is None:
            lines.append(f"  seed {seed}: never above {name}")
            continue
        verdict = "held" if s["held"] else "fell below it"
        lines.append(
            f"  seed {seed}: above from step {s['first_above']:.0f}; lowest after "
            f"{s['lowest_after']:.1f} at step {s['lowest_at']:.0f} ({verdict})"
        )
    return "\n".join(lines)
