"""The WebSocket transport: accepts connections and moves frames between sockets and sessions, and serves the
dashboard's static files over plain HTTP on the same port (a GET that is not a WebSocket upgrade).

It holds no protocol logic, so sessions are testable without sockets.
"""

from __future__ import annotations

import asyncio
import functools
import itertools
import logging
import mimetypes
import re
import ssl
import weakref
from collections.abc import AsyncIterator, Awaitable, Callable
from http import HTTPStatus
from pathlib import Path

from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.datastructures import Headers
from websockets.exceptions import ConnectionClosed
from websockets.protocol import State
from websockets.http11 import Request, Response

from .access import AccessDenied, AccessPolicy, Login
from .session import Session
from .settings import CoreSettings

log = logging.getLogger(__name__)
Ping = Callable[[], Awaitable[float]]  # one WebSocket ping: its round trip in seconds
WEB_ROOT = Path(__file__).parent.parent / "web"
PAGES = {"": "index.html", "/operator": "operator.html",  # the dashboard, and the headset's page
         "/participant": "participant.html"}  # a live study's participant: their questionnaires


class WebSocketTransport:
    def __init__(self, settings: CoreSettings, open_session: Callable[[str, str, Ping], Session],
                 close_session: Callable[[Session], None], policy: AccessPolicy | None = None) -> None:
        self.settings = settings
        self.policy = policy if policy is not None else AccessPolicy({})
        self._logins: weakref.WeakKeyDictionary[ServerConnection, Login] = weakref.WeakKeyDictionary()  # what each handshake said, until its handler runs
        self._open_session = open_session
        self._close_session = close_session
        self._server: Server | None = None
        self._numbers = itertools.count(1)
        self._open: set[ServerConnection] = set()  # connections whose handler runs, closing ones included

    async def bind(self) -> None:
        """Takes the address (OSError when it is in use, or the TLS files cannot be read) without accepting yet:
        a server checks its port before it starts anything slow, and clients are refused until start()."""
        if self._server is not None:
            return
        tls = None
        if self.settings.certfile is not None:
            tls = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
            tls.load_cert_chain(self.settings.certfile, self.settings.keyfile)
        self._server = await serve(
            self._handle, self.settings.host, self.settings.port,
            process_request=self._http, ssl=tls,
            max_size=self.settings.max_frame_size,
            compression=None,  # deflate costs CPU on every pose and gains nothing on JPEG frames
            close_timeout=0.5,
            ping_interval=20, ping_timeout=20,
            logger=_websockets_logger(),
            start_serving=False,
        )

    async def start(self) -> None:
        """Binds (if bind() was not called) and accepts connections."""
        await self.bind()
        await self._server.start_serving()

    def _http(self, connection: ServerConnection, request: Request) -> Response | None:
        """Static files for a plain GET; None lets a WebSocket upgrade through, once its URL's token (or
        Authorization header) and query are read: a wrong token is refused here with 401."""
        if "websocket" in request.headers.get("Upgrade", "").lower():
            try:
                self._logins[connection] = self.policy.login(request.path, request.headers.get("Authorization"))
            except AccessDenied as exc:
                log.warning("handshake from %s refused (401): %s", _peer(connection), exc)
                return _response(HTTPStatus.UNAUTHORIZED, f"{exc}\n".encode(), "text/plain")
            except ValueError as exc:
                log.warning("handshake from %s refused (400): %s", _peer(connection), exc)
                return _response(HTTPStatus.BAD_REQUEST, f"{exc}\n".encode(), "text/plain")
            return None
        path = request.path.split("?", 1)[0].split("#", 1)[0]
        relative = PAGES.get(path.rstrip("/"), path.lstrip("/"))
        target = (WEB_ROOT / relative).resolve()
        if WEB_ROOT.resolve() not in target.parents or not target.is_file():
            return _response(HTTPStatus.NOT_FOUND, b"not found\n", "text/plain")
        kind = mimetypes.guess_type(target.name)[0] or "application/octet-stream"
        return _response(HTTPStatus.OK, target.read_bytes(), kind)

    @property
    def port(self) -> int:
        assert self._server is not None, "the transport has not started"
        return self._server.sockets[0].getsockname()[1]

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close(close_connections=True)
            try:
                await asyncio.wait_for(self._server.wait_closed(), 2.0)
            except TimeoutError:
                # A client that stopped reading never takes its close frame (the socket's buffers are full), and
                # would hold the shutdown forever: drop such connections.
                for connection in list(self._open):
                    connection.transport.abort()
                await self._server.wait_closed()

    async def _handle(self, ws: ServerConnection) -> None:
        peer = _peer(ws)
        session = self._open_session(f"/rosbridge_websocket/client_{next(self._numbers)}", peer, lambda: _ping(ws))
        session.apply_login(self._logins.pop(ws, Login()))
        log.info("client connected: %s from %s", session.name, peer)
        writer = asyncio.create_task(self._write(ws, session))
        self._open.add(ws)
        try:
            async for frame in ws:
                pending = session.receive(frame)  # handle_frame, without a coroutine when nothing waits
                if pending is not None:
                    await pending
        except ConnectionClosed:
            pass
        finally:
            self._open.discard(ws)
            writer.cancel()
            self._close_session(session)
            code = ws.close_code
            log.info("client disconnected: %s from %s (code %s)", session.name, peer, code)

    def connect_local(self, path: str = "/", peer: str = "in-process") -> LocalConnection:
        """A connection from inside this process (replays and studies at `--speed max`, on a simulated clock): the
        same session, login and frames as a WebSocket client's, without a socket. `path` is what a client's URL
        would say (`/?token=...`)."""
        session = self._open_session(f"/rosbridge_websocket/client_{next(self._numbers)}", peer, _no_ping)
        session.apply_login(self.policy.login(path, None))
        log.info("client connected: %s (%s)", session.name, peer)
        return LocalConnection(session, self._close_session)

    @staticmethod
    async def _write(ws: ServerConnection, session: Session) -> None:
        session.outbox.write_now = functools.partial(_write_now, ws)
        try:
            while True:
                frames = await session.next_frames()
                if len(frames) > 1:
                    await _send_batch(ws, session, frames)
                    continue
                try:
                    await ws.send(frames[0])
                except (TypeError, ValueError):  # a frame that cannot be sent must not end the stream
                    log.exception("%s: a frame could not be sent and was dropped", session.name)
        except ConnectionClosed:
            pass


