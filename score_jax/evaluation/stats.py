"""Aggregate statistics of RL results over seeds, as in Agarwal et al. 2021 ("Deep RL at the
edge of the statistical precipice"): IQM, mean, median and optimality gap with stratified
bootstrap confidence intervals, probability of improvement and performance profiles.

Why not the ``rliable`` package itself: rliable 1.2.0 (the current release) installs cleanly
with the pinned set and ``pip check`` passes, but ``import rliable.library`` fails. rliable
requires ``arch<8.0``; arch 7.2.0 (the newest allowed) calls pandas' private
``deprecate_kwarg`` with the pandas-2 signature and raises ``TypeError`` at import under pandas
3.x, which is what this project resolves (pvlib pulls pandas; arch 8.0.0 supports pandas 3 but
rliable excludes it). Using rliable would mean pinning ``pandas<3`` for everyone, so the
estimators are re-implemented here with rliable's definitions (``rliable.metrics``) and the
bootstrap is ``scipy.stats.bootstrap``. rliable's bootstrap resamples runs independently
within each task (its ``StratifiedBootstrap`` without task bootstrap) and takes percentile
intervals; ``scipy.stats.bootstrap`` with one sample per task and ``paired=False`` resamples
each sample independently, which is the same scheme, and ``method="percentile"`` is used.

Scores are ``[num_runs]`` (one task) or ``[num_runs, num_tasks]`` arrays of final scores, one
row per seed. Definitions (as in ``rliable.metrics``):

- IQM: ``scipy.stats.trim_mean(scores, 0.25, axis=None)``, over all runs and tasks together.
- mean: the mean over tasks of the per-task mean over runs.
- median: the median over tasks of the per-task mean over runs. With a single task that is
  the mean over runs, so for one task this module reports the median over runs instead.
- optimality gap at ``gamma``: ``gamma - mean(min(scores, gamma))``, lower is better.
- probability of improvement ``P(X > Y)``: per task, the Mann-Whitney U statistic of X against
  Y over ``num_runs_x * num_runs_y`` (ties count one half), averaged over tasks.
- performance profile at ``tau``: the fraction of all runs and tasks with a score above tau.

Small numbers of runs (N = num_runs * num_tasks scores in total):

- ``trim_mean`` cuts ``int(0.25 * N)`` scores from each end, so for N < 4 nothing is cut and
  the IQM equals the mean (rliable does exactly this and does not warn); for N = 4 it is the
  mean of the middle two.
- With one run the bootstrap has nothing to resample: the interval is ``lo == hi == value``
  and ``Interval.degenerate`` is True (rliable returns the same interval, unmarked).
- With two to four runs the percentile interval is close to the range of the runs and covers
  the true value less often than its nominal level; report ``n`` next to it.

Every bootstrap draws from ``numpy.random.default_rng`` seeded from ``seed`` (and, in
``aggregate``, the algorithm's name), so results are deterministic for a seed and an
algorithm's interval does not depend on which other algorithms are aggregated with it.
"""

from __future__ import annotations

import dataclasses
import zlib
from collections.abc import Callable, Mapping, Sequence

import numpy as np
import scipy.stats

DEFAULT_REPS = 50_000  # rliable's default for interval estimates
PROFILE_REPS = 2_000  # rliable's default for performance profiles
CONFIDENCE = 0.95
_BATCH_ELEMENTS = 4_000_000  # intermediate elements per vectorised batch of resamples

Statistic = Callable[[np.ndarray], np.ndarray]
ProfileResult = tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]


@dataclasses.dataclass(frozen=True)
class Interval:
    """A point estimate and its confidence interval; ``degenerate`` when it came from a single
    run, so that ``lo == hi == value`` is not a real interval."""

    value: float
    lo: float
    hi: float
    degenerate: bool = False


