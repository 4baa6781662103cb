"""The paper's claims of §5 checked against measured results, each with a verdict.

A claim compares per-seed values of SCORE with those of other rows (algorithms or ablations).
Each comparison is the probability of improvement ``P(X > Y)`` (Agarwal et al. 2021,
``stats.probability_of_improvement``) with its 95% bootstrap interval; a claim is

- ``reproduced`` when every comparison it makes has its interval above 0.5,
- ``not reproduced`` when at least one has its interval below 0.5 (the other side wins),
- ``inconclusive`` otherwise (some interval covers 0.5: more seeds could tell), and always when
  either side has fewer than ``MIN_SEEDS`` seeds (a bootstrap of two values is no interval).

The claims (§5.2-§5.4, the conclusion):

- ``effectiveness``: SCORE's final return on the full space beats every baseline's;
- ``robustness``: SCORE keeps a larger share of its full-space return than every baseline when
  the most sub-spaces fail (default-value completion, the realistic mode of §5.3.3);
- ``transfer``: on unseen sub-spaces SCORE starts (Initial) and ends (Converge) above every
  baseline;
- ``ablation``: full SCORE (ASRL+AL+HN) beats every ablation, and removing ASRL costs more
  than removing the hypernetwork (``ASRL+AL`` beats ``AL+HN``).

Inputs are the ``rows`` of ``benchmarks/compare.py``'s result (``{label: {"full": {...},
"initial": {...}, "converge": {...}}}`` with ``per_seed`` lists) and robustness sweeps
(``robustness.json`` of each row's run) by label.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from score_jax.evaluation.stats import probability_of_improvement

REPRODUCED, NOT_REPRODUCED, INCONCLUSIVE, MISSING = (
    "reproduced",
    "not reproduced",
    "inconclusive",
    "not measured",
)
SCORE = "SCORE"
MIN_SEEDS = 3
ABLATION_PREFIXES = ("ASRL", "AL", "MF", "SF")


def is_ablation(label: str) -> bool:
    """Whether a compare.py row label names a SCORE ablation (``ASRL+MF+HN``, ``AL+HN``, ...,
    and ``ASRL(eq.2)``, the paper page's eq. 2 row)."""
    return label != SCORE and label.split("+")[0].split("(")[0] in ABLATION_PREFIXES


def comparison(x: Sequence[float], y: Sequence[float], x_label: str, y_label: str) -> dict:
    """``P(x > y)`` over seeds with its 95% interval and the verdict of that one comparison."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    point, (lo, hi) = probability_of_improvement(x, y, reps=5_000)
    verdict = REPRODUCED if lo > 0.5 else NOT_REPRODUCED if hi < 0.5 else INCONCLUSIVE
    if min(len(x), len(y)) < MIN_SEEDS:
        verdict = INCONCLUSIVE
    return {
        "x": x_label,
        "y": y_label,
        "p": float(point),
        "lo": float(lo),
        "hi": float(hi),
        "x_mean": float(x.mean()),
        "y_mean": float(y.mean()),
        "verdict": verdict,
    }


def combine(comparisons: Sequence[dict]) -> str:
    """A claim's verdict from its comparisons (see the module docstring)."""
    if not comparisons:
        return MISSING
    verdicts = {c["verdict"] for c in comparisons}
    if NOT_REPRODUCED in verdicts:
        return NOT_REPRODUCED
    return REPRODUCED if verdicts == {REPRODUCED} else INCONCLUSIVE


def _per_seed(rows: Mapping[str, dict], label: str, part: str) -> list[float] | None:
    entry = rows.get(label, {}).get(part)
    return None if not entry else entry.get("per_seed")


def retained_share(robustness: dict, mode: str = "default") -> np.ndarray:
    """Per trained seed, the return with the most sub-spaces failed as a share of the return
    with none: ``per_trained_seed_mean [K, counts, modes]`` -> ``[K]``. One-seed sweeps
    (no per-seed table) give their pooled mean as one value."""
    j = list(robustness["modes"]).index(mode)
    per_seed = robustness.get("per_trained_seed_mean")
    table = (
        np.asarray(per_seed, float)[:, :, j]
        if per_seed is not None
        else np.asarray(robustness["mean"], float)[None, :, j]
    )
    full = table[:, 0]
    if np.any(full <= 0):
        raise ValueError("retained_share needs positive full-space returns")
    return table[:, -1] / full


def check_claims(rows: Mapping[str, dict], robustness: Mapping[str, dict] | None = None) -> list:
    """Every claim of the module docstring for one environment: a list of
    ``{"claim", "statement", "verdict", "comparisons": [comparison(...)], "note"}``."""
    robustness = robustness or {}
    baselines = [k for k in rows if k != SCORE and not is_ablation(k) and "-" not in k]
    ablations = [k for k in rows if is_ablation(k)]
    out = []

    def claim(name, statement, comps, note=""):
        out.append(
            {
                "claim": name,
                "statement": statement,
                "verdict": combine(comps),
                "comparisons": comps,
                "note": note,
            }
        )

    score_full = _per_seed(rows, SCORE, "full")
    comps = [
        comparison(score_full, _per_seed(rows, b, "full"), SCORE, b)
        for b in baselines
        if score_full and _per_seed(rows, b, "full")
    ]
    claim(
        "effectiveness",
        "SCORE's final return on the full space beats every baseline's (Figs. 6a/8a)",
        comps,
    )

    comps, note = [], ""
    if SCORE in robustness:
        try:
            mine = retained_share(robustness[SCORE])
            comps = [
                comparison(mine, retained_share(robustness[b]), SCORE, b)
                for b in baselines
                if b in robustness
            ]
        except ValueError as e:
            note = str(e)
    claim(
        "robustness",
        "SCORE keeps the largest share of its full-space return when the most sub-spaces fail "
        "(default-value completion; Figs. 7/9)",
        comps,
        note,
    )

    comps = []
    for part in ("initial", "converge"):
        mine = _per_seed(rows, SCORE, part)
        comps += [
            comparison(mine, _per_seed(rows, b, part), f"{SCORE} {part}", f"{b} {part}")
            for b in [k for k in rows if k != SCORE and not is_ablation(k)]
            if mine and _per_seed(rows, b, part)
        ]
    claim(
        "transfer",
        "On unseen sub-spaces SCORE starts and ends above every baseline and variant "
        "(Figs. 6b/8b, Table 3)",
        comps,
    )

    comps = [
        comparison(score_full, _per_seed(rows, a, "full"), SCORE, a)
        for a in ablations
        if score_full and _per_seed(rows, a, "full")
    ]
    no_hn, no_asrl = _per_seed(rows, "ASRL+AL", "full"), _per_seed(rows, "AL+HN", "full")
    if no_hn and no_asrl:
        comps.append(comparison(no_hn, no_asrl, "ASRL+AL", "AL+HN"))
    claim(
        "ablation",
        "Full SCORE beats every ablation, and removing ASRL costs more than removing the "
        "hypernetwork (Table 2)",
        comps,
    )
    return out


def claims_markdown(claims: Sequence[dict]) -> str:
    """The claims as a Markdown table: claim, verdict, and each comparison's P(X > Y) [95% CI]
    with the two means."""
    lines = [
        "| claim | verdict | comparisons: P(X > Y) [95% CI] (mean X vs mean Y) |",
        "|---|---|---|",
    ]
    for c in claims:
        comps = "; ".join(
            f"{d['x']} > {d['y']}: {d['p']:.2f} [{d['lo']:.2f}, {d['hi']:.2f}] "
            f"({d['x_mean']:.1f} vs {d['y_mean']:.1f})"
            for d in c["comparisons"]
        )
        comps = comps or (c["note"] or "—")
        lines.append(f"| {c['claim']}: {c['statement']} | **{c['verdict']}** | {comps} |")
    return "\n".join(lines)
