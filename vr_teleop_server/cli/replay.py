"""`vr-teleop replay FILE [--server URL] [--speed S|max] [--report R] [--plot P]`; several files (or --workers,
--scheduler, --summary) at --speed max: a batch (tools/batch.py)."""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import sys
from pathlib import Path

from ..tools.distributed import add_arguments


def speed(text: str) -> float:
    """A positive number, or "max" (math.inf)."""
    if text == "max":
        return math.inf
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number or 'max'") from None
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"{text!r}: the speed must be above 0 (or 'max')")
    return value


def register(subparsers: argparse._SubParsersAction) -> None:
    r = subparsers.add_parser("replay", help="replay a session's headset messages against a server and report",
                              description="Replay the operator's messages of a recording (ours or synthesised) "
                                          "against a server, as a real rosbridge client, and report latency, "
                                          "tracking error, camera, menu acknowledgements and errors.")
    r.add_argument("file", type=Path, nargs="+", metavar="FILE",
                   help="the recording; several: a batch at --speed max, summarised one row per session")
    r.add_argument("--server", default=None, metavar="ws://HOST:PORT",
                   help="the server to replay against (default ws://127.0.0.1:9090; with --speed max and no "
                        "--server, a server of the replay's own on the stand-in and a simulated clock)")
    r.add_argument("--speed", type=speed, default=1.0, metavar="S|max",
                   help="times faster than recorded (default 1); max: as fast as the work allows (without "
                        "--server: on a simulated clock; with --server: each message as soon as the server takes it)")
    r.add_argument("--json", "--report", dest="json", type=Path, default=None, metavar="OUT",
                   help="also write the full report as JSON here ('-' for stdout, which then holds only the JSON); "
                        "a summary is printed either way")
    r.add_argument("--plot", type=Path, default=None, metavar="out.png",
                   help="commanded against measured joint angles over time")
    r.add_argument("--client", default=None, help="whose messages to replay (default: whoever sent most poses)")
    r.add_argument("--no-camera", action="store_true", help="do not subscribe to the camera")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.add_argument("--allow-truncated", action="store_true",
                   help="a recording that was cut off (not closed) is replayed as far as it goes, exit code 0 "
                        "(without it: the same replay, exit code 3)")
    add_arguments(r, "replays")
    r.add_argument("--summary", type=Path, default=None, metavar="OUT",
                   help="a batch's summary table, one row per session: OUT.csv and OUT.json")
    r.set_defaults(func=run_replay)


SIMULATED_SPEED = {True: 1.7, False: 20.0}  # --speed max without a server, camera or not (2-core machine, loaded)


def run_replay(args: argparse.Namespace) -> int:
    if len(args.file) > 1 or args.summary is not None or args.workers > 1 or args.scheduler is not None:
        from ..tools.batch import run_batch

        return run_batch(args)
    args.file = args.file[0]
    # what stdout is for: the report for a person, or with `--json -` the JSON alone (notes then go to stderr)
    to_stdout = args.json is not None and str(args.json) == "-"
    notes = sys.stderr if to_stdout else sys.stdout
    try:
        size_mb = args.file.stat().st_size / 1e6
        print(f"reading {args.file} ({size_mb:.1f} MB)", file=notes, flush=True)
        from ..recording.format import check_recording, read_recording

        check = check_recording(args.file)
        from ..tools.replay import load_steps, plot, report, run_simulated
        from ..tools.replay import run_replay as replay

        if not check.closed and not any(True for _ in read_recording(args.file)):
            print(f"vr-teleop replay: {args.file}: cut off before its first whole block of messages: the recording "
                  "was not closed, and nothing in it can be replayed", file=sys.stderr)
            return 2
        steps, client = load_steps(args.file, args.client)
    except (OSError, ValueError) as exc:
        print(f"vr-teleop replay: {exc}", file=sys.stderr)
        return 2
    session_s = steps[-1].t if steps else 0.0
    if not check.closed:
        of = f" of {round(check.planned_s, 1):g} s" if check.planned_s else ""
        print(f"vr-teleop replay: {args.file}: cut off after {session_s:.2f} s{of}: the recording was not closed "
              "(its writer was stopped, or the copy is incomplete); replaying what is there", file=sys.stderr,
              flush=True)
    simulated = math.isinf(args.speed) and args.server is None
    server = "in-process (stand-in, simulated clock)" if simulated else args.server or "ws://127.0.0.1:9090"
    print(_plan(session_s, len(steps), args.speed, simulated, not args.no_camera), file=notes, flush=True)
    try:
        if simulated:
            got, elapsed = run_simulated(steps, camera=not args.no_camera, progress=not args.quiet)
        else:
            got, elapsed = asyncio.run(replay(steps, server, args.speed, camera=not args.no_camera,
                                              progress=not args.quiet))
    except OSError as exc:
        hint = " (start one with `vr-teleop serve`, or replay without a server: --speed max)" \
            if args.server is None else ""
        print(f"vr-teleop replay: cannot reach {server}: {exc}{hint}", file=sys.stderr)
        return 1
    result = {"file": str(args.file), "client": client, "server": server, "closed": check.closed,
              **report(steps, got, elapsed, args.speed, recording=args.file)}
    if args.plot:
        plot(got, args.plot)
    if to_stdout:
        print(json.dumps(result, indent=2))
    else:
        from .report import replay_summary

        replay_summary(result, plot=args.plot)
        if args.json is not None:
            args.json.write_text(json.dumps(result, indent=2) + "\n")
            print(f"wrote {args.json} (the full report)")
    if not check.closed and not args.allow_truncated:
        print(f"vr-teleop replay: {args.file} was cut off: exit code 3 (--allow-truncated accepts it)",
              file=sys.stderr)
        return 3
    return 0


def _plan(session_s: float, steps: int, speed: float, simulated: bool, camera: bool) -> str:
    """What is about to be replayed, and how long it takes at this speed."""
    what = f"replaying {session_s:.1f} s of session ({steps} messages)"
    if simulated:
        guess = session_s / SIMULATED_SPEED[camera]
        return (f"{what} on a simulated clock, as fast as this machine allows: about {guess:.0f} s "
                f"(x{SIMULATED_SPEED[camera]:g} on a busy 2-core machine{'; --no-camera is faster' if camera else ''})")
    if math.isinf(speed):
        return f"{what} against a server, each message as soon as it takes it"
    return f"{what} in {'real time' if speed == 1 else f'x{speed:g}'}: {session_s / speed:.0f} s"
