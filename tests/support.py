"""Test helpers: a real server on a free port (in its own thread and event loop) and a raw WebSocket client."""

from __future__ import annotations

import asyncio
import json
import threading
import time
from collections.abc import Callable
from typing import Any

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

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


class RunningServer:
    """A TeleopServer served from a background thread, so that blocking clients (roslibpy, sync websockets)
    can talk to it from the test's thread."""

    def __init__(self, settings: ServerSettings) -> None:
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
        if not started.wait(30):
            raise RuntimeError("server did not start within 30 s")
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
        if self.server is not None:
            asyncio.run_coroutine_threadsafe(self.server.stop(), self.loop).result(10)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)


class RawClient:
    """A plain WebSocket client speaking rosbridge JSON by hand, to assert exact replies."""

    def __init__(self, url: str) -> None:
        self.ws: ClientConnection = connect(url, compression=None, max_size=None, open_timeout=10).__enter__()

    def send(self, message: dict[str, Any]) -> None:
        self.ws.send(json.dumps(message))

    def send_raw(self, frame: str | bytes) -> None:
        self.ws.send(frame)

    def recv_frame(self, timeout: float = 3.0) -> str | bytes:
        return self.ws.recv(timeout=timeout)

    def recv(self, timeout: float = 3.0) -> dict[str, Any]:
        frame = self.recv_frame(timeout)
        assert isinstance(frame, str), f"expected a TEXT frame, got {len(frame)} binary bytes"
        return json.loads(frame)

    def expect(self, op: str, timeout: float = 3.0, **fields: Any) -> dict[str, Any]:
        """The next message with this op (and these field values); fails on anything else in between."""
        message = self.recv(timeout)
        assert message.get("op") == op, f"expected op {op!r}, got {message}"
        for key, value in fields.items():
            assert message.get(key) == value, f"expected {key}={value!r} in {message}"
        return message

    def silent(self, duration: float = 0.3) -> bool:
        """True when nothing arrives for `duration` seconds."""
        try:
            frame = self.ws.recv(timeout=duration)
        except TimeoutError:
            return True
        raise AssertionError(f"expected silence, got {frame!r}")

    def alive(self, topic: str = "/alive_check") -> None:
        """Proves the connection still works: a publish this client makes comes back to it."""
        self.send({"op": "subscribe", "id": "alive", "topic": topic, "type": "std_msgs/String"})
        self.send({"op": "publish", "topic": topic, "msg": {"data": "still here"}})
        deadline = time.monotonic() + 3
        while time.monotonic() < deadline:
            message = self.recv()
            if message.get("op") == "publish" and message.get("topic") == topic:
                assert message["msg"] == {"data": "still here"}
                self.send({"op": "unsubscribe", "id": "alive", "topic": topic})
                return
        raise AssertionError("the connection no longer delivers messages")

    def close(self) -> None:
        try:
            self.ws.close()
        except ConnectionClosed:
            pass
