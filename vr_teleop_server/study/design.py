"""A study's design and each participant's order of conditions (pure: no server, no files).

- `within`: every participant meets every condition. `order: latin` takes the rows of a balanced Latin square
  (Williams, 1949) in turn: for k conditions the first row is 0, 1, k-1, 2, k-2, ...; row r adds r modulo k.
  For even k those k rows balance position and carry-over (each condition follows every other exactly once);
  for odd k the k rows reversed are added (2k rows), which alone balances carry-over. `random`: a seeded
  shuffle per participant; `fixed`: the study file's order for everyone.
- `between`: one condition each, assigned in blocks of k participants, each block holding every condition once
  (a seeded shuffle per block with `order: random`, the file's order with `fixed`), so the groups never differ in
  size by more than one.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np

Design = Literal["within", "between"]
Order = Literal["latin", "random", "fixed"]


class DesignError(ValueError):
    """A design that cannot give orders; the message names the field and the fix."""


def williams_rows(k: int) -> list[list[int]]:
    """The balanced Latin square's rows for k conditions (numbered 0..k-1): k rows, or 2k for odd k."""
    if k < 1:
        raise DesignError("a design needs at least one condition")
    first, low, high = [0], 1, k - 1
    while len(first) < k:
        first.append(low)
        low += 1
        if len(first) < k:
            first.append(high)
            high -= 1
    rows = [[(c + r) % k for c in first] for r in range(k)]
    if k % 2 == 1 and k > 1:
        rows += [row[::-1] for row in rows]
    return rows


def cycle_length(design: Design, order: Order, k: int) -> int:
    """How many participants complete a balanced set: the Latin rows, a between block, or 1 (nothing to balance)."""
    if design == "between":
        return k
    return len(williams_rows(k)) if order == "latin" else 1


def participant_order(conditions: Sequence[str], design: Design, order: Order, index: int,
                      seed: int = 0) -> list[str]:
    """The conditions of the participant enrolled `index`-th (0 for P01), in the order they meet them."""
    k = len(conditions)
    if k == 0:
        raise DesignError("a design needs at least one condition")
    if len(set(conditions)) != k:
        raise DesignError("condition names must be unique")
    if index < 0:
        raise DesignError("a participant's index is 0 or more")
    if design == "within":
        if order == "latin":
            rows = williams_rows(k)
            return [conditions[c] for c in rows[index % len(rows)]]
        if order == "random":
            rng = np.random.default_rng([seed, index])
            return [conditions[c] for c in rng.permutation(k)]
        return list(conditions)
    if order == "latin":
        raise DesignError("order: latin is for a within-subject design; a between-subject design takes "
                          "order: random (a seeded shuffle per block of participants) or fixed")
    block, position = divmod(index, k)
    assignment = np.random.default_rng([seed, block]).permutation(k) if order == "random" else np.arange(k)
    return [conditions[int(assignment[position])]]


def balance_note(design: Design, order: Order, k: int, participants: int) -> str | None:
    """What a reader must be told when the participants do not fill whole balanced sets; None when they do."""
    cycle = cycle_length(design, order, k)
    if cycle <= 1 or participants % cycle == 0:
        return None
    what = f"the {cycle} rows of the balanced Latin square" if design == "within" else \
        f"blocks of {cycle} (one per condition)"
    return (f"unbalanced: {participants} participants is not a multiple of {what}; "
            f"{cycle - participants % cycle} more would balance it")
