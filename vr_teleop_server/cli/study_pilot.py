"""`vr-teleop study pilot FILE --study-dir DIR --participants N [--speed max] [--seed S] [--perception P]`: the whole protocol of a
study with people, played by simulated people through the live study's services (tools/study_pilot.py), then
the folder's report."""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from simclock import WALL, SimulatedClock
from simclock import run as run_on

from .replay import speed as parse_speed


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("pilot", help="run a study's whole protocol with simulated participants",
                       description="Enrol N simulated participants and run them through the live study's own road: "
                                   "the experimenter's services, their trials on the stand-in, their questionnaires "
                                   "through the participant's services. Then `study report DIR` gives the table.")
    p.add_argument("file", type=Path, metavar="FILE", help="the study file (with a consent_form)")
    p.add_argument("--study-dir", type=Path, required=True, metavar="DIR", help="the study folder to fill")
    p.add_argument("--participants", type=int, required=True, metavar="N", help="how many to enrol")
    p.add_argument("--speed", type=parse_speed, default=1.0, metavar="max",
                   help="1 (real time, the default) or max (a simulated clock, as fast as the work allows)")
    p.add_argument("--seed", type=int, default=1, help="the simulated people's and answers' seed (default 1)")
    p.add_argument("--perception", choices=("modelled", "rendered"), default="modelled",
                   help="where the stand-in's pupils' faces come from: 'modelled' (the default: projected from the "
                        "scene with the detector's measured recall, no frame drawn; a dozen participants in minutes) "
                        "or 'rendered' (the detector on drawn frames, about 6 times the CPU)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..study.folder import FolderError
    from ..study.studyfile import StudyFileError
    from ..tools.study_pilot import pilot

    if args.participants < 1:
        print("vr-teleop study pilot: error: --participants must be 1 or more", file=sys.stderr)
        return 2
    if not (args.speed == 1.0 or math.isinf(args.speed)):
        print("vr-teleop study pilot: error: --speed is 1 or max", file=sys.stderr)
        return 2
    clock = SimulatedClock() if math.isinf(args.speed) else WALL
    started = time.perf_counter()
    try:
        result = run_on(pilot(args.file, args.study_dir, args.participants, clock=clock, seed=args.seed,
                              perception=args.perception), clock)
    except (FolderError, StudyFileError, ValueError) as exc:
        print(f"vr-teleop study pilot: error: {exc}", file=sys.stderr)
        return 2
    outcomes = ", ".join(f"{n} {o}" for o, n in sorted(result.outcomes.items()))
    print(f"pilot: {len(result.participants)} participants ({', '.join(result.participants)}), {result.trials} trials "
          f"({outcomes}), {result.questionnaires} questionnaires in {time.perf_counter() - started:.1f} s; "
          f"the table: vr-teleop study report {args.study_dir}")
    return 0
