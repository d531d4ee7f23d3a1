"""Counts the checks in the test suite, per file: `assert` statements and `pytest.raises`/`pytest.warns` blocks
(helpers' own asserts, support.py's expect and the like, count once where they are written).

Run before and after a change to the tests, to see that none was dropped:
    python scripts/count_checks.py [--total] [tests/...]
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def checks(path: Path) -> int:
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    n = 0
    for node in ast.walk(tree):
        if isinstance(node, ast.Assert):
            n += 1
        elif (isinstance(node, ast.withitem) and isinstance(node.context_expr, ast.Call)
              and isinstance(node.context_expr.func, ast.Attribute) and node.context_expr.func.attr in ("raises", "warns")):
            n += 1
    return n


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("paths", nargs="*", type=Path, default=[ROOT / "tests"])
    parser.add_argument("--total", action="store_true", help="only the total")
    args = parser.parse_args(argv)
    files = sorted(f for p in args.paths for f in ([p] if p.is_file() else p.rglob("*.py")))
    total = 0
    for f in files:
        n = checks(f)
        total += n
        if not args.total and n:
            print(f"{n:6d}  {f.relative_to(ROOT) if f.is_relative_to(ROOT) else f}")
    print(f"{total:6d}  total")
    return 0


if __name__ == "__main__":
    sys.exit(main())
