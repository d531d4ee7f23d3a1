"""`vr-teleop synth NAME --out FILE`: a synthesised headset session, as a recording that `replay` plays."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    from ..tools.synth import SCENARIOS

    p = subparsers.add_parser("synth", help="write a synthesised 90 Hz headset session as a recording",
                              description="Synthesise a headset session (human-like motion, sensor noise) as an "
                                          "MCAP recording that `vr-teleop replay` plays.")
    p.add_argument("name", choices=SCENARIOS)
    p.add_argument("--out", type=Path, required=True, metavar="FILE.mcap")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=run_synth)


def run_synth(args: argparse.Namespace) -> int:
    from ..tools.synth import build, write

    ticks = write(build(args.name, args.seed), args.out, seed=args.seed)
    print(f"vr-teleop synth: {args.name}: {ticks} headset frames ({ticks / 90:.1f} s at 90 Hz) -> {args.out}")
    return 0
