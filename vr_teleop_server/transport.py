"""The WebSocket transport: accepts connections and moves frames between sockets and sessions.

It holds no protocol logic, so sessions are testable without sockets.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
from collections.abc import Callable

from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.exceptions import ConnectionClosed

from .session import Session
from .settings import ServerSettings

log = logging.getLogger(__name__)


class WebSocketTransport:
    def __init__(self, settings: ServerSettings, open_session: Callable[[str, str], Session],
                 close_session: Callable[[Session], None]) -> None:
        self.settings = settings
        self._open_session = open_session
        self._close_session = close_session
        self._server: Server | None = None
        self._numbers = itertools.count(1)

    async def start(self) -> None:
        self._server = await serve(
            self._handle, self.settings.host, self.settings.port,
            max_size=self.settings.max_frame_size,
            compression=None,  # deflate costs CPU on every pose and gains nothing on JPEG frames
            close_timeout=0.5,
            ping_interval=20, ping_timeout=20,
        )

    @property
    def port(self) -> int:
        assert self._server is not None, "the transport has not started"
        return self._server.sockets[0].getsockname()[1]

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close(close_connections=True)
            await self._server.wait_closed()

    async def _handle(self, ws: ServerConnection) -> None:
        peer = "%s:%s" % ws.remote_address[:2] if ws.remote_address else "?"
        session = self._open_session(f"/rosbridge_websocket/client_{next(self._numbers)}", peer)
        log.info("client connected: %s from %s", session.name, peer)
        writer = asyncio.create_task(self._write(ws, session))
        try:
            async for frame in ws:
                await session.handle_frame(frame)
        except ConnectionClosed:
            pass
        finally:
            writer.cancel()
            self._close_session(session)
            code = ws.close_code
            log.info("client disconnected: %s from %s (code %s)", session.name, peer, code)

    @staticmethod
    async def _write(ws: ServerConnection, session: Session) -> None:
        try:
            while True:
                for frame in await session.next_frames():
                    await ws.send(frame)
        except ConnectionClosed:
            pass
