"""Learning curves over seeds: every seed faint, the mean over seeds with its 95% interval."""

from __future__ import annotations

import csv
import math

import numpy as np

# Moving-mean windows keep the curves readable: about this many points per run.
CURVE_POINTS = 20


def read_rows(csv_path: str) -> list[dict]:
    with open(csv_path) as f:
        return list(csv.DictReader(f))


def seed_curves(
    rows: list[dict], column: str, smooth: bool
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """``seed -> (steps, values)`` of ``column`` (NaN rows dropped); a moving mean when
    ``smooth``."""
    out = {}
    seeds = sorted({int(float(r.get("seed", 0) or 0)) for r in rows})
    for seed in seeds:
        mine = [r for r in rows if int(float(r.get("seed", 0) or 0)) == seed and r[column] != "nan"]
        steps = np.array([float(r["env_steps"]) for r in mine])
        values = np.array([float(r[column]) for r in mine])
        if smooth and len(values):
            w = max(1, len(values) // CURVE_POINTS)
            values = np.convolve(values, np.ones(w) / w, mode="valid")
            steps = steps[w - 1 :]
        if len(values):
            out[seed] = (steps, values)
    return out


def t_interval(stack: np.ndarray):
    """``(mean, lo, hi)`` over axis 0 of ``stack [n, ...]``: the 95% interval is Student's t
    over the n rows (``lo`` and ``hi`` None for one row)."""
    stack = np.asarray(stack, float)
    mean = stack.mean(0)
    n = stack.shape[0]
    if n < 2:
        return mean, None, None
    from scipy import stats as scipy_stats  # deferred: scipy.stats imports slowly

    half = scipy_stats.t.ppf(0.975, n - 1) * stack.std(0, ddof=1) / math.sqrt(n)
    return mean, mean - half, mean + half


def mean_and_interval(curves: dict[int, tuple[np.ndarray, np.ndarray]]):
    """``(steps, mean, lo, hi)`` over seeds on a common step grid (each seed interpolated onto
    the steps all of them cover); the 95% interval is Student's t over seeds (None for one seed)."""
    if not curves:
        return None
    start = max(s[0] for s, _ in curves.values())
    end = min(s[-1] for s, _ in curves.values())
    grid = np.unique(np.concatenate([s[(s >= start) & (s <= end)] for s, _ in curves.values()]))
    if not len(grid):
        return None
    stack = np.stack([np.interp(grid, s, v) for s, v in curves.values()])
    return (grid, *t_interval(stack))


def plot_band(
    ax,
    curves,
    label: str,
    colour,
    marker: str = "-",
    band_label: str | None = "95% interval over seeds",
) -> None:
    """``curves`` (``seed -> (steps, values)``) on ``ax``: every seed faint, the mean over seeds
    with its 95% interval (``band_label`` names the band in the legend; None leaves it out)."""
    for steps, values in curves.values():
        ax.plot(steps, values, marker, color=colour, alpha=0.25 if len(curves) > 1 else 0.9, lw=1)
    summary = mean_and_interval(curves)
    if summary is None or len(curves) < 2:
        if len(curves) == 1:
            ax.plot([], [], marker, color=colour, label=label)
        return
    grid, mean, lo, hi = summary
    ax.plot(grid, mean, "-", color=colour, lw=2.2, label=f"{label}, mean of {len(curves)} seeds")
    ax.fill_between(grid, lo, hi, color=colour, alpha=0.2, lw=0, label=band_label)


# Reference policies drawn as horizontal lines on a learning curve, when the report has them.
REFERENCE_LINES = ("random", "default", "expert", "best constant", "open-loop")


def plot_learning_curve(
    csv_path: str, png_path: str, title: str = "", references: dict | None = None
) -> None:
    """Training episodes' moving mean and deterministic evaluations against decisions: every seed
    faint, the mean over seeds with its 95% interval; ``references`` (``{name: return}``, e.g.
    the end-of-run report's default, expert and planned references) as dashed lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = read_rows(csv_path)
    fig, ax = plt.subplots(figsize=(9.5, 4))
    train = seed_curves(rows, "episode_return", smooth=True)
    if train:
        plot_band(ax, train, "training episodes (moving mean)", "tab:blue")
    evals = seed_curves(rows, "eval_return", smooth=False)
    if evals:
        plot_band(ax, evals, "evaluation (deterministic)", "tab:green", "o-")
    greys = plt.cm.Greys(np.linspace(0.35, 0.9, max(1, len(references or {}))))
    for colour, (name, value) in zip(greys, (references or {}).items(), strict=False):
        ax.axhline(value, ls="--", lw=1, color=colour, label=f"{name} ({value:.1f})")
    _save(fig, ax, png_path, title, "episode return")


def plot_curves(curves: dict[str, str], path: str, title: str) -> None:
    """Training-episode return against decisions for several metrics.csv files (Figs. 6b/8b):
    the mean over each file's seeds with its 95% interval; runs trained inside brax (sac, ppo,
    hppo) log no training episodes, so their evaluations are plotted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9.5, 4))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, (label, csv_path) in enumerate(curves.items()):
        rows = read_rows(csv_path)
        column = (
            "episode_return" if any(r["episode_return"] != "nan" for r in rows) else "eval_return"
        )
        per_seed = seed_curves(rows, column, smooth=column == "episode_return")
        name = label if column == "episode_return" else f"{label} (evaluations)"
        plot_band(ax, per_seed, name, colours[i % len(colours)])
    _save(fig, ax, path, title, "episode return (training episodes)")


def _save(fig, ax, path: str, title: str, ylabel: str) -> None:
    import matplotlib.pyplot as plt

    ax.set_xlabel("decisions (steps of the action-repeated env)")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    # outside the axes: with reference lines and seed bands inside there is no free corner
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
