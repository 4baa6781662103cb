"""evaluation/claims.py: verdicts follow the probability-of-improvement intervals."""

import numpy as np
import pytest

from score_jax.evaluation.claims import (
    INCONCLUSIVE,
    MISSING,
    NOT_REPRODUCED,
    REPRODUCED,
    check_claims,
    claims_markdown,
    is_ablation,
    retained_share,
)


def _row(full=None, initial=None, converge=None):
    out = {}
    for part, v in (("full", full), ("initial", initial), ("converge", converge)):
        if v is not None:
            out[part] = {"per_seed": list(map(float, v))}
    return out


def _sweep(per_seed_by_count):
    """robustness.json with one mode ('default') from ``[K, counts]``."""
    p = np.asarray(per_seed_by_count, float)[:, :, None]
    return {"modes": ["default"], "per_trained_seed_mean": p.tolist(), "mean": p.mean(0).tolist()}


def by_name(claims):
    return {c["claim"]: c for c in claims}


def test_labels_of_ablations():
    assert is_ablation("AL+HN") and is_ablation("ASRL+MF+HN") and is_ablation("ASRL+AL")
    assert is_ablation("ASRL(eq.2)")  # a variant of SCORE, not a baseline it must beat
    assert not is_ablation("SCORE") and not is_ablation("ISAC") and not is_ablation("PPO-mask")


def test_clear_wins_reproduce_clear_losses_refute_and_overlap_is_inconclusive():
    rows = {
        "SCORE": _row(full=[10, 11, 12, 13, 14], initial=[5, 6, 7, 8, 9], converge=[9, 9, 9, 9, 9]),
        "ISAC": _row(full=[1, 2, 3, 4, 5], initial=[1, 1, 1, 1, 1], converge=[20, 21, 22, 23, 24]),
        "PPO": _row(full=[0, 1, 2, 3, 4]),
        "ASRL+AL": _row(full=[10, 11, 12, 13, 14]),  # equal to SCORE: P = 0.5
        "AL+HN": _row(full=[1, 2, 3, 4, 5]),
    }
    robust = {
        "SCORE": _sweep([[10, 9], [12, 11], [14, 13]]),  # keeps about 90%
        "ISAC": _sweep([[10, 2], [12, 3], [14, 4]]),  # keeps about 25%
    }
    claims = by_name(check_claims(rows, robust))
    assert claims["effectiveness"]["verdict"] == REPRODUCED
    assert {c["y"] for c in claims["effectiveness"]["comparisons"]} == {"ISAC", "PPO"}
    assert claims["robustness"]["verdict"] == REPRODUCED
    assert claims["transfer"]["verdict"] == NOT_REPRODUCED  # ISAC converges higher
    assert claims["ablation"]["verdict"] == INCONCLUSIVE  # SCORE vs ASRL+AL is a tie
    last = claims["ablation"]["comparisons"][-1]
    assert (last["x"], last["y"], last["verdict"]) == ("ASRL+AL", "AL+HN", REPRODUCED)
    md = claims_markdown(list(claims.values()))
    assert "**not reproduced**" in md and "SCORE > ISAC: 1.00" in md


def test_fewer_than_three_seeds_decide_nothing():
    rows = {"SCORE": _row(full=[10, 11]), "ISAC": _row(full=[1, 2])}
    claims = by_name(check_claims(rows))
    assert claims["effectiveness"]["comparisons"][0]["p"] == 1.0
    assert claims["effectiveness"]["verdict"] == INCONCLUSIVE


def test_what_was_not_run_is_not_measured():
    claims = by_name(check_claims({"SCORE": _row(full=[1, 2, 3])}))
    assert {c["verdict"] for c in claims.values()} == {MISSING}


def test_retained_share_is_per_trained_seed_and_needs_positive_returns():
    np.testing.assert_allclose(retained_share(_sweep([[10, 5, 2], [4, 4, 4]])), [0.2, 1.0])
    with pytest.raises(ValueError, match="positive"):
        retained_share(_sweep([[0, 1]]))
