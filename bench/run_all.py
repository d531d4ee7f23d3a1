"""`make bench`: the benchmark suite (bench/suite.py), printed as one table of figures against same-run baselines.
Pass --quick for short runs. Progress goes to stderr: which part is running, the rows it makes, and its expected
duration. The other scripts in bench/ print more detail on one subject each."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import suite

if __name__ == "__main__":
    sys.exit(suite.main(sys.argv[1:]))
