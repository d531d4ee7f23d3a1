"""`vr-teleop replay FILE --server URL [--speed S] [--report R] [--plot P]`."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    r = subparsers.add_parser("replay", help="replay a session's headset messages against a server and report",
                              description="Replay the operator's messages of a recording (ours or synthesised) "
                                          "against a server, as a real rosbridge client, and report latency, "
                                          "tracking error, camera, menu acknowledgements and errors.")
    r.add_argument("file", type=Path)
    r.add_argument("--server", default="ws://127.0.0.1:9090", metavar="ws://HOST:PORT")
    r.add_argument("--speed", type=float, default=1.0, help="times faster than recorded (default 1)")
    r.add_argument("--json", "--report", dest="json", type=Path, default=None, metavar="OUT",
                   help="write the report as JSON here ('-' for stdout, which then holds only the JSON); without "
                        "it the report is printed")
    r.add_argument("--plot", type=Path, default=None, metavar="out.png",
                   help="commanded against measured joint angles over time")
    r.add_argument("--client", default=None, help="whose messages to replay (default: whoever sent most poses)")
    r.add_argument("--no-camera", action="store_true", help="do not subscribe to the camera")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.set_defaults(func=run_replay)


def run_replay(args: argparse.Namespace) -> int:
    from ..tools.replay import load_steps, plot, report
    from ..tools.replay import run_replay as replay

    if not args.speed > 0:
        print("vr-teleop replay: --speed must be above 0", file=sys.stderr)
        return 2
    try:
        steps, client = load_steps(args.file, args.client)
    except (OSError, ValueError) as exc:
        print(f"vr-teleop replay: {exc}", file=sys.stderr)
        return 2
    try:
        got, elapsed = asyncio.run(replay(steps, args.server, args.speed, camera=not args.no_camera,
                                          progress=not args.quiet))
    except OSError as exc:
        print(f"vr-teleop replay: cannot reach {args.server}: {exc}", file=sys.stderr)
        return 1
    result = {"file": str(args.file), "client": client, "server": args.server, **report(steps, got, elapsed,
                                                                                          args.speed)}
    text = json.dumps(result, indent=2)
    if args.json is not None and str(args.json) != "-":
        args.json.write_text(text + "\n")
    if args.plot:
        plot(got, args.plot)
    print(text)  # stdout holds the report and nothing else (progress goes to stderr)
    return 0
