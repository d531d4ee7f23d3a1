"""A worker process behind a socket pair, for work that must not share the server's GIL or CPU priority.

The stand-in's renderer (sim/render_process.py) and the WebRTC video encoders (vr_teleop_server/media/
encoder_process.py) each run in one. The parent starts the worker with subprocess (multiprocessing's spawn would
leave a resource-tracker process behind for the server's life) and talks to it over a socket pair with
multiprocessing.connection's framing (pickles): first `(nice, hello)`, answered `(True, None)` when the worker is
ready, then one request at a time, each answered `(True, value)` or `(False, why)` (the request failed; the worker
lives on). The worker exits when its socket closes, so it cannot outlive its parent; a worker that dies, or stays
silent past a timeout (then killed), is the subclass's `Died` error.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any


class WorkerDied(RuntimeError):
    """The worker process died, hung or could not start."""


class WorkerProcess:
    """Parent side. Not thread-safe: one thread makes every call."""

    NAME = "the worker process"  # how errors name it
    START_TIMEOUT_S = 60.0
    REPLY_TIMEOUT_S = 30.0
    Died: type[WorkerDied] = WorkerDied

    def __init__(self, boot: str, args: list[str], nice: int, hello: tuple, pass_fds: tuple[int, ...] = ()) -> None:
        """Run `python -c boot *args FD`, FD the worker's end of the socket pair, and wait until it is ready.
        `pass_fds` reach the worker under the same numbers (a frame_ring.FrameRing's, say)."""
        ours, theirs = socket.socketpair()
        try:
            self.process = subprocess.Popen([sys.executable, "-c", boot, *args, str(theirs.fileno())],
                                            pass_fds=(theirs.fileno(), *pass_fds), stdin=subprocess.DEVNULL,
                                            stdout=subprocess.DEVNULL, close_fds=True)
        except BaseException:
            ours.close()
            raise
        finally:
            theirs.close()
        self._conn = Connection(ours.detach())
        try:
            self._conn.send((int(nice), hello))
            self._reply(self.START_TIMEOUT_S)
        except BaseException:
            self.close()
            raise

    @property
    def pid(self) -> int:
        return self.process.pid

    def call(self, request: Any) -> Any:
        """The worker's answer to `request`; `failed(why)` if it could not answer it, `Died` if it is gone."""
        try:
            self._conn.send(request)
        except (OSError, ValueError) as exc:
            raise self._died(exc) from exc
        return self._reply(self.REPLY_TIMEOUT_S)

    def failed(self, why: str) -> Exception:
        """What a request the worker answered with a failure raises (the worker lives on)."""
        return RuntimeError(why)

    def close(self, timeout: float = 5.0) -> None:
        """Close the socket (the worker exits on it), then wait; kill the worker past `timeout`."""
        try:
            self._conn.close()
        except OSError:
            pass
        try:
            self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()

    def _reply(self, timeout: float) -> Any:
        try:
            if not self._conn.poll(timeout):
                self.process.kill()
                raise self.Died(f"{self.NAME} (pid {self.pid}) did not answer within {timeout:g} s and was killed")
            ok, value = self._conn.recv()
        except (EOFError, OSError, ValueError) as exc:
            raise self._died(exc) from exc
        if not ok:
            raise self.failed(value)
        return value

    def _died(self, exc: BaseException) -> WorkerDied:
        code = self.process.poll()
        if code is None:
            time.sleep(0.1)
            code = self.process.poll()
        return self.Died(f"{self.NAME} (pid {self.pid}) exited (code {code}): {exc!r}")


# ---- the worker's side ---------------------------------------------------------------------------------------
def accept(fd: int) -> tuple[Connection, tuple]:
    """Worker: take the parent's socket, lower this process's priority as asked, and return the hello. Ctrl-C
    reaches the whole process group: the parent stops the worker, so the worker ignores it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    conn = Connection(fd)
    nice, hello = conn.recv()
    os.nice(nice)
    return conn, hello


def answer(conn: Connection, handle: Callable[[Any], Any]) -> None:
    """Worker: tell the parent it is ready, then answer its requests in order until the socket closes."""
    conn.send((True, None))
    while True:
        try:
            request = conn.recv()
        except (EOFError, OSError):
            return
        try:
            reply = (True, handle(request))
        except Exception as exc:
            reply = (False, f"{type(exc).__name__}: {exc}")
        conn.send(reply)
