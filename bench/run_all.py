"""`make bench`: runs every benchmark in bench/ in turn and prints its figures (pass --quick for short runs)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
SKIP = {"run_all.py", "relay.py"}


def main() -> int:
    extra = sys.argv[1:]
    failed = []
    for bench in sorted(p for p in HERE.glob("*.py") if p.name not in SKIP and not p.name.startswith("_")):
        print(f"\n=== {bench.name} {' '.join(extra)}", flush=True)
        if subprocess.run([sys.executable, str(bench), *extra], cwd=HERE.parent).returncode != 0:
            failed.append(bench.name)
    if failed:
        print(f"\nfailed: {', '.join(failed)}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
