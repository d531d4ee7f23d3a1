"""`vr-teleop export elan FILE.mcap --out DIR`: a session recording as a video and an ELAN file to code it in."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "export", help="export a session recording for video coding (ELAN)",
        description="Export a session recording: `export elan FILE.mcap --out DIR` writes the head camera as "
                    "DIR/NAME.mp4 (H.264, each frame at its recorded time) and DIR/NAME.eaf, an ELAN file linking "
                    "the video whose tiers are the labels, the human's and the robot's actions, proposals, "
                    "decisions, the pupils' and the teacher's speech and the autonomy level; time zero is the "
                    "first camera frame.")
    p.add_argument("format", choices=("elan",), help="what to export for (elan)")
    p.add_argument("recording", type=Path, metavar="FILE.mcap", help="a session recording (serve --record)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="the folder to write the files into")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..tools.elan import ExportError, export_elan, summary  # PyAV, OpenCV and pympi only for this command

    try:
        result = export_elan(args.recording, args.out)
    except ExportError as exc:
        print(f"vr-teleop export: error: {exc}", file=sys.stderr)
        return 2
    print(summary(result))
    return 0
