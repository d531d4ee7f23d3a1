"""`vr-teleop schema --out DIR`: writes one JSON Schema per wire message and op (what the Unity team codes against)."""

from __future__ import annotations

import argparse
from pathlib import Path

from client_protocol.schema_export import write_schemas


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("schema", help="write the protocol's JSON Schemas",
                              description="Write one JSON Schema per rosbridge op and per ROS message type.")
    p.add_argument("--out", required=True, type=Path, help="directory to write the schemas into")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    written = write_schemas(args.out)
    print(f"wrote {len(written)} schemas to {args.out}")
    return 0
