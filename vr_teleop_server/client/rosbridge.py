"""A rosbridge v2 client over a WebSocket, or over any connection shaped like one (`await send(frame)`,
`async for frame in connection`, `await close()`): the server's in-process connection
(`WebSocketTransport.connect_local`) is one, so a replay or a study on the simulated clock runs the same client.

Nothing here sleeps on the wall clock: every wait is on a message, a response or a timeout of the running loop,
which on a simulated loop is simulated time.

The refusal rule lives here once (`outcome`): a call the server could not run comes back with `result: false`
(`CallFailed`); a call it ran and refused comes back as a successful response whose values say `success: false`
(or LuxAI's `status: false`) with the reason in `message` (`Refused`).
"""

from __future__ import annotations

import asyncio
import itertools
import json
import logging
from collections.abc import AsyncIterator, Callable
from typing import Any, Protocol

from pydantic import ValidationError
from pydantic_core import from_json
from websockets.asyncio.client import connect as open_websocket
from websockets.exceptions import ConnectionClosed

from client_protocol import names
from client_protocol.interface import ENDPOINTS
from client_protocol.registry import TypeRegistry, describe_validation_error

log = logging.getLogger(__name__)
Message = dict[str, Any]
Callback = Callable[[Message], None]
Match = Callable[[Message], bool]
CALL_TIMEOUT_S = 10.0
# The service type of each call the interface lists, so that a call's response is validated without being told.
SERVICE_TYPES = {e.name: e.type for e in ENDPOINTS if e.direction == "call"}


class RosbridgeError(RuntimeError):
    """A call that did not do what was asked; `message` says why, `values` is what the server answered."""

    def __init__(self, service: str, message: str, values: Any = None) -> None:
        super().__init__(f"{service}: {message}" if service else message)
        self.service = service
        self.message = message
        self.values = values


class CallFailed(RosbridgeError):
    """rosbridge's own failure (`result: false`): no such service, arguments of the wrong type, the service failed."""


class Refused(RosbridgeError):
    """The service ran and said no: a successful response with `success: false` (or `status: false`)."""


def outcome(response: Message, service: str = "") -> Any:
    """The values of a `service_response` frame; raises Refused or CallFailed when it says the call did not do
    what was asked. The one place the refusal rule is written."""
    values = response.get("values")
    if not response.get("result", False):
        raise CallFailed(service, values if isinstance(values, str) else json.dumps(values), values)
    if isinstance(values, dict) and (values.get("success") is False or values.get("status") is False):
        raise Refused(service, str(values.get("message") or "refused"), values)
    return values


class Connection(Protocol):
    async def send(self, frame: str | bytes) -> None: ...

    def __aiter__(self) -> AsyncIterator[str | bytes]: ...

    async def close(self) -> None: ...


class Subscription:
    """One subscription's messages. With a callback, each message goes to it as it arrives; without one they
    wait here to be read, by `async for message in subscription` or `await subscription.next(match)`, which both
    take the oldest unread message first (so a test that subscribes, then acts, then reads misses nothing)."""

    def __init__(self, client: Client, topic: str, type_name: str | None, callback: Callback | None) -> None:
        self.client = client
        self.topic = topic
        self.type = type_name
        self.callback = callback
        self.latest: Message | None = None
        self.count = 0
        self._unread: asyncio.Queue[Message | None] | None = asyncio.Queue() if callback is None else None
        self._waiters: list[tuple[Match | None, asyncio.Future[Message]]] = []

    def _deliver(self, msg: Message) -> None:
        self.latest = msg
        self.count += 1
        if self.callback is not None:
            try:
                self.callback(msg)
            except Exception:  # one bad handler must not stop the client's reading
                log.exception("the callback of %s failed", self.topic)
            for waiter in [w for w in self._waiters if not w[1].done() and (w[0] is None or w[0](msg))]:
                waiter[1].set_result(msg)
        else:
            self._unread.put_nowait(msg)

    def _end(self) -> None:
        if self._unread is not None:
            self._unread.put_nowait(None)
        for _match, future in self._waiters:
            if not future.done():
                future.set_exception(ConnectionError(f"{self.topic}: the connection closed"))

    async def next(self, match: Match | None = None, timeout: float = CALL_TIMEOUT_S) -> Message:
        """The next message (that `match` accepts, when given); raises TimeoutError after `timeout` seconds of
        the running loop's clock."""
        async with asyncio.timeout(timeout):
            if self._unread is None:  # a callback takes the messages: wait for one still to come
                future: asyncio.Future[Message] = asyncio.get_running_loop().create_future()
                waiter = (match, future)
                self._waiters.append(waiter)
                try:
                    return await future
                finally:
                    self._waiters.remove(waiter)
            while True:
                msg = await self._unread.get()
                if msg is None:
                    self._unread.put_nowait(None)
                    raise ConnectionError(f"{self.topic}: the connection closed")
                if match is None or match(msg):
                    return msg

    def __aiter__(self) -> AsyncIterator[Message]:
        return self._iterate()

    async def _iterate(self) -> AsyncIterator[Message]:
        assert self._unread is not None, "a subscription with a callback is not iterated"
        while (msg := await self._unread.get()) is not None:
            yield msg
        self._unread.put_nowait(None)

    async def unsubscribe(self) -> None:
        await self.client.unsubscribe(self)


