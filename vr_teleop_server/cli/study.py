"""`vr-teleop study run FILE (--trial NAME | --all)`: run study trials on the stand-in and compare their metrics."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from pathlib import Path

from .metrics import summary
from ..tools.study_runner import run_trial, table
from ..study.studyfile import StudyFileError, load_study


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("study", help="HRI user studies: run trials of a study file on the stand-in")
    sub = p.add_subparsers(dest="study_command", metavar="ACTION", required=True)
    r = sub.add_parser(
        "run", help="run one trial (--trial) or every trial (--all) of a study file",
        description="Run trials of a study file on the MuJoCo stand-in, each with its own server, session "
                    "recording and simulated participant, operator and experimenter; print the metrics, and for "
                    "--all a table shaped like the framework paper's Table III.")
    r.add_argument("file", type=Path, metavar="FILE", help="the study file (YAML)")
    which = r.add_mutually_exclusive_group(required=True)
    which.add_argument("--trial", metavar="NAME", help="the trial to run")
    which.add_argument("--all", action="store_true", help="run every trial, in the file's order")
    r.add_argument("--record-dir", type=Path, default=Path("study-recordings"), metavar="DIR",
                   help="where each trial's session recording (TRIAL.mcap) goes (default: study-recordings)")
    r.add_argument("--json", type=Path, metavar="OUT",
                   help="write every trial's metrics as JSON here ('-' for stdout, which then holds only the JSON)")
    r.add_argument("--timeout", type=float, default=900.0, metavar="S", help="give up on a trial after S seconds")
    r.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        study = load_study(args.file)
    except StudyFileError as exc:
        print(f"vr-teleop study: error: {exc}", file=sys.stderr)
        return 2
    names = list(study.trials) if args.all else [args.trial]
    if args.trial is not None and args.trial not in study.trials:
        print(f"vr-teleop study: error: no trial {args.trial!r} in {args.file}; trials: {', '.join(study.trials)}",
              file=sys.stderr)
        return 2
    args.record_dir.mkdir(parents=True, exist_ok=True)
    to_stdout = args.json is not None and str(args.json) == "-"
    notes = sys.stderr if to_stdout else sys.stdout  # `--json -`: stdout holds the JSON and nothing else
    reports = []
    for name in names:
        print(f"running trial {name} ...", file=notes, flush=True)

        def progress(elapsed: float, done: int, name: str = name) -> None:
            print(f"  {name}: {elapsed:5.1f} s, {done} action{'' if done == 1 else 's'} done", file=sys.stderr,
                  flush=True)

        report = asyncio.run(run_trial(study, name, record=args.record_dir / f"{name}.mcap", timeout=args.timeout,
                                       progress=progress))
        reports.append(report)
        print(summary(f"{name} ({report.outcome})", report.live), file=notes)
        print(f"  recording {report.recording}: metrics from it "
              f"{'equal' if report.recording_matches else 'DIFFER FROM'} the live ones", file=notes)
        for refusal in report.refusals:
            print(f"  operator command refused: {refusal}", file=notes)
    if len(reports) > 1:
        print(file=notes)
        print(table(reports), file=notes)
    if args.json is not None:
        text = json.dumps({r.trial: {"outcome": r.outcome, "modules": list(r.modules), **r.live.to_json_dict()}
                           for r in reports}, indent=2)
        if to_stdout:
            print(text)
        else:
            args.json.write_text(text + "\n")
            print(f"wrote {args.json}", file=notes)
    return 0 if all(r.outcome == "completed" and r.recording_matches for r in reports) else 1
