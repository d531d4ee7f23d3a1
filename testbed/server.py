"""A real server on a free port, served from a thread of its own (its own event loop), so that blocking clients and a
bench's measuring code can talk to it and look inside it from the caller's thread; and `wait_for`, polling a
condition with a deadline (`until` the same from a coroutine). Used by the tests (tests/support.py's ServerFactory builds on it) and by the benches that
look inside a running server (bench/suite.py's churn, bench/autonomy.py, bench/media.py)."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable
from typing import Any

from vr_teleop_server.app import TeleopServer
from vr_teleop_server.settings import ServerSettings


def wait_for(predicate: Callable[[], Any], timeout: float = 5.0) -> bool:
    """Polls `predicate` until it is true or `timeout` seconds pass."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return False


async def until(predicate: Callable[[], Any], timeout: float, interval: float = 0.02) -> bool:
    """wait_for without blocking the running loop (a peer, a headset or a robot may live on it): polls `predicate`
    every `interval` seconds of the loop until it is true or `timeout` seconds pass, then tries it a last time."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        await asyncio.sleep(interval)
    return bool(predicate())


START_TIMEOUT_S = 90


class RunningServer:
    """A TeleopServer served from a background thread, so that blocking clients (roslibpy, sync websockets)
    can talk to it from the test's thread."""

    def __init__(self, settings: ServerSettings) -> None:
        if "autonomy" not in settings.model_fields_set:
            # Tests run teleoperated unless they ask for autonomy: its attention would keep the stand-in's camera
            # rendering for face detection and move the head in every test (tests/test_autonomy*.py ask).
            settings = settings.model_copy(update={"autonomy": "teleoperated"})
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