class Client:
    """A rosbridge v2 client on `connection`; made in a coroutine (it starts reading at once). `async with` closes
    it. Service calls: `call` (the validated response values, or Refused/CallFailed); publish: `advertise` then
    `publish`; topics: `subscribe` (a Subscription). `statuses` keeps the server's status messages (and
    `on_status` sees each); `on_binary` sees binary frames (CBOR or pose frames), which are otherwise dropped."""

    def __init__(self, connection: Connection, *, id_prefix: str = "client") -> None:
        self.connection = connection
        self.id_prefix = id_prefix
        self.statuses: list[Message] = []
        self.on_status: Callback | None = None
        self.on_binary: Callable[[bytes], None] | None = None
        self._ids = itertools.count(1)
        self._calls: dict[str, asyncio.Future[Message]] = {}
        self._call_errors: dict[str, str] = {}  # call id -> a status error the server sent about that call
        self._topics: dict[str, list[Subscription]] = {}
        self._registry: TypeRegistry | None = None
        self.closed = False
        self._reader = asyncio.get_running_loop().create_task(self._read())

    # ---- sending -------------------------------------------------------------------------------------------
    async def send(self, frame: Message | str | bytes) -> None:
        """One frame as it is (a dict goes as its JSON): for what the methods below do not say."""
        await self.connection.send(frame if isinstance(frame, (str, bytes)) else json.dumps(frame))

    async def advertise(self, topic: str, type_name: str) -> None:
        await self.send({"op": "advertise", "topic": topic, "type": type_name})

    async def unadvertise(self, topic: str) -> None:
        await self.send({"op": "unadvertise", "topic": topic})

    async def publish(self, topic: str, msg: Message) -> None:
        await self.connection.send(json.dumps({"op": "publish", "topic": topic, "msg": msg}))

    async def subscribe(self, topic: str, type_name: str | None = None, callback: Callback | None = None,
                        **options: Any) -> Subscription:
        """Subscribes (`options`: rosbridge's queue_length, throttle_rate, compression...). The server has the
        subscription once a later frame of this client's is answered: `await client.sync()` when it matters."""
        subscription = Subscription(self, topic, type_name, callback)
        self._topics.setdefault(topic, []).append(subscription)
        frame: Message = {"op": "subscribe", "topic": topic, **options}
        if type_name is not None:
            frame["type"] = type_name
        await self.send(frame)
        return subscription

    async def unsubscribe(self, subscription: Subscription) -> None:
        """Ends one subscription; the server's ends with the topic's last one of this client."""
        subscriptions = self._topics.get(subscription.topic, [])
        if subscription in subscriptions:
            subscriptions.remove(subscription)
            subscription._end()
        if not subscriptions:
            self._topics.pop(subscription.topic, None)
            await self.send({"op": "unsubscribe", "topic": subscription.topic})

    async def request(self, service: str, args: Message | None = None, *, call_id: str | None = None
                      ) -> asyncio.Future[Message]:
        """Sends a call and returns at once the future of its `service_response` frame (for callers that keep
        sending meanwhile, in order); `outcome(response, service)` reads it."""
        call_id = call_id or f"{self.id_prefix}:{next(self._ids)}"
        future: asyncio.Future[Message] = asyncio.get_running_loop().create_future()
        self._calls[call_id] = future
        future.add_done_callback(lambda _f: self._calls.pop(call_id, None))
        future.add_done_callback(lambda _f: self._call_errors.pop(call_id, None))
        if self.closed:
            future.set_exception(ConnectionError("the connection is closed"))
            return future
        await self.send({"op": "call_service", "id": call_id, "service": service, "args": args or {}})
        return future

    async def call(self, service: str, args: Message | None = None, *, type_name: str | None = None,
                   timeout: float = CALL_TIMEOUT_S) -> Message:
        """The service's response values, validated against its response type (`type_name`, or the interface's
        type of that service; values of a service the client knows no type of come as they are). Raises
        Refused, CallFailed, or TimeoutError after `timeout` seconds of the loop's clock."""
        call_id = f"{self.id_prefix}:{next(self._ids)}"
        future = await self.request(service, args, call_id=call_id)
        try:
            async with asyncio.timeout(timeout):
                response = await asyncio.shield(future)  # still pending after a timeout: its status read below
        except TimeoutError:
            # A frame the server could not take as a call (a malformed one, too many calls in progress) is
            # answered by a status error with its id only.
            error = self._call_errors.get(call_id)
            future.cancel()
            if error is not None:
                raise CallFailed(service, error) from None
            raise TimeoutError(f"{service}: no answer within {timeout:g} s") from None
        values = outcome(response, service)
        type_name = type_name or SERVICE_TYPES.get(service)
        if type_name is None:
            return values if isinstance(values, dict) else {}
        registry = self.registry()
        if not registry.is_known_service(type_name):
            return values if isinstance(values, dict) else {}
        try:
            return registry.codec(registry.service_parts(type_name)[1]).validate(values or {})
        except ValidationError as exc:
            raise CallFailed(service, f"the response is not a {type_name} response: "
                             f"{describe_validation_error(exc)}", values) from None

    async def sync(self, timeout: float = CALL_TIMEOUT_S) -> None:
        """Returns once the server has handled every frame sent before (it handles a client's frames in order,
        and answers this call after them): subscriptions and advertisements are in place."""
        await self.call(names.ROSAPI_GET_TIME_SERVICE, timeout=timeout)

    def registry(self) -> TypeRegistry:
        """The message types (client_protocol/definitions.py), built on first use."""
        if self._registry is None:
            self._registry = TypeRegistry()
        return self._registry

    # ---- receiving -----------------------------------------------------------------------------------------
    async def _read(self) -> None:
        try:
            async for frame in self.connection:
                if isinstance(frame, bytes):
                    if self.on_binary is not None:
                        self.on_binary(frame)
                    continue
                self._dispatch(from_json(frame))  # pydantic-core's parser: half json.loads' time a frame
        except (ConnectionClosed, ConnectionError):
            pass  # the connection ended, as when the iteration ends
        finally:
            self._ended()

    def _dispatch(self, message: Message) -> None:
        op = message.get("op")
        if op == "publish":
            for subscription in self._topics.get(message.get("topic", ""), ()):
                subscription._deliver(message["msg"])
        elif op == "service_response":
            future = self._calls.get(str(message.get("id")))
            if future is not None and not future.done():
                future.set_result(message)
        elif op == "status":
            self.statuses.append(message)
            if message.get("level") == "error" and str(message.get("id")) in self._calls:
                self._call_errors[str(message.get("id"))] = str(message.get("msg", ""))
            if self.on_status is not None:
                self.on_status(message)
        elif op is None:
            log.warning("a frame without an op: %.200s", message)

    def _ended(self) -> None:
        self.closed = True
        for future in list(self._calls.values()):
            if not future.done():
                future.set_exception(ConnectionError("the connection closed before the answer"))
        for subscriptions in self._topics.values():
            for subscription in subscriptions:
                subscription._end()

    async def wait_closed(self) -> None:
        """Returns when the server has closed the connection (or `close` did)."""
        await asyncio.shield(self._reader)

    async def close(self) -> None:
        self._reader.cancel()
        try:
            await self._reader
        except asyncio.CancelledError:
            pass
        await self.connection.close()

    async def __aenter__(self) -> Client:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()


async def connect(url: str, **options: Any) -> Client:
    """A Client over a new WebSocket to `url` (`options`: Client's id_prefix)."""
    websocket = await open_websocket(url, max_size=None, compression=None, open_timeout=10)
    return Client(websocket, **options)
