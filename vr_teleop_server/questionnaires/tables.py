"""Plain-text tables for the terminal: aligned columns, numbers right-aligned, ASCII only."""

from __future__ import annotations

from collections.abc import Sequence


def num(value: float | None, signed: bool = False, digits: int = 2) -> str:
    """A number as short as it can be shown exactly to `digits` decimals; "-" when there is none."""
    if value is None:
        return "-"
    text = f"{value:.{digits}f}".rstrip("0").rstrip(".")
    if text == "-0":
        text = "0"
    if signed and value > 0 and text != "0":
        text = "+" + text
    return text


def p_text(p: float | None) -> str:
    if p is None:
        return "-"
    return "<.001" if p < 0.001 else f"{p:.3f}"


def table(headers: Sequence[str], rows: Sequence[Sequence[str]], left: Sequence[int] = (0,),
          indent: str = "  ", min_widths: Sequence[int] = ()) -> str:
    """Columns listed in `left` are left-aligned, the others right-aligned (numbers).

    `min_widths` lets several tables printed one after another share their column widths.
    """
    widths = [max(len(h), w) for h, w in zip(headers, [*min_widths, *[0] * len(headers)])]
    for row in rows:
        for i, cell in enumerate(row):
            widths[i] = max(widths[i], len(cell))

    def line(cells: Sequence[str]) -> str:
        parts = [cell.ljust(widths[i]) if i in left else cell.rjust(widths[i]) for i, cell in enumerate(cells)]
        return (indent + "  ".join(parts)).rstrip()

    rule = indent + "  ".join("-" * w for w in widths)
    return "\n".join([line(headers), rule, *(line(row) for row in rows)])