def _write_now(ws: ServerConnection, frame: str | bytes) -> bool:
    """Writes one frame to the socket in the caller's turn of the loop, as websockets' broadcast does, when nothing
    is waiting to go out (else False: the writer task sends it, with websockets' flow control)."""
    if ws.protocol.state is not State.OPEN or ws.send_in_progress is not None \
            or ws.transport.get_write_buffer_size():
        return False
    try:
        if isinstance(frame, str):
            ws.protocol.send_text(frame.encode("utf-8"))
        else:
            ws.protocol.send_binary(frame)
    except Exception:  # not taken: the writer task sends it and reports what is wrong
        return False
    try:
        ws.send_data()
    except OSError:  # the connection is failing: its reader ends the session
        pass
    return True


async def _send_batch(ws: ServerConnection, session: Session, frames: list[str | bytes]) -> None:
    """Several frames in one write to the socket: one system call instead of one per frame, which was the
    largest single cost of a busy connection (py-spy). Flow control and closing are websockets' own."""
    async with ws.send_context():
        for frame in frames:
            try:
                if isinstance(frame, str):
                    ws.protocol.send_text(frame.encode("utf-8"))
                else:
                    ws.protocol.send_binary(frame)
            except (TypeError, ValueError):  # a frame that cannot be sent must not end the stream
                log.exception("%s: a frame could not be sent and was dropped", session.name)
        data = b"".join(ws.protocol.data_to_send())
        if data:
            ws.transport.write(data)


class LocalConnection:
    """An in-process client's end of a session, shaped like a websockets connection: `await send(frame)`, and
    `async for frame in connection` for what the server sends. Frames in are handled in order, as the socket's
    handler does, but in the sender's task: `send` returns once the session has handled the frame (its handlers
    never wait on the client), which spares a queue and a turn of the loop per frame. Frames out are the session's
    outbox, as the socket's writer takes them."""

    def __init__(self, session: Session, close_session: Callable[[Session], None]) -> None:
        self.session = session
        self._close_session = close_session
        self._order = asyncio.Lock()  # senders in several tasks: one frame at a time, in the order they came
        self.closed = False

    async def send(self, frame: str | bytes) -> None:
        if self.closed:
            raise ConnectionError(f"{self.session.name} is closed")
        async with self._order:
            await self.session.handle_frame(frame)

    async def __aiter__(self) -> AsyncIterator[str | bytes]:
        while not self.closed:
            for frame in await self.session.next_frames():
                yield frame

    async def close(self) -> None:
        """Closes the session (as a client's close frame would), after the frame being handled, if any."""
        if self.closed:
            return
        async with self._order:
            self.closed = True
            self._close_session(self.session)

    async def __aenter__(self) -> LocalConnection:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()


async def _no_ping() -> float:
    return 0.0  # no network between an in-process client and the server


def _websockets_logger() -> logging.Logger:
    """websockets' server logger with the token filter on it (added once: a filter, not module state)."""
    logger = logging.getLogger("websockets.server")
    if not any(isinstance(f, RedactSecrets) for f in logger.filters):
        logger.addFilter(RedactSecrets())
    return logger


def _peer(ws: ServerConnection) -> str:
    return "%s:%s" % ws.remote_address[:2] if ws.remote_address else "?"


class RedactSecrets(logging.Filter):
    """Keeps tokens out of websockets' own log lines (its debug log shows each request line and header)."""

    _SECRET = re.compile(r"((?:token|mac)=)[^&\s]*|(authorization:\s*\S+\s+)\S+", re.IGNORECASE)

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        redacted = self._SECRET.sub(lambda m: (m.group(1) or m.group(2)) + "***", text)
        if redacted != text:
            record.msg, record.args = redacted, ()
        return True


async def _ping(ws: ServerConnection) -> float:
    """One WebSocket ping; its pong's round trip in seconds (for the link telemetry)."""
    return await (await ws.ping())


def _response(status: HTTPStatus, body: bytes, kind: str) -> Response:
    headers = Headers({"Content-Type": f"{kind}; charset=utf-8" if kind.startswith("text/") or kind.endswith(
        "javascript") else kind, "Content-Length": str(len(body)), "Cache-Control": "no-cache",
        "X-Content-Type-Options": "nosniff"})
    return Response(status.value, status.phrase, headers, body)
