"""Descriptive statistics and the paired test shared by the questionnaires.

Choices, stated once:
- Median and IQR suit Likert answers. Quartiles use numpy's default (linear interpolation, Hyndman-Fan type 7);
  IQR = Q3 - Q1. Mean, SD (n - 1) and a t-based 95 % CI of the mean are reported too, for the interval scores
  (SUS, TLX, Godspeed series means).
- Paired test: scipy.stats.wilcoxon, two-sided, on perceived - expected. Pairs with a zero difference are dropped
  (zero_method="wilcox", Wilcoxon's original rule), so the test is run only when at least `min_nonzero`
  non-zero differences remain. The default of 6 is the smallest n for which the exact two-sided test can reach
  p < .05 at all (its smallest p is 2 / 2**n: 0.0625 for n = 5, 0.031 for n = 6).
- Effect size: the matched-pairs rank-biserial correlation r = (R+ - R-) / (R+ + R-), with R+ and R- the sums of
  the ranks of |d| for positive and negative differences (Kerby, 2014). It runs from -1 (every rater lower when
  perceived) to +1 (every rater higher), needs no normal approximation, and so stays meaningful for the small,
  tie-heavy samples Likert data give. (r = Z / sqrt(n) is the other common choice; it is not used here.)
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence

import numpy as np
from pydantic import BaseModel
from scipy import stats

DEFAULT_MIN_NONZERO = 6


class Describe(BaseModel):
    """Summary of one set of answers; None where a statistic needs more data than there is."""

    n: int
    missing: int
    median: float | None = None
    q1: float | None = None
    q3: float | None = None
    iqr: float | None = None
    mean: float | None = None
    sd: float | None = None
    ci95_low: float | None = None
    ci95_high: float | None = None
    min: float | None = None
    max: float | None = None


def describe(values: Sequence[float | None]) -> Describe:
    present = np.array([v for v in values if v is not None], dtype=float)
    missing = len(values) - present.size
    if present.size == 0:
        return Describe(n=0, missing=missing)
    q1, median, q3 = (float(q) for q in np.percentile(present, [25, 50, 75]))
    mean = float(present.mean())
    result = Describe(n=int(present.size), missing=missing, median=median, q1=q1, q3=q3, iqr=q3 - q1,
                      mean=mean, min=float(present.min()), max=float(present.max()))
    if present.size >= 2:
        sd = float(present.std(ddof=1))
        result.sd = sd
        half = float(stats.t.ppf(0.975, present.size - 1)) * sd / math.sqrt(present.size)
        result.ci95_low, result.ci95_high = mean - half, mean + half
    return result


class PairedTest(BaseModel):
    """Wilcoxon signed-rank test of perceived against expected, or the plain reason it was not run."""

    n_pairs: int
    n_nonzero: int
    tested: bool
    statistic: float | None = None  # scipy's W: the smaller of R+ and R-
    p_value: float | None = None
    rank_biserial: float | None = None
    median_difference: float | None = None
    note: str = ""


def rank_biserial(differences: Sequence[float]) -> float | None:
    d = np.asarray([x for x in differences if x != 0], dtype=float)
    if d.size == 0:
        return None
    ranks = stats.rankdata(np.abs(d))
    r_plus, r_minus = float(ranks[d > 0].sum()), float(ranks[d < 0].sum())
    return (r_plus - r_minus) / (r_plus + r_minus)


def wilcoxon_paired(expected: Sequence[float], perceived: Sequence[float],
                    min_nonzero: int = DEFAULT_MIN_NONZERO) -> PairedTest:
    """Paired test on complete pairs only (the caller drops pairs with a missing side)."""
    if len(expected) != len(perceived):
        raise ValueError("expected and perceived must be paired (same length)")
    before = np.asarray(expected, dtype=float)
    after = np.asarray(perceived, dtype=float)
    diff = after - before
    n_pairs, n_nonzero = int(diff.size), int(np.count_nonzero(diff))
    median_difference = float(np.median(diff)) if diff.size else None
    base = dict(n_pairs=n_pairs, n_nonzero=n_nonzero, median_difference=median_difference,
                rank_biserial=rank_biserial(diff.tolist()))
    if n_pairs == 0:
        return PairedTest(**base, tested=False, note="no pairs: no rater gave both an expected and a perceived answer")
    if n_nonzero < min_nonzero:
        pairs = f"{n_pairs} pair{'s' if n_pairs != 1 else ''}"
        return PairedTest(**base, tested=False,
                          note=f"n too small: {pairs}, {n_nonzero} with a difference; "
                               f"the test needs at least {min_nonzero}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # scipy warns when ties force the normal approximation
        result = stats.wilcoxon(after, before, zero_method="wilcox", alternative="two-sided")
    return PairedTest(**base, tested=True, statistic=float(result.statistic), p_value=float(result.pvalue))


def cronbach_alpha(items: np.ndarray) -> float | None:
    """Internal consistency of a respondents x items matrix of complete answers; None if undefined."""
    items = np.asarray(items, dtype=float)
    if items.ndim != 2 or items.shape[0] < 2 or items.shape[1] < 2:
        return None
    total_variance = items.sum(axis=1).var(ddof=1)
    if total_variance == 0:
        return None
    k = items.shape[1]
    return float(k / (k - 1) * (1 - items.var(axis=0, ddof=1).sum() / total_variance))
