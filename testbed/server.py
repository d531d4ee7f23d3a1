"""The harness's servers, one API for the three ways a test or a bench runs one, each on a free port, with the
tests' defaults (`server_settings`):
- `in_loop(...)`: in the caller's event loop (an async test, a simulated clock's run);
- `RunningServer(settings)` / `ServerFactory`: in a thread of its own (its own loop), so that blocking clients and
  a bench's measuring code can talk to it and look inside it from the caller's thread;
- `processes.serve(...)`: `vr-teleop serve` as a process of its own (a kill, a signal, the command line itself).
And waiting: `wait_for` polls a condition with a deadline, `until` the same from a coroutine; `Pace` paces a
real-time source (a headset's 90 Hz). A check that nothing happens waits for an event the design guarantees after
which it would have happened (a later message, an acknowledgement, a sequence number), never for a time window."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from simclock import WALL, Clock
from testbed.waiting import Pace, until, wait_for  # noqa: F401 (the harness's one import)
from vr_teleop_server.app import TeleopServer
from vr_teleop_server.settings import ServerSettings


def server_settings(settings: ServerSettings | None = None, **overrides: Any) -> ServerSettings:
    """The tests' server: on loopback and a free port (0) unless given, with no robot unless a backend is given,
    and teleoperated unless it asks for autonomy: autonomy's attention would keep the stand-in's camera rendering
    for face detection and move the head in every test (tests/test_autonomy*.py ask)."""
    if settings is None:
        settings = ServerSettings(**{"port": 0, "backend": "none", **overrides})
    elif overrides:
        settings = settings.model_copy(update=overrides)
    if "autonomy" not in settings.model_fields_set:
        settings = settings.model_copy(update={"autonomy": "teleoperated"})
    return settings


@asynccontextmanager
async def in_loop(settings: ServerSettings | None = None, clock: Clock | None = None,
                  **overrides: Any) -> AsyncIterator[TeleopServer]:
    """A server in the caller's event loop (server_settings' defaults), started, and stopped on leaving."""
    async with TeleopServer(server_settings(settings, **overrides), clock or WALL) as server:
        yield server


START_TIMEOUT_S = 90


class RunningServer:
    """A TeleopServer served from a background thread, so that blocking clients (roslibpy, sync websockets)
    can talk to it from the test's thread."""

    def __init__(self, settings: ServerSettings) -> None:
        settings = server_settings(settings)
        self.settings = settings
        self.loop = asyncio.new_event_loop()
        self.server: TeleopServer | None = None
        started = threading.Event()
        self._error: BaseException | None = None

        def run() -> None:
            asyncio.set_event_loop(self.loop)
            try:
                self.server = TeleopServer(settings)
                self.loop.run_until_complete(self.server.start())
            except BaseException as exc:  # surface start-up failures in the test
                self._error = exc
                started.set()
                return
            started.set()
            self.loop.run_forever()

        self.thread = threading.Thread(target=run, name="test-server", daemon=True)
        self.thread.start()
        # The server's own start-up bounds its waits (the stand-in's render process: RenderProcess.START_TIMEOUT_S,
        # 60 s on a loaded machine) and fails with the reason: past those plus slack it hung.
        if not started.wait(START_TIMEOUT_S):
            raise RuntimeError(f"server did not start within {START_TIMEOUT_S} s")
        if self._error is not None:
            raise self._error

    @property
    def url(self) -> str:
        assert self.server is not None
        return self.server.url

    @property
    def port(self) -> int:
        assert self.server is not None
        return self.server.transport.port

    def call(self, fn: Callable[[], Any]) -> Any:
        """Runs `fn` on the server's loop (to inspect its state safely) and returns its result."""
        async def wrapper() -> Any:
            return fn()
        return asyncio.run_coroutine_threadsafe(wrapper(), self.loop).result(10)

    def stop(self) -> None:
        """Stops the server (once: a test may stop it to read its recording before the fixture does)."""
        if not self.thread.is_alive():
            return
        if self.server is not None:
            asyncio.run_coroutine_threadsafe(self.server.stop(), self.loop).result(30)  # a loaded 2-core machine
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)

    def __enter__(self) -> RunningServer:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.stop()


class ServerFactory:
    """Servers in threads for the tests (conftest's `servers` and `module_servers`) and the benches: settings from
    keywords (server_settings'), gestures and audio logs in a directory of the server's own unless given; every
    server it made is stopped by `stop_all`, a test's own `stop` first or not."""

    def __init__(self, tmp: Callable[[str], Path]) -> None:
        self._tmp = tmp  # makes a fresh temporary directory for a server
        self.made: list[RunningServer] = []

    def __call__(self, **overrides: Any) -> RunningServer:
        tmp = self._tmp("server")
        server = RunningServer(server_settings(**{"gesture_dir": tmp / "gestures", "audio_dir": tmp / "audio",
                                                **overrides}))
        self.made.append(server)
        return server

    def stop_all(self) -> None:
        for server in reversed(self.made):
            server.stop()
