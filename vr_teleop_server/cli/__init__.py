"""The `vr-teleop` command line: one subcommand per tool, each registered by the module that implements it."""

from __future__ import annotations

import argparse
import difflib
import importlib
import importlib.metadata
import os
import sys

# Each subcommand, and the module that registers it: each module exposes `register(subparsers)`, which adds its
# subcommands and sets `func` on them; `func(args)` returns the process exit code. A command line names its
# subcommand first, and only that module is imported: `serve` does not load the study tools' libraries (scipy.stats,
# matplotlib: more CPU than the whole server's imports). --help, --version and an unknown command build them all.
_QUESTIONNAIRES = "vr_teleop_server.cli.questionnaires"
SUBCOMMANDS: dict[str, str] = {
    "serve": "vr_teleop_server.cli.serve",
    "schema": "vr_teleop_server.cli.schema",
    "synth": "vr_teleop_server.cli.synth",
    "replay": "vr_teleop_server.cli.replay",
    **dict.fromkeys(("qam", "sus", "tlx", "godspeed"), _QUESTIONNAIRES),
    "metrics": "vr_teleop_server.cli.metrics",
    "export": "vr_teleop_server.cli.export",
    "study": "vr_teleop_server.cli.study",
    "cert": "vr_teleop_server.cli.cert",
    "examples": "vr_teleop_server.cli.examples",
}


def _version() -> str:
    try:
        return importlib.metadata.version("vr-teleop-server")
    except importlib.metadata.PackageNotFoundError:  # a source tree that was never installed
        return "unknown (not installed)"


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of every subcommand, or of `command`'s alone."""
    parser = argparse.ArgumentParser(
        prog="vr-teleop",
        description="VR telepresence server for QTrobot (rosbridge v2 over WebSocket) and HRI study tools.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    modules = [SUBCOMMANDS[command]] if command in SUBCOMMANDS else dict.fromkeys(SUBCOMMANDS.values())
    for name in modules:
        importlib.import_module(name).register(subparsers)
    return parser


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    return {name: sub for action in parser._actions if isinstance(action, argparse._SubParsersAction)
            for name, sub in action.choices.items()}


def check_options(parser: argparse.ArgumentParser, argv: list[str]) -> None:
    """A mistyped option is answered by the subcommand it was given to, with its usage and the nearest option
    (argparse alone reports it at the top level, with the top-level usage). Exits as argparse does (code 2)."""
    current = parser
    for token in argv:
        if token == "--":
            return
        subcommands = _subcommands(current)
        if token in subcommands:
            current = subcommands[token]
            continue
        if not token.startswith("-") or token == "-" or token[1:2].isdigit():
            continue  # a value, or a negative number
        name = token.split("=", 1)[0]
        known = [o for action in current._actions for o in action.option_strings]
        if any(o.startswith(name) for o in known) if name.startswith("--") else name in known:
            continue  # an option, or a prefix argparse expands
        near = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
        hint = f"; did you mean {near[0]}?" if near else f"; its options are listed by {current.prog} --help"
        current.error(f"unrecognized option {name}{hint}")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser(argv[0] if argv else None)
    check_options(parser, argv)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except BrokenPipeError:  # output piped into `head` and the like: not an error of ours
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
