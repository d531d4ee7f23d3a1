"""Exact arithmetic on finite sets of closed time intervals.

Endpoints stay the caller's floats (clipping and merging only compare them, which is exact); lengths are
summed as `Fraction`s, so a measure is the exact sum of exact differences and rounding happens once, when
the caller turns it into a float. That makes identities such as |H u R| = |H| + |R| - |H n R| hold exactly,
and lets the live calculator, which sums the same time in different pieces, agree with the batch one bit
for bit.
"""

from __future__ import annotations

from collections.abc import Iterable
from fractions import Fraction

Interval = tuple[float, float]


def clip(intervals: Iterable[Interval], lo: float, hi: float) -> list[Interval]:
    """Intersect each interval with [lo, hi]; intervals that miss it are dropped, touching ones kept as points."""
    out: list[Interval] = []
    for a, b in intervals:
        if b < lo or a > hi:
            continue
        out.append((max(a, lo), min(b, hi)))
    return out


def union(intervals: Iterable[Interval]) -> list[Interval]:
    """Sorted, pairwise disjoint intervals covering the same set (sweep over sorted start points)."""
    merged: list[Interval] = []
    for a, b in sorted(intervals):
        if merged and a <= merged[-1][1]:
            if b > merged[-1][1]:
                merged[-1] = (merged[-1][0], b)
        else:
            merged.append((a, b))
    return merged


def intersection(first: Iterable[Interval], second: Iterable[Interval]) -> list[Interval]:
    """The set where both hold, as sorted disjoint intervals (two-pointer sweep over the two unions)."""
    xs, ys = union(first), union(second)
    out: list[Interval] = []
    i = j = 0
    while i < len(xs) and j < len(ys):
        lo = max(xs[i][0], ys[j][0])
        hi = min(xs[i][1], ys[j][1])
        if lo <= hi:
            out.append((lo, hi))
        if xs[i][1] < ys[j][1]:
            i += 1
        else:
            j += 1
    return out


def length(a: float, b: float) -> Fraction:
    """b - a without rounding."""
    return Fraction(b) - Fraction(a)


def measure(intervals: Iterable[Interval]) -> Fraction:
    """Exact Lebesgue measure of the union of the intervals (overlaps counted once, points count zero)."""
    return sum((length(a, b) for a, b in union(intervals)), Fraction(0))
