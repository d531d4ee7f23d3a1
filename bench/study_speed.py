"""A study's trials on the simulated clock against the same trials in real time, same seed, same run.

Runs every trial of a study file (default examples/toolbox.yaml) as `vr-teleop study run --all --speed max`
does, then as a real-time run does (`--speed 1`; skip with `--max-only`), and prints for each: the trial's
simulated duration against the wall and CPU seconds it took (the issue's target: x10 or faster), and each metric
of the paper's table side by side with its relative difference (the issue's bound: within 2%).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from simclock import WALL, SimulatedClock
from simclock import run as run_on_clock
from vr_teleop_server.study.kind import TrialReport
from vr_teleop_server.study.kinds import KINDS, load_study
from vr_teleop_server.tools.study_runner import run_trial

TASK = KINDS["task"]

ROOT = Path(__file__).resolve().parent.parent


def cpu_seconds() -> float:
    """CPU seconds of this process and its ended children (the stand-in's render process)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def run(study, name: str, record: Path, simulated: bool) -> tuple[TrialReport, float, float]:
    clock = SimulatedClock() if simulated else WALL
    wall, cpu = time.perf_counter(), cpu_seconds()
    report = run_on_clock(run_trial(study, name, record=record, clock=clock), clock)
    return report, time.perf_counter() - wall, cpu_seconds() - cpu


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("file", nargs="?", type=Path, default=ROOT / "examples" / "toolbox.yaml")
    parser.add_argument("--max-only", action="store_true", help="skip the real-time runs")
    args = parser.parse_args()
    study = load_study(args.file)
    fast: list[TrialReport] = []
    slow: list[TrialReport] = []
    with tempfile.TemporaryDirectory() as tmp:
        total = [0.0, 0.0, 0.0]
        for name in study.trials:
            report, wall, cpu = run(study, name, Path(tmp) / f"{name}-max.mcap", simulated=True)
            fast.append(report)
            t1 = report.live.duration_s
            total = [total[0] + t1, total[1] + wall, total[2] + cpu]
            print(f"{name:<18} at max: {t1:6.1f} s of trial in {wall:6.1f} s wall = x{t1 / wall:5.1f}, "
                  f"{cpu:6.1f} CPU s = x{t1 / cpu:5.1f} per CPU second; {report.outcome}", flush=True)
        print(f"{'all trials':<18} at max: {total[0]:6.1f} s of trials in {total[1]:6.1f} s wall = "
              f"x{total[0] / total[1]:5.1f}, x{total[0] / total[2]:5.1f} per CPU second")
        print(TASK.table(fast))
        if args.max_only:
            return 0
        for name in study.trials:
            report, wall, _cpu = run(study, name, Path(tmp) / f"{name}-x1.mcap", simulated=False)
            slow.append(report)
            print(f"{name:<18} at x1: {report.live.duration_s:6.1f} s of trial in {wall:6.1f} s; {report.outcome}", flush=True)
        print(TASK.table(slow))
        worst = 0.0
        for a, b in zip(fast, slow):
            x, y = a.live.to_json_dict(), b.live.to_json_dict()
            parts = []
            for key in TASK.metrics:
                if x.get(key) is None or y.get(key) is None:
                    continue
                diff = abs(x[key] - y[key]) / max(abs(y[key]), 1e-9)
                worst = max(worst, diff if abs(y[key]) > 1e-9 else 0.0)
                parts.append(f"{key} {x[key]:.3f}/{y[key]:.3f} ({100 * diff:.1f}%)")
            print(f"{a.trial:<18} max/x1: " + ", ".join(parts))
        print(f"largest relative difference {100 * worst:.1f}% (bound 2%)")
    return 0 if all(r.outcome == "completed" for r in fast) else 1


if __name__ == "__main__":
    sys.exit(main())
