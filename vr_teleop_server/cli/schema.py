"""`vr-teleop schema --out DIR [--names-js FILE]`: writes one JSON Schema per wire message and op (what the Unity team
codes against), and the pages' names module."""

from __future__ import annotations

import argparse
from pathlib import Path

from client_protocol.names import javascript_module
from client_protocol.schema_export import write_schemas


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("schema", help="write the protocol's JSON Schemas",
                              description="Write one JSON Schema per rosbridge op and per ROS message type.")
    p.add_argument("--out", required=True, type=Path, help="directory to write the schemas into")
    p.add_argument("--names-js", type=Path, default=None, metavar="FILE",
                   help="also write client_protocol/names.py's names as the pages' ES module "
                        "(vr_teleop_server/web/names.js)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    written = write_schemas(args.out)
    print(f"wrote {len(written)} schemas to {args.out}")
    if args.names_js is not None:
        args.names_js.write_text(javascript_module())
        print(f"wrote the names module {args.names_js}")
    return 0