@dataclasses.dataclass(frozen=True)
class Aggregate:
    """Aggregate metrics of one algorithm over its runs.

    ``scores`` holds the raw final scores ``[n, num_tasks]`` (read-only); ``per_seed`` their
    mean over tasks ``[n]``. ``optimality_gap`` is None unless a threshold was given.
    """

    name: str
    n: int
    num_tasks: int
    iqm: Interval
    mean: Interval
    median: Interval
    optimality_gap: Interval | None
    scores: np.ndarray = dataclasses.field(compare=False, repr=False)
    confidence: float = CONFIDENCE
    reps: int = DEFAULT_REPS

    @property
    def per_seed(self) -> np.ndarray:
        """Per-run score ``[n]`` (the mean over tasks)."""
        return self.scores.mean(axis=1)

    @property
    def degenerate(self) -> bool:
        """True for a single run: the intervals are points."""
        return self.n == 1

    def metric(self, name: str) -> Interval:
        """One of ``iqm``, ``mean``, ``median``, ``optimality_gap`` by name."""
        if name not in METRICS:
            raise ValueError(f"unknown metric {name!r}; known: {', '.join(METRICS)}")
        value = getattr(self, name)
        if value is None:
            raise ValueError(f"{self.name!r} has no {name}: pass optimality_threshold")
        return value


METRICS = ("iqm", "mean", "median", "optimality_gap")
_LABELS = {"iqm": "IQM", "mean": "mean", "median": "median", "optimality_gap": "optimality gap"}


# --- input checks -----------------------------------------------------------------------------


