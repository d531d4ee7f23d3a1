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
from websockets.sync.client import connect

from vr_teleop_server.app import TeleopServer
from vr_teleop_server.settings import ServerSettings

EXE = shutil.which("vr-teleop") or str(Path(sys.executable).with_name("vr-teleop"))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


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
