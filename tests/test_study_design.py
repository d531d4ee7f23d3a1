"""Designs and orders: the balanced Latin square against the reference's rows for k = 3 and its properties for
k = 2..6, seeded random orders, and balanced between-subject assignment."""

from __future__ import annotations

from collections import Counter
from itertools import pairwise, permutations

import pytest

from vr_teleop_server.study.design import (DesignError, balance_note, cycle_length, participant_order,
                                           williams_rows)

CONDITIONS = ["A", "B", "C", "D", "E", "F"]


def test_k3_rows_are_the_references():
    rows = ["".join(map(str, row)) for row in williams_rows(3)]
    assert rows == ["012", "120", "201", "210", "021", "102"]


def test_k4_rows_are_williams():
    assert williams_rows(4) == [[0, 1, 3, 2], [1, 2, 0, 3], [2, 3, 1, 0], [3, 0, 2, 1]]


@pytest.mark.parametrize("k", [2, 3, 4, 5, 6])
def test_latin_square_balances_position_and_carry_over(k):
    rows = williams_rows(k)
    assert len(rows) == (k if k % 2 == 0 else 2 * k)
    for row in rows:
        assert sorted(row) == list(range(k))  # every condition once per participant
    copies = len(rows) // k
    for position in range(k):
        assert Counter(row[position] for row in rows) == {c: copies for c in range(k)}
    carry = Counter(pair for row in rows for pair in pairwise(row))
    assert set(carry) == set(permutations(range(k), 2))  # every condition follows every other ...
    assert set(carry.values()) == {copies}  # ... equally often


@pytest.mark.parametrize("k", [2, 3, 4, 5, 6])
def test_participants_take_the_rows_in_turn(k):
    conditions = CONDITIONS[:k]
    rows = williams_rows(k)
    for index in range(3 * len(rows)):
        expected = [conditions[c] for c in rows[index % len(rows)]]
        assert participant_order(conditions, "within", "latin", index) == expected


def test_random_order_is_seeded_and_fixed_is_the_files():
    first = [participant_order(CONDITIONS, "within", "random", i, seed=7) for i in range(12)]
    assert first == [participant_order(CONDITIONS, "within", "random", i, seed=7) for i in range(12)]
    assert first != [participant_order(CONDITIONS, "within", "random", i, seed=8) for i in range(12)]
    assert all(sorted(o) == CONDITIONS for o in first)
    assert len({tuple(o) for o in first}) > 1  # not one order for everyone
    assert participant_order(CONDITIONS, "within", "fixed", 5) == CONDITIONS


@pytest.mark.parametrize("order", ["random", "fixed"])
@pytest.mark.parametrize("k", [2, 3, 4, 5, 6])
def test_between_assignment_keeps_groups_equal(k, order):
    conditions = CONDITIONS[:k]
    for n in range(1, 4 * k + 1):
        groups = Counter(participant_order(conditions, "between", order, i, seed=3)[0] for i in range(n))
        sizes = [groups.get(c, 0) for c in conditions]
        assert max(sizes) - min(sizes) <= 1, (n, sizes)
        if n % k == 0:
            assert set(sizes) == {n // k}


def test_balance_is_reported_and_bad_designs_refused():
    assert cycle_length("within", "latin", 3) == 6 and cycle_length("within", "latin", 4) == 4
    assert balance_note("within", "latin", 3, 12) is None
    assert balance_note("within", "latin", 3, 7) == ("unbalanced: 7 participants is not a multiple of the 6 rows "
                                                     "of the balanced Latin square; 5 more would balance it")
    assert balance_note("between", "random", 3, 4).startswith("unbalanced: 4 participants")
    assert balance_note("within", "random", 3, 7) is None
    with pytest.raises(DesignError, match="order: latin is for a within-subject design"):
        participant_order(CONDITIONS, "between", "latin", 0)
    with pytest.raises(DesignError, match="condition names must be unique"):
        participant_order(["A", "A"], "within", "latin", 0)
    with pytest.raises(DesignError, match="at least one condition"):
        williams_rows(0)
