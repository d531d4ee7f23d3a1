"""The `vr-teleop` command line: one subcommand per tool, each registered by the module that implements it."""

from __future__ import annotations

import argparse
import importlib
import os
import sys

# Each module here exposes `register(subparsers)`, which adds its subcommands and sets `func` on them.
# `func(args)` returns the process exit code.
SUBCOMMAND_MODULES: tuple[str, ...] = (
    "vr_teleop_server.serve_cli",
    "vr_teleop_server.schema_cli",
    "vr_teleop_server.replay_cli",
    "vr_teleop_server.questionnaires.cli",
    "vr_teleop_server.study.metrics.cli",
    "vr_teleop_server.study.cli",
    "vr_teleop_server.cert_cli",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vr-teleop",
        description="VR telepresence server for QTrobot (rosbridge v2 over WebSocket) and HRI study tools.",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in SUBCOMMAND_MODULES:
        importlib.import_module(name).register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except BrokenPipeError:  # output piped into `head` and the like: not an error of ours
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
