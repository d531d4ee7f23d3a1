"""`vr-teleop serve` as a user runs it: one line saying where it listens, connections logged, clean stop."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from websockets.sync.client import connect

EXE = shutil.which("vr-teleop") or str(Path(sys.executable).with_name("vr-teleop"))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_serve_prints_where_it_listens_logs_clients_and_stops_within_a_second(sig):
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
        time.sleep(0.2)
        proc.send_signal(sig)
        start = time.monotonic()
        proc.wait(timeout=5)
        assert time.monotonic() - start < 1.0
        assert proc.returncode == 0
        log = proc.stderr.read()
        assert "client connected: /rosbridge_websocket/client_1 from 127.0.0.1" in log
        assert "client disconnected: /rosbridge_websocket/client_1" in log
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
