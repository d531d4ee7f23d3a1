"""`vr-teleop metrics INPUT`: fluency and team metrics of one trial, as a summary, JSON and a Gantt chart."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..study.metrics.fluency import compute_metrics
from ..study.metrics.fluency import fluency_summary as summary
from ..study.metrics.model import FDEL_DIRECTIONS
from ..study.metrics.model import MetricsInputError
from ..study.metrics.readers import read_interventions, read_trial

_EPILOG = """\
input formats:
  CSV   header agent,action,start,stop; agent is human or robot; times in seconds since the study start;
        an empty stop marks an action still running at the end (clipped to T1, reported as unfinished).
  JSON  a list of {"agent", "action", "start", "stop"} objects (stop may be null), or an object
        {"updates": [...], "interventions": [...], "planned_subtasks": N}.
  MCAP  session recordings (serve --record, study run): the trial's /study/state_updates, /study/interventions
        and /study/trial; the window is the trial's clock [0, T1] unless --t0/--t1 say otherwise.

`vr-teleop metrics autonomy FILE.mcap [--json OUT]`: supervised autonomy in a session recording instead: proposals
per minute, the share accepted, rejected, timed out and executed, the median time to a decision, the teacher's
own actions per minute, and attention from a pupil's speech onset to the head pointing at them (p50, p95).

T0 defaults to the earliest start, T1 to the latest stop (or an unfinished action's start, if later).
Effectiveness is computed only when interventions are known (--interventions, or "interventions" in a JSON
object): 1 - intervened robot subtasks / planned robot subtasks (default: the robot actions in [T0, T1]).
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "metrics", help="fluency metrics (H-IDLE, R-IDLE, C-ACT, F-DEL) of one trial",
        description="Compute Hoffman's fluency metrics and team efficiency/effectiveness from a trial's "
                    "state updates; print a summary, and optionally write JSON and a Gantt chart.",
        epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input", type=Path, metavar="INPUT", help="trial file: .csv, .json or .mcap (see below); or "
                                                             "'autonomy' followed by a session recording")
    p.add_argument("recording", type=Path, nargs="?", metavar="FILE.mcap",
                   help="after 'autonomy': the session recording whose autonomy to measure")
    p.add_argument("--trial", metavar="NAME", help="in a recording holding several trials, the one to compute")
    p.add_argument("--json", type=Path, metavar="OUT", help="write the metrics as JSON here ('-' for stdout)")
    p.add_argument("--plot", type=Path, metavar="PNG", help="write a Gantt chart of the trial here")
    p.add_argument("--t0", type=float, metavar="S", help="task start T0 in seconds (default: earliest start)")
    p.add_argument("--t1", type=float, metavar="S", help="task end T1 in seconds (default: latest stop)")
    p.add_argument("--fdel", choices=FDEL_DIRECTIONS, default="both",
                   help="which hand-overs F-DEL sums: both (default), human_to_robot (the wait the human "
                        "experiences) or robot_to_human")
    p.add_argument("--interventions", type=Path, metavar="FILE",
                   help="interventions as CSV (start,stop,subtask,note) or JSON list; enables effectiveness")
    p.add_argument("--planned-subtasks", type=int, metavar="N",
                   help="planned robot subtasks for effectiveness (default: robot actions in the window)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if str(args.input) == "autonomy":
        return run_autonomy(args)
    if args.recording is not None:
        print(f"vr-teleop metrics: error: one input, not two ({args.input}, {args.recording}); 'metrics autonomy "
              "FILE.mcap' measures autonomy", file=sys.stderr)
        return 2
    try:
        trial = read_trial(args.input, args.trial)
        interventions = trial.interventions
        if args.interventions is not None:
            if interventions is not None:
                raise MetricsInputError(args.input, "interventions are given both in this file and by --interventions",
                                        "keep one of the two")
            interventions = read_interventions(args.interventions)
        if not trial.updates:
            raise MetricsInputError(args.input, "no state updates", "add rows agent,action,start,stop")
        planned = args.planned_subtasks if args.planned_subtasks is not None else trial.planned_subtasks
        t0 = args.t0 if args.t0 is not None else trial.t0
        t1 = args.t1 if args.t1 is not None else trial.t1
        result = compute_metrics(trial.updates, t0=t0, t1=t1, fdel_direction=args.fdel,
                                 interventions=interventions, planned_subtasks=planned)
    except ValueError as exc:  # MetricsInputError included
        print(f"vr-teleop metrics: error: {exc}", file=sys.stderr)
        return 2

    notes = _report(args.json, summary(args.input.name, result), result.to_json_dict())
    if args.plot is not None:
        from ..study.metrics.gantt import plot_gantt  # matplotlib only when a chart is asked for

        plot_gantt(trial.updates, args.plot, result=result, title=args.input.name)
        print(f"wrote {args.plot}", file=notes)
    return 0


def run_autonomy(args: argparse.Namespace) -> int:
    from ..study.metrics.autonomy import autonomy_metrics, autonomy_summary

    if args.recording is None:
        print("vr-teleop metrics: error: 'metrics autonomy' needs a session recording: metrics autonomy FILE.mcap",
              file=sys.stderr)
        return 2
    try:
        measured = autonomy_metrics(args.recording)
    except (OSError, ValueError) as exc:
        print(f"vr-teleop metrics: error: {exc}", file=sys.stderr)
        return 2
    _report(args.json, autonomy_summary(measured), measured)
    return 0


def _report(out: Path | None, text: str, data: dict) -> object:
    """The summary, and the JSON where --json says ('-': stdout holds the JSON and nothing else); returns where
    notes go."""
    to_stdout = out is not None and str(out) == "-"
    notes = sys.stderr if to_stdout else sys.stdout
    print(text, file=notes)
    if out is not None:
        dumped = json.dumps(data, indent=2)
        if to_stdout:
            print(dumped)
        else:
            out.write_text(dumped + "\n", encoding="utf-8")
            print(f"wrote {out}", file=notes)
    return notes
