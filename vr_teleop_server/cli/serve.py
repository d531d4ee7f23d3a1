"""`vr-teleop serve`: runs the server until Ctrl-C or SIGTERM."""

from __future__ import annotations

import argparse
import asyncio
import gc
import logging
import signal
import sys
from pathlib import Path

from pydantic import ValidationError

from client_protocol.files import describe_problems, read_document
from client_protocol.registry import describe_validation_error

from ..app import TeleopServer
from ..robot.backends import BACKENDS
from ..robot.link import RobotUnreachable
from ..settings import ServerSettings
from ..core.access import generate_tokens
from ..core.scheduling import short_slice
from ..teleop import TeleopSettings
from .options import add_options, choices_of, values_from


GROUPS = {  # `serve --help`'s groups: title, description
    "server": ("the protocol server", None),
    "robot": ("the robot", "--backend chooses it; --robot-url says where a real one is (each backend's default "
                           "below)"),
    "luxai": ("--backend luxai", "a QTrobot v3 through LuxAI's SDK: these options only apply with it"),
    "sim": ("--backend sim", "the MuJoCo stand-in: these options only apply with it"),
    "autonomy": ("autonomy", "the robot's own behaviour: attention to who speaks, proposals the teacher decides "
                             "(docs: the autonomy guide)"),
    "files": ("data files", None),
    "media": ("WebRTC media", None),
    "recording": ("recording", None),
    "study": ("a live study", "participants, trials and questionnaires on this server (docs: the studies guide)"),
    "access": ("roles, tokens and TLS", None),
    "teleop": ("explicit control", "the flags override --teleop-config's values"),
}
# TeleopSettings fields that are also flags: given, they override --teleop-config's values
TELEOP_FLAGS = {"watchdog_timeout_s": ("--watchdog-timeout", "S"), "watchdog_ceiling_s": ("--watchdog-ceiling", "S"),
                "deadman_mode": ("--deadman-mode", None)}


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("serve", help="run the rosbridge v2 server",
                              description="Run the VR telepresence server (rosbridge v2 over WebSocket).")
    groups = {key: p.add_argument_group(title, description) for key, (title, description) in GROUPS.items()}
    add_options(ServerSettings, groups)
    defaults = ServerSettings()
    groups["robot"].add_argument(
        "--camera-size", default=f"{defaults.camera_width}x{defaults.camera_height}", metavar="WxH",
        help="head-camera image size (default %(default)s)")
    groups["access"].add_argument("--generate-tokens", action="store_true",
                                  help="make a token for each role and print them")
    teleop = groups["teleop"]
    teleop.add_argument("--teleop-config", type=Path, default=None, metavar="FILE",
                        help="explicit-control parameters (YAML or JSON; keys as in vr_teleop_server/teleop/"
                             "settings.py)")
    fields = TeleopSettings.model_fields
    for name, (flag, metavar) in TELEOP_FLAGS.items():
        field = fields[name]
        choices = choices_of(field.annotation)
        teleop.add_argument(flag, dest=name, default=None, metavar=metavar, choices=choices,
                            type=None if choices else field.annotation,
                            help=f"{field.description} (default {getattr(field.default, 'value', field.default)})")
    p.add_argument("--log-level", default="info", choices=["debug", "info", "warning", "error"],
                   help="how much the server logs (default %(default)s)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        width, height = (int(v) for v in args.camera_size.lower().split("x"))
    except ValueError:
        print(f"vr-teleop serve: --camera-size must look like 640x480, not {args.camera_size!r}", file=sys.stderr)
        return 2
    try:
        teleop = _teleop_settings(args)
    except (OSError, ValueError) as exc:
        print(f"vr-teleop serve: {exc}", file=sys.stderr)
        return 2
    try:
        BACKENDS[args.backend].check_url(args.robot_url, args.robot_id)
    except ValueError as exc:
        print(f"vr-teleop serve: {exc}", file=sys.stderr)
        return 2
    values = values_from(ServerSettings, args)
    if args.generate_tokens:
        for role, token in generate_tokens().items():
            values[f"{role}_token"] = values[f"{role}_token"] or token
    try:
        settings = ServerSettings(**values, camera_width=width, camera_height=height, teleop=teleop)
    except ValidationError as exc:
        print(f"vr-teleop serve: {describe_validation_error(exc)}", file=sys.stderr)
        return 2
    if settings.backend == "luxai":
        from ..robot.backends.luxai import parse_robot_url

        try:
            parse_robot_url(settings.resolved_robot_url, settings.robot_id)
        except ValueError as exc:
            print(f"vr-teleop serve: {exc}", file=sys.stderr)
            return 2
    # Process-wide logging only once the arguments are good: a refused command line leaves the caller's alone.
    logging.basicConfig(level=args.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    logging.getLogger("websockets").setLevel(max(logging.WARNING, logging.getLogger().level))  # we log our own
    quiet_third_parties()
    short_slice()  # the loop's wake-ups preempt media work (core/scheduling.py)
    return asyncio.run(_serve(settings))


THIRD_PARTY_NOTICES = ("OpenGL",)  # start-up notices (OpenGL_accelerate loaded) nobody acts on: --log-level debug


def quiet_third_parties() -> None:
    """Third-party libraries' info lines only at --log-level debug."""
    for name in THIRD_PARTY_NOTICES:
        logging.getLogger(name).setLevel(max(logging.WARNING, logging.getLogger().level))


def _teleop_settings(args: argparse.Namespace) -> TeleopSettings:
    """The --teleop-config file, then the flags on top; errors name the file and the key."""
    values: dict = {}
    if args.teleop_config is not None:
        loaded = read_document(args.teleop_config)  # JSON is YAML too
        if not isinstance(loaded, dict):
            raise ValueError(f"{args.teleop_config}: expected a mapping of teleop settings")
        values.update(loaded)
    values.update({name: getattr(args, name) for name in TELEOP_FLAGS if getattr(args, name) is not None})
    try:
        return TeleopSettings(**values)
    except ValidationError as exc:
        where = args.teleop_config or "teleop settings"
        raise ValueError(f"{where}: {describe_problems(exc)}") from None


async def _serve(settings: ServerSettings) -> int:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        server = TeleopServer(settings)
    except ValueError as exc:  # a bad menu or motivation file: its name, the item and the problem
        print(f"vr-teleop serve: {exc}", file=sys.stderr)
        return 2
    try:
        await server.start()
    except RobotUnreachable as exc:
        logging.getLogger("vr_teleop_server").error("%s", exc)
        return 1
    except OSError as exc:
        logging.getLogger("vr_teleop_server").error("cannot listen on %s:%s: %s", settings.host, settings.port, exc)
        return 1
    # What start-up made (models, the registry, the stand-in) lives as long as the server. Frozen, it is left out
    # of the collector's full passes, which otherwise walk all of it (27 ms with no backend) in the middle of the
    # 90 Hz pose stream.
    gc.freeze()
    print(f"vr-teleop: listening on {server.url}", flush=True)
    web = server.url.replace("ws", "http", 1) + "/"
    if server.access.open:
        print(f"vr-teleop: open access (no tokens), loopback only; dashboard at {web}", flush=True)
        print(f"vr-teleop: operator page (headset) at {web}operator", flush=True)
    else:
        for token, role in server.access.tokens.items():
            print(f"vr-teleop: {role} token {token}  (dashboard: {web}#token={token})", flush=True)
            if role == "operator":
                print(f"vr-teleop: operator page (headset): {web}operator#token={token}", flush=True)
    await stop.wait()
    await server.stop()
    print("vr-teleop: stopped", flush=True)
    return 0
