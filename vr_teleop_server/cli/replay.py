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
                   help="write the report as JSON here ('-' for stdout, which then holds only the JSON); without "
                        "it the report is printed")
    r.add_argument("--plot", type=Path, default=None, metavar="out.png",
                   help="commanded against measured joint angles over time")
    r.add_argument("--client", default=None, help="whose messages to replay (default: whoever sent most poses)")
    r.add_argument("--no-camera", action="store_true", help="do not subscribe to the camera")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    add_arguments(r, "replays")
    r.add_argument("--summary", type=Path, default=None, metavar="OUT",
                   help="a batch's summary table, one row per session: OUT.csv and OUT.json")
    r.set_defaults(func=run_replay)


def run_replay(args: argparse.Namespace) -> int:
    if len(args.file) > 1 or args.summary is not None or args.workers > 1 or args.scheduler is not None:
        from ..tools.batch import run_batch

        return run_batch(args)
    args.file = args.file[0]
    from ..tools.replay import load_steps, plot, report, run_simulated
    from ..tools.replay import run_replay as replay

    try:
        steps, client = load_steps(args.file, args.client)
    except (OSError, ValueError) as exc:
        print(f"vr-teleop replay: {exc}", file=sys.stderr)
        return 2
    simulated = math.isinf(args.speed) and args.server is None
    server = "in-process (stand-in, simulated clock)" if simulated else args.server or "ws://127.0.0.1:9090"
    try:
        if simulated:
            got, elapsed = run_simulated(steps, camera=not args.no_camera, progress=not args.quiet)
        else:
            got, elapsed = asyncio.run(replay(steps, server, args.speed, camera=not args.no_camera,
                                              progress=not args.quiet))
    except OSError as exc:
        print(f"vr-teleop replay: cannot reach {server}: {exc}", file=sys.stderr)
        return 1
    result = {"file": str(args.file), "client": client, "server": server,
              **report(steps, got, elapsed, args.speed, recording=args.file)}
    text = json.dumps(result, indent=2)
    if args.json is not None and str(args.json) != "-":
        args.json.write_text(text + "\n")
    if args.plot:
        plot(got, args.plot)
    print(text)  # stdout holds the report and nothing else (progress goes to stderr)
    return 0