def as_score_matrix(name: str, scores: np.ndarray | Sequence[float]) -> np.ndarray:
    """Validate one algorithm's scores; returns a float64 ``[num_runs, num_tasks]`` copy.

    Raises ValueError naming the algorithm for an empty array, more than two dimensions, or a
    NaN or infinite score.
    """
    x = np.array(scores, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2:
        raise ValueError(
            f"scores for {name!r} must be [num_runs] or [num_runs, num_tasks], got {x.shape}"
        )
    if x.size == 0:
        raise ValueError(f"scores for {name!r} are empty (shape {x.shape})")
    bad = ~np.isfinite(x)
    if bad.any():
        runs = sorted(set(np.nonzero(bad)[0].tolist()))
        kind = "NaN" if np.isnan(x).any() else "infinite"
        raise ValueError(
            f"scores for {name!r} contain {kind} values (runs {runs}); "
            "drop or fix those runs before aggregating"
        )
    x.setflags(write=False)
    return x


def _check_confidence(confidence: float) -> None:
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")


def _name_rng(seed: int, name: str) -> np.random.Generator:
    """A generator from ``seed`` and a stable hash of ``name``."""
    return np.random.default_rng([seed, zlib.crc32(name.encode())])


# --- estimators on [..., runs, tasks] -----------------------------------------------------------


def _iqm(s: np.ndarray) -> np.ndarray:
    """Interquartile mean over runs and tasks: ``[..., runs, tasks] -> [...]``."""
    return scipy.stats.trim_mean(s.reshape(*s.shape[:-2], -1), 0.25, axis=-1)


def _mean(s: np.ndarray) -> np.ndarray:
    """Mean over tasks of per-task means: ``[..., runs, tasks] -> [...]``."""
    return s.mean(axis=-2).mean(axis=-1)


def _median(s: np.ndarray) -> np.ndarray:
    """Median over tasks of per-task means; over runs when there is one task."""
    if s.shape[-1] == 1:
        return np.median(s[..., 0], axis=-1)
    return np.median(s.mean(axis=-2), axis=-1)


def _optimality_gap(s: np.ndarray, gamma: float) -> np.ndarray:
    """``gamma`` minus the mean score clipped at ``gamma``: ``[..., runs, tasks] -> [...]``."""
    return gamma - np.minimum(s, gamma).mean(axis=(-2, -1))


def _improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """P(X > Y) + P(X = Y) / 2 over all pairs of runs: ``[..., nx], [..., ny] -> [...]``."""
    xs, ys = x[..., :, None], y[..., None, :]
    return (xs > ys).mean(axis=(-2, -1)) + 0.5 * (xs == ys).mean(axis=(-2, -1))


# --- bootstrap --------------------------------------------------------------------------------


def _percentile_ci(
    samples: Sequence[np.ndarray],
    statistic: Callable[..., np.ndarray],
    reps: int,
    rng: np.random.Generator,
    confidence: float,
    per_resample: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Percentile bootstrap interval, each 1-D sample resampled independently.

    ``statistic(*resampled)`` gets arrays ``[batch, len(sample)]`` and returns ``[k, batch]``;
    the result is ``(lo [k], hi [k])``. ``per_resample`` is the size of the statistic's largest
    intermediate per resample; it sets the batch (and so depends only on shapes).
    """
    batch = max(1, min(reps, _BATCH_ELEMENTS // max(1, per_resample)))

    def stat(*resampled: np.ndarray, axis: int = -1) -> np.ndarray:
        assert axis == -1
        return statistic(*resampled)

    res = scipy.stats.bootstrap(
        tuple(samples),
        stat,
        n_resamples=reps,
        batch=batch,
        vectorized=True,
        paired=False,
        axis=-1,
        confidence_level=confidence,
        method="percentile",
        rng=rng,
    )
    return np.atleast_1d(res.confidence_interval.low), np.atleast_1d(res.confidence_interval.high)


def stratified_ci(
    scores: np.ndarray,
    statistic: Statistic,
    reps: int,
    rng: np.random.Generator,
    confidence: float = CONFIDENCE,
    per_score: int = 4,
) -> tuple[np.ndarray, np.ndarray]:
    """Stratified bootstrap interval of ``statistic`` (runs resampled within each task).

    ``scores``: ``[num_runs >= 2, num_tasks]``; ``statistic``: ``[..., runs, tasks] -> [k, ...]``
    using about ``per_score`` intermediate elements per score. Returns ``(lo [k], hi [k])``.
    """
    columns = [scores[:, j] for j in range(scores.shape[1])]
    return _percentile_ci(
        columns,
        lambda *cols: statistic(np.stack(cols, axis=-1)),
        reps,
        rng,
        confidence,
        per_resample=scores.size * per_score,
    )


# --- public API -------------------------------------------------------------------------------


def _point_metrics(gamma: float | None) -> Statistic:
    """``[..., runs, tasks] -> [k, ...]`` with k = 3 (IQM, mean, median) or 4 (+ gap)."""

    def fn(s: np.ndarray) -> np.ndarray:
        out = [_iqm(s), _mean(s), _median(s)]
        if gamma is not None:
            out.append(_optimality_gap(s, gamma))
        return np.stack(out, axis=0)

    return fn


def aggregate_one(
    name: str,
    scores: np.ndarray | Sequence[float],
    reps: int = DEFAULT_REPS,
    seed: int = 0,
    confidence: float = CONFIDENCE,
    optimality_threshold: float | None = None,
) -> Aggregate:
    """IQM, mean, median (and optimality gap) of one algorithm's ``[num_runs(, num_tasks)]``
    scores with stratified bootstrap intervals; see ``aggregate``."""
    _check_confidence(confidence)
    s = as_score_matrix(name, scores)
    fn = _point_metrics(optimality_threshold)
    point = fn(s)
    n = s.shape[0]
    if n == 1:
        lo, hi = point, point
    else:
        lo, hi = stratified_ci(s, fn, reps, _name_rng(seed, name), confidence)
    iv = [
        Interval(float(p), float(a), float(b), n == 1)
        for p, a, b in zip(point, lo, hi, strict=True)
    ]
    return Aggregate(
        name=name,
        n=n,
        num_tasks=s.shape[1],
        iqm=iv[0],
        mean=iv[1],
        median=iv[2],
        optimality_gap=iv[3] if optimality_threshold is not None else None,
        scores=s,
        confidence=confidence,
        reps=reps,
    )


def aggregate(
    scores: Mapping[str, np.ndarray | Sequence[float]],
    reps: int = DEFAULT_REPS,
    seed: int = 0,
    confidence: float = CONFIDENCE,
    optimality_threshold: float | None = None,
) -> dict[str, Aggregate]:
    """Aggregate metrics with stratified bootstrap confidence intervals per algorithm.

    ``scores[name]`` is ``[num_runs]`` or ``[num_runs, num_tasks]`` of final scores (one row per
    seed). ``reps`` bootstrap resamples, percentile intervals at ``confidence``; the optimality
    gap is computed when ``optimality_threshold`` is given. Deterministic for ``seed``.
    Raises ValueError naming the algorithm for NaN/infinite or empty scores.
    """
    return {
        name: aggregate_one(name, s, reps, seed, confidence, optimality_threshold)
        for name, s in scores.items()
    }


def probability_of_improvement(
    x: np.ndarray | Sequence[float],
    y: np.ndarray | Sequence[float],
    reps: int = DEFAULT_REPS,
    seed: int = 0,
    confidence: float = CONFIDENCE,
    names: tuple[str, str] = ("x", "y"),
) -> tuple[float, tuple[float, float]]:
    """P(X > Y) of algorithm X over Y averaged over tasks, with its stratified bootstrap interval
    (the runs of X and of Y resampled independently within each task).

    ``x``: ``[num_runs_x(, num_tasks)]``, ``y``: ``[num_runs_y(, num_tasks)]``; the run counts may
    differ, the task counts must match. Returns ``(point, (lo, hi))``; with one run each the
    interval is the point. ``names`` label the arrays in error messages.
    """
    _check_confidence(confidence)
    sx, sy = as_score_matrix(names[0], x), as_score_matrix(names[1], y)
    if sx.shape[1] != sy.shape[1]:
        raise ValueError(
            f"{names[0]!r} has {sx.shape[1]} tasks and {names[1]!r} {sy.shape[1]}; they must match"
        )
    tasks = sx.shape[1]

    def stat(*cols: np.ndarray) -> np.ndarray:
        per_task = [_improvement(cols[j], cols[tasks + j]) for j in range(tasks)]
        return np.mean(per_task, axis=0)[None]

    point = float(stat(*sx.T, *sy.T)[0])
    if sx.shape[0] == 1 and sy.shape[0] == 1:
        return point, (point, point)
    # scipy resamples only samples of two or more; a duplicated single run resamples to itself
    # and leaves the pairwise proportions unchanged.
    sx, sy = (np.repeat(s, 2, axis=0) if s.shape[0] == 1 else s for s in (sx, sy))
    lo, hi = _percentile_ci(
        [*sx.T, *sy.T],
        stat,
        reps,
        np.random.default_rng(seed),
        confidence,
        per_resample=2 * tasks * sx.shape[0] * sy.shape[0],
    )
    return point, (float(lo[0]), float(hi[0]))


def performance_profile(
    scores: Mapping[str, np.ndarray | Sequence[float]],
    taus: np.ndarray | Sequence[float],
    reps: int = PROFILE_REPS,
    seed: int = 0,
    confidence: float = CONFIDENCE,
) -> dict[str, ProfileResult]:
    """Score distribution (fraction of runs x tasks with score > tau) per algorithm.

    ``taus``: ``[num_taus]``. Returns ``{name: (profile [num_taus], (lo [num_taus],
    hi [num_taus]))}`` with stratified bootstrap intervals; for ascending taus the profile is
    non-increasing.
    """
    _check_confidence(confidence)
    t = np.asarray(taus, dtype=np.float64).reshape(-1)

    def fn(s: np.ndarray) -> np.ndarray:  # [..., runs, tasks] -> [taus, ...]
        above = s[..., None] > t
        return np.moveaxis(above.mean(axis=(-3, -2)), -1, 0)

    out: dict[str, ProfileResult] = {}
    for name, raw in scores.items():
        s = as_score_matrix(name, raw)
        profile = fn(s)
        if s.shape[0] == 1:
            out[name] = (profile, (profile.copy(), profile.copy()))
            continue
        lo, hi = stratified_ci(s, fn, reps, _name_rng(seed, name), confidence, per_score=t.size)
        out[name] = (profile, (lo, hi))
    return out


# --- formatting -------------------------------------------------------------------------------


def format_interval(value: float, lo: float, hi: float, digits: int = 1) -> str:
    """``"903.2 [871.0, 944.9]"``."""
    return f"{value:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def format_estimate(iv: Interval, digits: int = 1) -> str:
    """``format_interval`` of an Interval; a degenerate one reads ``"903.2 (n=1, no CI)"``."""
    if iv.degenerate:
        return f"{iv.value:.{digits}f} (n=1, no CI)"
    return format_interval(iv.value, iv.lo, iv.hi, digits)


def markdown_table(
    aggregates: Mapping[str, Aggregate], metric: str = "iqm", digits: int = 1
) -> str:
    """A Markdown table, one row per algorithm, best first by ``metric`` (higher is better,
    lower for the optimality gap): IQM, mean and median with their intervals (and the
    optimality gap when computed), n, and the per-seed values (means over tasks)."""
    aggs = list(aggregates.values())
    if not aggs:
        raise ValueError("no aggregates to tabulate")
    for a in aggs:
        a.metric(metric)  # validates the name and that it was computed
    sign = 1.0 if metric == "optimality_gap" else -1.0
    aggs.sort(key=lambda a: sign * a.metric(metric).value)
    cols = ["iqm", "mean", "median"]
    if all(a.optimality_gap is not None for a in aggs):
        cols.append("optimality_gap")
    pct = ", ".join(sorted({f"{100 * a.confidence:g}%" for a in aggs}))
    per_seed = "per-seed" if all(a.num_tasks == 1 for a in aggs) else "per-seed (task mean)"
    header = ["algorithm", *(f"{_LABELS[c]} [{pct} CI]" for c in cols), "n", per_seed]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for a in aggs:
        seeds = ", ".join(f"{v:.{digits}f}" for v in a.per_seed)
        cells = [a.name, *(format_estimate(a.metric(c), digits) for c in cols), str(a.n), seeds]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


# --- plots ------------------------------------------------------------------------------------


def new_figure(width: float, height: float):
    """A matplotlib Figure with the Agg canvas (no pyplot, the global backend untouched)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def plot_interval_estimates(
    aggregates: Mapping[str, Aggregate],
    path: str,
    metrics: Sequence[str] = ("iqm", "mean", "median"),
    xlabel: str = "score",
) -> None:
    """One panel per metric, one horizontal bar per algorithm spanning its interval with a tick
    at the point estimate (rliable's ``plot_interval_estimates`` layout), a diamond alone for a
    single run; written to ``path``."""
    names = list(aggregates)
    if not names:
        raise ValueError("no aggregates to plot")
    fig = new_figure(2.6 * len(metrics) + 1.0, 0.45 * len(names) + 1.2)
    axes = fig.subplots(1, len(metrics), sharey=True, squeeze=False)[0]
    colors = [f"C{i % 10}" for i in range(len(names))]
    for ax, metric in zip(axes, metrics, strict=True):
        ivs = [aggregates[name].metric(metric) for name in names]
        left, right = min(iv.lo for iv in ivs), max(iv.hi for iv in ivs)
        pad = 0.08 * (right - left) or 0.5  # bars' sticky edges defeat ax.margins
        ax.set_xlim(left - pad, right + pad)
        for i, name in enumerate(names):
            iv = aggregates[name].metric(metric)
            ax.barh(i, iv.hi - iv.lo, left=iv.lo, height=0.6, color=colors[i], alpha=0.75)
            ax.vlines(iv.value, i - 0.3, i + 0.3, color="k", linewidth=1.5)
            if iv.degenerate:
                ax.plot(iv.value, i, marker="D", color=colors[i], markeredgecolor="k")
        ax.set_title(_LABELS[metric])
        ax.set_xlabel(xlabel)
        ax.grid(axis="x", alpha=0.3)
    axes[0].set_yticks(range(len(names)), names)
    axes[0].invert_yaxis()
    fig.savefig(path, dpi=120)


def plot_performance_profiles(
    profiles: Mapping[str, ProfileResult],
    taus: np.ndarray | Sequence[float],
    path: str,
    xlabel: str = r"score $\tau$",
    title: str = "",
) -> None:
    """Performance profiles (``performance_profile``'s output) with shaded intervals against
    ``taus`` ``[num_taus]``; written to ``path``."""
    t = np.asarray(taus, dtype=np.float64).reshape(-1)
    fig = new_figure(5.0, 3.5)
    ax = fig.subplots()
    for i, (name, (profile, (lo, hi))) in enumerate(profiles.items()):
        ax.plot(t, profile, color=f"C{i % 10}", label=name)
        ax.fill_between(t, lo, hi, color=f"C{i % 10}", alpha=0.2, linewidth=0)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(r"fraction of runs with score $> \tau$")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    if title:
        ax.set_title(title)
    ax.legend(frameon=False)
    fig.savefig(path, dpi=120)
