"""The composition root: builds the server's parts from one settings object and starts and stops them."""

from __future__ import annotations

import logging

from client_protocol.registry import TypeRegistry

from .bus import Bus
from .rosapi import RosApi
from .session import Session
from .settings import ServerSettings
from .transport import WebSocketTransport

log = logging.getLogger(__name__)


class TeleopServer:
    def __init__(self, settings: ServerSettings) -> None:
        self.settings = settings
        self.registry = TypeRegistry(time_style=settings.time_style)
        self.bus = Bus(self.registry)
        self.sessions: dict[str, Session] = {}
        self.rosapi = RosApi(self.bus)
        self.transport = WebSocketTransport(settings, self._open_session, self._close_session)

    def _open_session(self, name: str, peer: str) -> Session:
        session = Session(name, self.bus, self.settings, peer)
        self.sessions[name] = session
        return session

    def _close_session(self, session: Session) -> None:
        session.close()
        self.sessions.pop(session.name, None)

    async def start(self) -> None:
        self.rosapi.start()
        await self.transport.start()

    async def stop(self) -> None:
        await self.transport.stop()
        for session in list(self.sessions.values()):
            self._close_session(session)

    @property
    def url(self) -> str:
        return f"ws://{self.settings.host}:{self.transport.port}"

    async def __aenter__(self) -> "TeleopServer":
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()
