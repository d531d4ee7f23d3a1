"""`vr-teleop study run FILE (--trial NAME | --condition NAME | --all) [--speed max] [--repeat N --seed S]
[--network lan,continent] [--workers K | --scheduler tcp://HOST:8786] [--shared-dir DIR]`: run study trials on the
stand-in and compare their metrics. A task study (toolbox.yaml) gives fluency metrics; a classroom study
(`kind: classroom`, classroom.yaml) gives attention and teacher-workload measures per condition (autonomy level)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from importlib import resources
from pathlib import Path

from . import study_pilot, study_report, study_withdraw
from .examples import STUDIES, study_file
from .replay import speed as parse_speed
from ..tools.distributed import Workers, WorkersError, add_arguments, positive
from ..tools.distributed import run_all as run_everywhere
from ..tools.study_runner import TrialJob, run_job
from ..tools.timeout import TrialTimedOut
from ..study.kind import StudyKind, TrialReport
from ..study.kinds import KINDS, kind_of, load_study
from ..study.network import profiles
from ..study.studyfile import StudyFileError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("study", help="HRI user studies: run trials of a study file on the stand-in")
    sub = p.add_subparsers(dest="study_command", metavar="ACTION", required=True)
    r = sub.add_parser(
        "run", help="run one trial (--trial) or every trial (--all) of a study file",
        description="Run trials of a study file on the MuJoCo stand-in, each with its own server, session "
                    "recording and simulated participant, operator and experimenter; print the metrics, and for "
                    "--all a table shaped like the framework paper's Table III.")
    r.add_argument("file", type=Path, metavar="FILE", nargs="?",
                   help="the study file (YAML); or --example NAME for a packaged one")
    r.add_argument("--example", choices=sorted(STUDIES), default=None,
                   help="a packaged example study instead of FILE (vr-teleop examples copy DIR: editable copies)")
    which = r.add_mutually_exclusive_group(required=True)
    which.add_argument("--trial", "--condition", dest="trial", metavar="NAME",
                       help="the trial (a classroom study's condition) to run")
    which.add_argument("--all", action="store_true", help="run every trial (condition), in the file's order")
    r.add_argument("--record-dir", type=Path, default=Path("study-recordings"), metavar="DIR",
                   help="where each trial's session recording (TRIAL.mcap) goes (default: study-recordings)")
    r.add_argument("--json", type=Path, metavar="OUT",
                   help="write every trial's metrics as JSON here ('-' for stdout, which then holds only the JSON)")
    r.add_argument("--timeout", type=float, default=900.0, metavar="S",
                   help="stop a trial that has not ended after S seconds (simulated seconds at --speed max): "
                        "exit code 2")
    r.add_argument("--port", type=int, default=0, metavar="PORT",
                   help="at real time, each trial's server (and its dashboard, to follow the trial live) listens "
                        "on this port (default: any free one; the address is printed)")
    r.add_argument("--speed", type=_speed, default=1.0, metavar="max",
                   help="1 (default): in real time; max: on a simulated clock, as fast as the work allows")
    r.add_argument("--repeat", type=positive, default=None, metavar="N",
                   help="run each trial N times, with seeds S..S+N-1, and print each metric's mean, SD and 95%% "
                        "confidence interval beside the table; --json then holds every run")
    r.add_argument("--seed", type=int, default=None, metavar="S",
                   help="the simulated people's seed (default: the study file's seed)")
    r.add_argument("--network", type=_profiles, default=None, metavar="P1,P2",
                   help="classroom studies at --speed max: run each condition under each of these network profiles "
                        "(netem/profiles.yaml: lan, wifi, city, continent, bad) on the teacher's connection")
    add_arguments(r, "trials")
    r.add_argument("--shared-dir", type=Path, default=None, metavar="DIR",
                   help="a directory every worker sees at this path (a network share): the workers write the "
                        "recordings there and none is sent back (instead of --record-dir)")
    r.set_defaults(func=run)
    study_withdraw.register(sub)
    study_pilot.register(sub)
    study_report.register(sub)


def _plan(kind: StudyKind, study: object, jobs: list[TrialJob], simulated: bool, workers: Workers) -> str:
    """What is about to run and how long it takes at this speed; at --speed max, why there is nothing to watch."""
    each = kind.trial_s(study)
    trials = f"{len(jobs)} trial{'' if len(jobs) == 1 else 's'}"
    where = "" if workers.in_process else f" on {workers.describe()}"
    total = each * len(jobs)
    if not simulated:
        each_one = f" ({_duration(each)} a trial)" if len(jobs) > 1 else ""
        return (f"running {trials}{where} in real time: about {_duration(total)}{each_one}; "
                "--speed max runs them on a simulated clock, usually several times faster")
    return (f"running {trials}{where} at --speed max: {_duration(total)} of trials on a simulated clock, as fast as "
            "this machine allows. There is nothing to follow live: each trial's server runs inside this process "
            "with no network port (run without --speed max to watch a trial on the dashboard)")


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.0f} min"


def _speed(text: str) -> float:
    value = parse_speed(text)
    if value not in (1.0, math.inf):
        raise argparse.ArgumentTypeError("a study runs in real time (1) or as fast as it can (max)")
    return value


def _profiles(text: str) -> list[str]:
    chosen = [p.strip() for p in text.split(",") if p.strip()]
    try:
        profiles(chosen)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--network: ")) from None
    if not chosen:
        raise argparse.ArgumentTypeError("name at least one profile, e.g. lan,continent")
    return chosen


def run(args: argparse.Namespace) -> int:
    if (args.file is None) == (args.example is None):
        print("vr-teleop study run: error: give a study FILE or --example NAME (one of "
              f"{', '.join(sorted(STUDIES))}), not {'both' if args.file else 'neither'}", file=sys.stderr)
        return 2
    try:
        if args.example is not None:
            with resources.as_file(study_file(args.example)) as path:
                study = load_study(path)
            args.file = Path(f"--example {args.example}")
        else:
            study = load_study(args.file)
    except StudyFileError as exc:
        print(f"vr-teleop study: error: {exc}", file=sys.stderr)
        return 2
    kind = kind_of(study)
    if args.network is not None and not kind.networks:
        networked = " or ".join(k.name for k in KINDS.values() if k.networks)
        print(f"vr-teleop study: error: --network is for {networked} studies (kind: {networked})", file=sys.stderr)
        return 2
    if args.network is not None and not math.isinf(args.speed):
        print("vr-teleop study: error: --network runs on the simulated clock only: add --speed max (at real time, "
              "run the server behind the WAN emulator: docs/guides/deployment.md)", file=sys.stderr)
        return 2
    names = list(study.trials) if args.all else [args.trial]
    if args.trial is not None and args.trial not in study.trials:
        print(f"vr-teleop study: error: no trial {args.trial!r} in {args.file}; trials: {', '.join(study.trials)}",
              file=sys.stderr)
        return 2
    record_dir = args.shared_dir or args.record_dir
    record_dir.mkdir(parents=True, exist_ok=True)
    to_stdout = args.json is not None and str(args.json) == "-"
    notes = sys.stderr if to_stdout else sys.stdout  # `--json -`: stdout holds the JSON and nothing else
    simulated = math.isinf(args.speed)
    first = study.seed if args.seed is None else args.seed
    seeds = list(range(first, first + (args.repeat or 1)))
    workers = Workers.from_args(args)
    # The recording is written where this process reads it (in this process, or a shared directory), or sent back.
    sent_back = not workers.in_process and args.shared_dir is None
    written_to = None if sent_back else record_dir if workers.in_process else record_dir.resolve()
    networks = args.network or [None]
    jobs = [TrialJob(study, name, seed, "", written_to, args.timeout, simulated, progress=workers.in_process,
                     network=network, port=args.port)
            for name in names for network in networks for seed in seeds]
    jobs = [dataclasses.replace(job, record_name=f"{job.name}-seed{job.seed}.mcap" if args.repeat is not None
                                else f"{job.name}.mcap") for job in jobs]
    groups = list(dict.fromkeys(job.name for job in jobs))  # conditions (x network profiles), in order
    done: dict[str, TrialReport] = {}
    if args.port and (simulated or len(jobs) > 1 and not workers.in_process):
        print("vr-teleop study: error: --port is for trials run one after another at real time (their servers "
              "then take the port in turn)", file=sys.stderr)
        return 2
    print(_plan(kind, study, jobs, simulated, workers), file=notes, flush=True)
    try:
        for job, result in run_everywhere(run_job, jobs, workers, name=lambda job: job.key,
                                            progress=not workers.in_process, unit="trial"):
            report = result.report
            if result.recording is not None:
                path = record_dir / job.record_name
                path.write_bytes(result.recording)
                report = dataclasses.replace(report, recording=path)
            done[job.key] = report
            seeded = f" (seed {job.seed})" if args.repeat is not None else ""
            print(kind.summary(f"{job.name}{seeded} ({report.outcome})", report.live), file=notes)
            if simulated:
                t1, wall = report.live.duration_s, result.wall_s
                print(f"  {t1:.1f} s of trial in {wall:.1f} s (x{t1 / wall:.1f})", file=notes)
            print(kind.recording_line(report), file=notes, flush=True)
            for refusal in report.refusals:
                print(f"  operator command refused: {refusal}", file=notes)
    except TrialTimedOut as exc:
        print(f"vr-teleop study: {exc}", file=sys.stderr)
        return 2
    except WorkersError as exc:
        print(f"vr-teleop study: error: {exc}", file=sys.stderr)
        return 1
    except ValueError as exc:  # what only the running server can check (a classroom's menu item ids)
        print(f"vr-teleop study: error: {args.file}: {exc}", file=sys.stderr)
        return 2
    runs = {name: [done[job.key] for job in jobs if job.name == name] for name in groups}
    reports = [r for name in groups for r in runs[name]]
    if len(groups) > 1 or args.repeat is not None:
        print(file=notes)
        shown = [r for name in groups for r in runs[name][:1]] if args.repeat is None else reports
        print(kind.table(shown), file=notes)
    if args.repeat is not None:
        print(file=notes)
        print(kind.stats_table(runs), file=notes)
    if args.json is not None:
        if args.repeat is None:
            document = {r.trial: {"outcome": r.outcome, "modules": list(r.modules), **r.live.to_json_dict()}
                        for r in reports}
        else:
            document = {name: {"modules": list(trial_runs[0].modules), "seeds": seeds,
                               "stats": kind.summarise(trial_runs),
                               "runs": [{"seed": r.seed, "outcome": r.outcome, **r.live.to_json_dict()}
                                        for r in trial_runs]}
                        for name, trial_runs in runs.items()}
        text = json.dumps(document, indent=2)
        if to_stdout:
            print(text)
        else:
            args.json.write_text(text + "\n")
            print(f"wrote {args.json}", file=notes)
    return 0 if all(r.outcome == "completed" and r.recording_matches for r in reports) else 1
