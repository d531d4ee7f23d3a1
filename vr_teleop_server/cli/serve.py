"""`vr-teleop serve`: runs the server until Ctrl-C or SIGTERM."""

from __future__ import annotations

import argparse
import asyncio
import gc
import logging
import os
import signal
import sys
from pathlib import Path

from pydantic import ValidationError

from client_protocol.files import describe_problems, read_document
from client_protocol.registry import describe_validation_error

from ..app import TeleopServer
from ..settings import ServerSettings
from ..core.access import ROLES, generate_tokens
from ..core.scheduling import short_slice
from ..teleop import TeleopSettings

TURN_SECRET_ENV = "VR_TELEOP_TURN_SECRET"


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("serve", help="run the rosbridge v2 server",
                              description="Run the VR telepresence server (rosbridge v2 over WebSocket).")
    defaults = ServerSettings()
    p.add_argument("--host", default=defaults.host, help="address to listen on (default %(default)s)")
    p.add_argument("--port", type=int, default=defaults.port, help="port to listen on (default %(default)s)")
    p.add_argument("--time-style", choices=["ros1", "ros2"], default=defaults.time_style,
                   help="send time as {secs, nsecs} (ros1) or {sec, nanosec} (ros2); both are accepted")
    p.add_argument("--max-message-size", type=int, default=defaults.max_message_size, metavar="BYTES",
                   help="larger frames get a status error (default %(default)s)")
    p.add_argument("--service-timeout", type=float, default=defaults.service_timeout, metavar="S",
                   help="seconds a service call waits when the caller gives no timeout (default %(default)s)")
    p.add_argument("--backend", choices=["sim", "ros", "luxai", "none"], default=defaults.backend,
                   help="the robot: the embedded MuJoCo stand-in (sim), a real QTrobot's rosbridge (ros, with "
                        "--robot-url), a QTrobot v3 through LuxAI's SDK (luxai, with --robot-url) or none "
                        "(default %(default)s)")
    p.add_argument("--robot-url", default=None, metavar="URL",
                   help="the real robot: for --backend ros its rosbridge, ws://ROBOT:9090 (default "
                        "ws://127.0.0.1:9091); for --backend luxai its service hub, tcp://ROBOT:50500 (default "
                        "tcp://127.0.0.1:50500), or an MQTT broker, mqtt://BROKER:1883 (also mqtts://, wss://), "
                        "with --robot-id")
    p.add_argument("--robot-id", default=None, metavar="QTRD000320",
                   help="the QTrobot v3's id, for --backend luxai through an MQTT broker")
    p.add_argument("--mqtt-ca-file", type=Path, default=None, metavar="CA.pem",
                   help="--backend luxai through a TLS broker (mqtts://, wss://): the CA certificate to trust "
                        "(default: the system's)")
    p.add_argument("--mqtt-username", default=None, metavar="NAME",
                   help="--backend luxai through a broker that wants a login; the password is read from "
                        "$VR_TELEOP_MQTT_PASSWORD (never from the command line, where other users could read it)")
    p.add_argument("--camera-url", default=None, metavar="tcp://ROBOT:50655",
                   help="the QTrobot v3's realsense-driver plugin over ZeroMQ (default: the robot's host, port "
                        "50655); through MQTT it is found under its node id qtrobot-realsense-driver")
    p.add_argument("--camera-size", default=f"{defaults.camera_width}x{defaults.camera_height}", metavar="WxH",
                   help="head-camera image size (default %(default)s)")
    p.add_argument("--camera-fps", type=float, default=defaults.camera_fps,
                   help="head-camera frames a second while someone watches (default %(default)s)")
    p.add_argument("--gesture-dir", type=Path, default=None,
                   help="directory for recorded gestures and extra LuxAI gesture files")
    p.add_argument("--menu-dir", type=Path, default=None, metavar="DIR",
                   help="radial menu files (*.yaml) to use instead of the packaged ones (see menus/data)")
    p.add_argument("--motivation-config", type=Path, default=None, metavar="FILE",
                   help="motivation variables: limits and dynamics (default: the packaged motivation.yaml)")
    p.add_argument("--audio-dir", type=Path, default=None, metavar="DIR",
                   help="where the operator's voice is logged, one WAV per client (default: a temporary directory)")
    p.add_argument("--bystander-interval", type=float, default=defaults.bystander_interval, metavar="S",
                   help="the stand-in's simulated pupils take turns saying a line every S seconds (heard in the "
                        "robot's microphone, reported as voice activity); 0: never (default %(default)s)")
    p.add_argument("--autonomy", choices=["teleoperated", "supervised", "autonomous"], default=defaults.autonomy,
                   help="the robot's autonomy level at start: teleoperated (nothing moves unless someone moves "
                        "it), supervised (it looks at who speaks and proposes actions the teacher decides), "
                        "autonomous (it does what it proposes); changed live with /vr_teleop/autonomy/level "
                        "(default %(default)s)")
    p.add_argument("--autonomy-rules", type=Path, default=None, metavar="FILE",
                   help="the proposal rules, situations to menu items (YAML; default: the packaged rules)")
    p.add_argument("--autonomy-memory", type=Path, default=None, metavar="PATH",
                   help="a JSON file where autonomy keeps what it learned from the teacher, loaded at start "
                        "(default: nothing kept between runs)")
    p.add_argument("--autonomy-attention", type=Path, default=None, metavar="FILE",
                   help="the attention configuration (YAML; default: the packaged one, LuxAI's figures)")
    p.add_argument("--ice-server", action="append", default=[], metavar="URL",
                   help="a STUN server for WebRTC media, e.g. stun:stun.example.org:3478 (repeatable; "
                        "default none: host candidates, enough on a LAN)")
    p.add_argument("--turn-url", action="append", default=[], metavar="URL",
                   help="a TURN relay for WebRTC media (repeatable): turn:HOST:3478?transport=udp, "
                        "turn:HOST:3478?transport=tcp, turns:HOST:443?transport=tcp. Clients get them with fresh "
                        "credentials from /vr_teleop/media/ice_servers; the server's own peer uses the first one "
                        "(put first the one the server can reach: turns:...:443 behind a firewall that blocks UDP)")
    p.add_argument("--turn-secret", default=None, metavar="SECRET",
                   help="the relay's shared secret (coturn: use-auth-secret, static-auth-secret=SECRET), or "
                        "$VR_TELEOP_TURN_SECRET; TURN credentials are made from it, valid for --turn-ttl")
    p.add_argument("--turn-ttl", type=float, default=defaults.turn_ttl, metavar="S",
                   help="seconds a TURN credential stays valid (default %(default)s)")
    p.add_argument("--record", type=Path, default=None, metavar="FILE.mcap",
                   help="record every message of the session, both ways, per client, to an MCAP file")
    p.add_argument("--record-camera-fps", type=float, default=defaults.record_camera_fps, metavar="FPS",
                   help="camera frames a second kept in the recording; 0 keeps none (default %(default)s)")
    p.add_argument("--operator-token", default=None, help="token of the operator role (or $VR_TELEOP_OPERATOR_TOKEN)")
    p.add_argument("--supervisor-token", default=None,
                   help="token of the supervisor role (or $VR_TELEOP_SUPERVISOR_TOKEN)")
    p.add_argument("--spectator-token", default=None,
                   help="token of the read-only spectator role (or $VR_TELEOP_SPECTATOR_TOKEN)")
    p.add_argument("--generate-tokens", action="store_true", help="make a token for each role and print them")
    p.add_argument("--insecure", action="store_true",
                   help="allow open access (no tokens) on a non-loopback address")
    p.add_argument("--certfile", type=Path, default=None, help="TLS certificate (PEM): serve wss:// and https://")
    p.add_argument("--keyfile", type=Path, default=None, help="TLS private key (PEM)")
    p.add_argument("--teleop-config", type=Path, default=None, metavar="FILE",
                   help="explicit-control parameters (YAML or JSON; keys as in vr_teleop_server/teleop/settings.py)")
    p.add_argument("--watchdog-timeout", type=float, default=None, metavar="S",
                   help="hold the robot when head poses stop for this long (default 0.2); the floor of the "
                        "threshold, which adapts to the measured pose jitter")
    p.add_argument("--watchdog-ceiling", type=float, default=None, metavar="S",
                   help="the adaptive watchdog threshold never goes above this (default 0.5)")
    p.add_argument("--deadman-mode", choices=["hold", "toggle"], default=None,
                   help="arms follow while the grip is held (hold), or each grip press toggles following")
    p.add_argument("--log-level", default="info", choices=["debug", "info", "warning", "error"])
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
    if args.backend == "luxai":
        from ..robot.backends.luxai import parse_robot_url

        try:
            parse_robot_url(args.robot_url or "tcp://127.0.0.1", args.robot_id)
        except ValueError as exc:
            print(f"vr-teleop serve: {exc}", file=sys.stderr)
            return 2
    tokens = {role: getattr(args, f"{role}_token") for role in ROLES}
    if args.generate_tokens:
        tokens = {role: tokens[role] or token for role, token in generate_tokens().items()}
    try:
        settings = ServerSettings(operator_token=tokens["operator"], supervisor_token=tokens["supervisor"],
                                  spectator_token=tokens["spectator"], insecure=args.insecure,
                                  certfile=args.certfile, keyfile=args.keyfile, teleop=teleop, host=args.host, port=args.port, time_style=args.time_style,
                                  max_message_size=args.max_message_size, service_timeout=args.service_timeout,
                                  backend=args.backend, robot_url=args.robot_url, robot_id=args.robot_id,
                                  camera_url=args.camera_url, mqtt_ca_file=args.mqtt_ca_file,
                                  mqtt_username=args.mqtt_username,
                                  mqtt_password=os.environ.get("VR_TELEOP_MQTT_PASSWORD") or None,
                                  camera_width=width,
                                  camera_height=height,
                                  camera_fps=args.camera_fps, gesture_dir=args.gesture_dir,
                                  menu_dir=args.menu_dir, motivation_config=args.motivation_config,
                                  audio_dir=args.audio_dir, bystander_interval=args.bystander_interval,
                                  autonomy=args.autonomy, autonomy_rules=args.autonomy_rules,
                                  autonomy_memory=args.autonomy_memory,
                                  autonomy_attention=args.autonomy_attention,
                                  ice_servers=tuple(args.ice_server), turn_urls=tuple(args.turn_url),
                                  turn_secret=args.turn_secret or os.environ.get(TURN_SECRET_ENV) or None,
                                  turn_ttl=args.turn_ttl,
                                  record=args.record,
                                  record_camera_fps=args.record_camera_fps)
    except ValidationError as exc:
        print(f"vr-teleop serve: {describe_validation_error(exc)}", file=sys.stderr)
        return 2
    # Process-wide logging only once the arguments are good: a refused command line leaves the caller's alone.
    logging.basicConfig(level=args.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    logging.getLogger("websockets").setLevel(max(logging.WARNING, logging.getLogger().level))  # we log our own
    short_slice()  # the loop's wake-ups preempt media work (core/scheduling.py)
    return asyncio.run(_serve(settings))


def _teleop_settings(args: argparse.Namespace) -> TeleopSettings:
    """The --teleop-config file, then the flags on top; errors name the file and the key."""
    values: dict = {}
    if args.teleop_config is not None:
        loaded = read_document(args.teleop_config)  # JSON is YAML too
        if not isinstance(loaded, dict):
            raise ValueError(f"{args.teleop_config}: expected a mapping of teleop settings")
        values.update(loaded)
    if args.watchdog_timeout is not None:
        values["watchdog_timeout_s"] = args.watchdog_timeout
    if args.watchdog_ceiling is not None:
        values["watchdog_ceiling_s"] = args.watchdog_ceiling
    if args.deadman_mode is not None:
        values["deadman_mode"] = args.deadman_mode
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
    except RuntimeError as exc:  # the robot cannot be reached
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
