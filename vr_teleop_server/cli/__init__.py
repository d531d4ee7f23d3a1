"""The `vr-teleop` command line: one subcommand per tool, each registered by the module that implements it."""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import os
import sys

# Each module here exposes `register(subparsers)`, which adds its subcommands and sets `func` on them.
# `func(args)` returns the process exit code.
SUBCOMMAND_MODULES: tuple[str, ...] = (
    "vr_teleop_server.cli.serve",
    "vr_teleop_server.cli.schema",
    "vr_teleop_server.cli.synth",
    "vr_teleop_server.cli.replay",
    "vr_teleop_server.cli.questionnaires",
    "vr_teleop_server.cli.metrics",
    "vr_teleop_server.cli.study",
    "vr_teleop_server.cli.cert",
)


def _version() -> str:
    try:
        return importlib.metadata.version("vr-teleop-server")
    except importlib.metadata.PackageNotFoundError:  # a source tree that was never installed
        return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vr-teleop",
        description="VR telepresence server for QTrobot (rosbridge v2 over WebSocket) and HRI study tools.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
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
