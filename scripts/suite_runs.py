"""Runs the full test suite N times in a row (default 5) on a fresh clone of this checkout's HEAD, and reports each
run's result and time: "green five runs in a row", shown.

    python scripts/suite_runs.py [--runs 5] [--workers 2] [--python .venv/bin/python] [--keep]

The clone is made with `git clone` into a temporary directory, so only committed work is tested. Without --python
the clone is set up as a fresh machine is (`make` builds its .venv, the Debian packages and npm's, once, timed
apart from the runs); with --python an interpreter that already has the dependencies runs the clone's code
(PYTHONPATH first), and the checkout's node_modules (git ignores it) is linked into the clone, its web/vendor
copied (the server serves no file whose real path is outside its web root).
Exits 1 unless every run passed.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
IGNORED_LINKS = ("node_modules",)  # what `make` would build, linked instead...
IGNORED_COPIES = ("vr_teleop_server/web/vendor",)  # ...or copied


def clone(into: Path) -> Path:
    """A clone at this checkout's HEAD (a worktree's own branch, whatever the repository's HEAD is)."""
    target = into / "clone"
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                          check=True).stdout.strip()
    subprocess.run(["git", "clone", "--quiet", "--no-hardlinks", str(ROOT), str(target)], check=True)
    subprocess.run(["git", "checkout", "--quiet", "--detach", head], cwd=target, check=True)
    return target


def set_up(repo: Path, python: str | None) -> tuple[list[str], dict[str, str], float]:
    """The pytest command and environment for the clone, and how long setting it up took."""
    t0 = time.monotonic()
    env = {**os.environ}
    if python is None:
        subprocess.run(["make", ".venv/.installed"], cwd=repo, check=True)
        python = str(repo / ".venv" / "bin" / "python")
    else:
        python = os.path.abspath(python)  # not resolved: a venv's python is a link to the system's
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(repo), env.get("PYTHONPATH")]))
        for name in IGNORED_LINKS:
            if (ROOT / name).exists() and not (repo / name).exists():
                (repo / name).symlink_to((ROOT / name).resolve())
        for name in IGNORED_COPIES:  # served: the server refuses a file whose real path is outside its web root
            if (ROOT / name).exists() and not (repo / name).exists():
                shutil.copytree(ROOT / name, repo / name)
    return [python, "-m", "pytest", "-q", "-p", "no:cacheprovider"], env, time.monotonic() - t0


def summary(output: str) -> str:
    """pytest's last line ("934 passed, 1 failed in ..."), without its '=' rules."""
    lines = [line.strip("= ") for line in output.splitlines() if re.search(r"\b(passed|failed|error)", line)]
    return lines[-1] if lines else "(no summary: pytest did not finish)"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--workers", default="2", help="pytest-xdist workers, as `make test` (0: one process)")
    parser.add_argument("--python", help="an interpreter with the dependencies (default: set the clone up)")
    parser.add_argument("--keep", action="store_true", help="keep the clone and the runs' logs")
    parser.add_argument("pytest_args", nargs="*", help="more arguments for pytest (after --)")
    args = parser.parse_args(argv)
    workdir = Path(tempfile.mkdtemp(prefix="suite-runs-"))
    try:
        repo = clone(workdir)
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=repo, capture_output=True, text=True,
                              check=True).stdout.strip()
        cmd, env, setup_s = set_up(repo, args.python)
        cmd += ["-n", args.workers, "--dist", "loadfile", *args.pytest_args]
        print(f"clone of {head} in {repo}; set-up {setup_s:.0f} s; each run: {' '.join(cmd[1:])}", flush=True)
        failed = 0
        for run in range(1, args.runs + 1):
            load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
            t0 = time.monotonic()
            proc = subprocess.run(cmd, cwd=repo, env=env, capture_output=True, text=True)
            elapsed = time.monotonic() - t0
            (workdir / f"run{run}.log").write_text(proc.stdout + proc.stderr)
            failed += proc.returncode != 0
            print(f"run {run}: {'green' if proc.returncode == 0 else 'RED'} in {elapsed / 60:.1f} min "
                  f"(load at start {load}): {summary(proc.stdout)}", flush=True)
        if failed:
            args.keep = True  # the red runs' logs are what the reader needs
            print(f"{failed} of {args.runs} runs red; the logs are in {workdir}")
            return 1
        print(f"{args.runs} of {args.runs} runs green in a row" + (f"; logs in {workdir}" if args.keep else ""))
        return 0
    finally:
        if not args.keep:
            shutil.rmtree(workdir, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
