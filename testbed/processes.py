"""Servers as processes of their own, for the benches and the tests: a free port, the environment a process runs in,
a command started and waited for until it says it is listening, `vr-teleop serve` on a port of its own, and a stop
that waits, then kills."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def free_port() -> int:
    """A TCP port on loopback that nothing listens on right now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def environment(**extra: str) -> dict[str, str]:
    """The environment of a process a test or bench starts: this one's (importing testbed set MUJOCO_GL), with this
    checkout first on PYTHONPATH (a worktree's code is what runs, whatever is installed), and `extra`."""
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    return {**os.environ, "PYTHONPATH": path, **extra}


def start(cmd: list[str], env: dict[str, str] | None = None, stderr: int | None = None) -> subprocess.Popen:
    """Runs `cmd` from the repository's root (in `environment()` unless `env` is given) and returns once its first
    line says it is listening (a server or bench/relay.py); kills it and raises otherwise. Its stdout (and its
    stderr, with `stderr=subprocess.PIPE`) is the caller's to read on."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=stderr, text=True, cwd=ROOT, env=env or environment())
    line = proc.stdout.readline()  # "... listening on ..."
    if "listening" not in line:
        proc.kill()
        raise RuntimeError(f"{' '.join(cmd[1:5])} did not start: {line!r}")
    return proc


def serve(*args: str, log_level: str = "error", env: dict[str, str] | None = None,
          stderr: int | None = None) -> subprocess.Popen:
    """`vr-teleop serve` (this interpreter's) on a free port with `args`, in `environment(**env)`; the process has
    `port` and `url`."""
    port = free_port()
    proc = start([sys.executable, "-m", "vr_teleop_server.cli", "serve", "--port", str(port), "--log-level", log_level,
                  *args], env=environment(**(env or {})), stderr=stderr)
    proc.port = port  # type: ignore[attr-defined]
    proc.url = f"ws://127.0.0.1:{port}"  # type: ignore[attr-defined]
    return proc


def stop(proc: subprocess.Popen, timeout: float = 10.0) -> None:
    """Asks the process to end (SIGTERM), and kills it after `timeout` seconds."""
    proc.terminate()
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
