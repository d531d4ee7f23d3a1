"""`vr-teleop serve` as a user runs it: one line saying where it listens, connections logged, clean stop."""

from __future__ import annotations

import asyncio
import os
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from testbed.processes import free_port
from websockets.sync.client import connect

from vr_teleop_server.app import TeleopServer
from vr_teleop_server.settings import ServerSettings

EXE = shutil.which("vr-teleop") or str(Path(sys.executable).with_name("vr-teleop"))


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_serve_prints_where_it_listens_logs_clients_and_stops_cleanly(sig):
    port = free_port()
    proc = subprocess.Popen([EXE, "serve", "--host", "127.0.0.1", "--port", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        line = proc.stdout.readline()
        assert line.strip() == f"vr-teleop: listening on ws://127.0.0.1:{port}"
        with connect(f"ws://127.0.0.1:{port}") as ws:
            ws.send('{"op": "call_service", "id": 1, "service": "/rosapi/get_time"}')
            assert '"service_response"' in ws.recv(timeout=5)
        proc.send_signal(sig)
        # The timeout only catches a hang; how fast it stops is a speed figure (bench/standin.py).
        assert proc.wait(timeout=60) == 0
        assert proc.stdout.read().splitlines()[-1] == "vr-teleop: stopped"  # the last word, after the server stopped
        log = proc.stderr.read()
        connected = log.index("client connected: /rosbridge_websocket/client_1 from 127.0.0.1")
        assert log.index("client disconnected: /rosbridge_websocket/client_1") > connected  # in that order
    finally:
        if proc.poll() is None:
            proc.kill()


def test_serve_reports_a_busy_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        out = subprocess.run([EXE, "serve", "--port", str(port)], capture_output=True, text=True, timeout=20)
    assert out.returncode == 1
    assert f"cannot listen on 127.0.0.1:{port}" in out.stderr


def serve_parser():
    import argparse

    from vr_teleop_server.cli import build_parser

    return next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices["serve"]


def test_every_marked_setting_is_an_option_with_its_description_choices_and_default():
    from vr_teleop_server.cli.options import cli_fields
    from vr_teleop_server.settings import ServerSettings

    by_dest = {a.dest: a for a in serve_parser()._actions}
    defaults = ServerSettings()
    marked = cli_fields(ServerSettings)
    assert len(marked) >= 30
    for name, field, cli in marked:
        if cli.flag == "":
            assert name not in by_dest  # a secret read from the environment only
            continue
        action = by_dest[name]
        assert action.help.startswith(field.description), name
        if action.nargs != 0 and not isinstance(action.default, list):
            assert action.default == getattr(defaults, name), name
    assert by_dest["backend"].choices == ["sim", "ros", "luxai", "none"]
    assert by_dest["time_style"].choices == ["ros1", "ros2"]
    groups = {g.title: [a.option_strings[0] for a in g._group_actions] for g in serve_parser()._action_groups}
    assert {"--robot-id", "--mqtt-ca-file", "--mqtt-username", "--camera-url"} == set(groups["--backend luxai"])
    assert "--bystander-interval" in groups["--backend sim"]
    assert {"--backend", "--robot-url"} <= set(groups["the robot"])
    robot_url = by_dest["robot_url"].help  # documented per backend, with each backend's default
    from vr_teleop_server.robot.backends import BACKENDS
    real = {b.name: b.default_url for b in BACKENDS.values() if b.default_url}
    assert real and all(f"--backend {b}" in robot_url and url in robot_url for b, url in real.items())


def test_parsed_options_make_the_settings_and_secrets_come_from_the_environment(monkeypatch):
    from vr_teleop_server.cli.options import values_from
    from vr_teleop_server.settings import ServerSettings

    monkeypatch.setenv("VR_TELEOP_TURN_SECRET", "from-env")
    monkeypatch.setenv("VR_TELEOP_MQTT_PASSWORD", "hunter2")
    args = serve_parser().parse_args(["--backend", "luxai", "--robot-url", "mqtt://broker:1883", "--robot-id",
                                      "QTRD000320", "--turn-url", "turn:relay:3478?transport=udp", "--turn-url",
                                      "turns:relay:443?transport=tcp", "--port", "0", "--insecure",
                                      "--time-style", "ros2", "--watchdog-timeout", "0.3", "--deadman-mode", "toggle"])
    settings = ServerSettings(**values_from(ServerSettings, args))
    assert (settings.backend, settings.robot_url, settings.robot_id) == ("luxai", "mqtt://broker:1883", "QTRD000320")
    assert settings.turn_urls == ("turn:relay:3478?transport=udp", "turns:relay:443?transport=tcp")
    assert settings.turn_secret.get_secret_value() == "from-env" and settings.mqtt_password == "hunter2"
    assert (settings.port, settings.insecure, settings.time_style) == (0, True, "ros2")
    assert (args.watchdog_timeout_s, args.deadman_mode) == (0.3, "toggle")
    given = serve_parser().parse_args(["--turn-url", "turn:relay:3478", "--turn-secret", "given"])
    assert ServerSettings(**values_from(ServerSettings, given)).turn_secret.get_secret_value() == "given"
    assert ServerSettings(**values_from(ServerSettings, serve_parser().parse_args([]))) == ServerSettings(
        turn_secret="from-env", mqtt_password="hunter2")  # no option given: the fields' own defaults


def test_a_bad_option_value_is_refused_with_the_fields_rule():
    out = subprocess.run([EXE, "serve", "--port", "70000"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "port" in out.stderr and "65535" in out.stderr
    out = subprocess.run([EXE, "serve", "--backend", "luxai", "--robot-url", "http://robot"], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 2 and "http://robot" in out.stderr


def test_a_busy_port_stops_the_server_before_the_robot_starts():
    """The port is taken first: a server that cannot listen starts neither the stand-in nor a feature."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        server = TeleopServer(ServerSettings(port=s.getsockname()[1]))
        with pytest.raises(OSError, match="address already in use"):
            asyncio.run(server.start())
    assert server.robot is None and server.media is None and not server.features


def test_each_command_line_builds_only_its_own_subcommand():
    """SUBCOMMANDS names exactly what the modules register; `serve` loads none of the study tools' libraries."""
    from vr_teleop_server.cli import SUBCOMMANDS, build_parser

    def commands(parser) -> set[str]:
        return set(next(a for a in parser._actions if a.dest == "command").choices)

    assert commands(build_parser()) == set(SUBCOMMANDS)
    assert all(name in commands(build_parser(name)) for name in SUBCOMMANDS)
    loaded = subprocess.run([sys.executable, "-c", "import sys; from vr_teleop_server.cli import build_parser; "
                             "build_parser('serve'); print(sorted(m for m in ('scipy.stats', 'matplotlib', "
                             "'vr_teleop_server.questionnaires', 'vr_teleop_server.tools.study_runner') "
                             "if m in sys.modules))"], capture_output=True, text=True, check=True)
    assert loaded.stdout.strip() == "[]", loaded.stdout
