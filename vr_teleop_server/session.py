"""One client's rosbridge session: parses each frame, dispatches it by op, and keeps what the client owns.

A handler per op (as rosbridge_suite's capabilities, without their globals). Errors become `status` replies that
name the problem and echo the operation's `id`; the connection always goes on. Outgoing messages wait in a
bounded outbox that the transport drains: a client that reads slowly loses its oldest messages per
subscription, and never slows a publisher or another client.
"""

from __future__ import annotations

import asyncio
import itertools
import json
import logging
import math
import time
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel, ValidationError

from client_protocol import ops
from client_protocol.registry import describe_validation_error

from .access import AccessDenied, AccessPolicy, Role
from .bus import GOAL_STATUS_ABORTED, Bus, BusError, GoalHandle, Published
from .settings import ServerSettings
from .wire import FrameError, decode_frame, dumps, encode_for_client, png_pack, publish_cbor, publish_text, \
    split_fragments

log = logging.getLogger(__name__)

LEVELS = {"info": 0, "warning": 1, "error": 2, "none": 3}
Frame = str | bytes


class ProtocolError(Exception):
    def __init__(self, message: str, level: str = "error") -> None:
        super().__init__(message)
        self.level = level


def json_value(value: Any) -> Any:
    return value.model_dump(mode="json", by_alias=True) if isinstance(value, BaseModel) else value


@dataclass(frozen=True)
class SubscriptionRequest:
    throttle_rate: int
    queue_length: int
    fragment_size: int | None
    compression: str


class TopicSubscription:
    """Everything one client asked of one topic. However many subscription ids it holds, the client gets one
    frame per message, sent at the lowest throttle rate, with the smallest fragment size and the longest queue."""

    def __init__(self, topic: str, default_bound: int) -> None:
        self.topic = topic
        self.requests: dict[Any, SubscriptionRequest] = {}
        self.default_bound = default_bound
        self.queue: deque[Published] = deque(maxlen=default_bound)
        self.token = 0
        self.last_sent = -math.inf
        self.throttle_s = 0.0
        self.fragment_size: int | None = None
        self.compression = "none"
        self.dropped = 0

    def update(self) -> None:
        reqs = list(self.requests.values())
        self.throttle_s = min(r.throttle_rate for r in reqs) / 1000.0
        sizes = [r.fragment_size for r in reqs if r.fragment_size]
        self.fragment_size = min(sizes) if sizes else None
        self.compression = reqs[-1].compression
        queue_length = max(r.queue_length for r in reqs)
        # queue_length 0: unthrottled, a bounded backlog for slow readers; throttled, only the newest message.
        bound = queue_length or (1 if self.throttle_s > 0 else self.default_bound)
        if bound != self.queue.maxlen:
            self.queue = deque(self.queue, maxlen=bound)


class _PublishOp:
    """A publish op whose envelope was checked by hand; read by handlers as ops.Publish is."""

    def __init__(self, topic: str, msg: Any, latch: bool, msg_id: Any) -> None:
        self.topic = topic
        self.msg = msg
        self.latch = latch
        self.id = msg_id


def _well_formed_publish(raw: dict[str, Any]) -> _PublishOp | None:
    """The publish op when its envelope is what ops.Publish accepts, checked in plain Python: the model's
    validation was a tenth of a publish's cost (py-spy). None sends anything unusual to the model, which decides
    and words the error; the message itself is validated by the bus either way."""
    topic = raw.get("topic")
    latch = raw.get("latch", False)
    msg_id = raw.get("id")
    if type(topic) is str and topic and type(latch) is bool and (
            msg_id is None or type(msg_id) is str or type(msg_id) is int):
        return _PublishOp(topic, raw.get("msg"), latch, msg_id)
    return None


@dataclass
class FragmentSet:
    total: int
    parts: dict[int, str]
    size: int
    expiry: asyncio.TimerHandle | None = None


class Session:
    def __init__(self, name: str, bus: Bus, settings: ServerSettings, peer: str = "") -> None:
        self.name = name
        self.peer = peer
        self.bus = bus
        self.registry = bus.registry
        self.settings = settings
        self.level = "error"
        self.closed = False
        self.subscriptions: dict[str, TopicSubscription] = {}
        self.advertised: dict[str, str] = {}  # topic -> type
        self.services: set[str] = set()
        self.actions: set[str] = set()
        self._pending: dict[str, TopicSubscription] = {}  # subscriptions with queued messages, in arrival order
        self._control: deque[Frame] = deque(maxlen=settings.control_queue_bound)
        self._wake = asyncio.Event()
        self._tasks: set[asyncio.Task[Any]] = set()
        self._calls_to_me: dict[str, asyncio.Future[Any]] = {}  # server-made call id -> caller's future
        self._goals_to_me: dict[str, GoalHandle] = {}  # goals this client serves, by the bus's goal id
        self._my_goals: dict[Any, GoalHandle] = {}  # goals this client sent, by its own id
        self._fragments: dict[Any, FragmentSet] = {}
        self._ids = itertools.count(1)
        self.counters = {"frames_in": 0, "errors": 0, "dropped": 0}
        # Sees every frame but topic messages, in ("in") and out ("out"): (session name, direction, frame).
        self.tap: Callable[[str, str, Frame], None] | None = None
        self.policy = AccessPolicy({})  # set by the server; open until then
        self.role: Role | None = None  # set by a successful auth op
        self.ping: Callable[[], Awaitable[float]] | None = None  # set by the transport: a WebSocket ping's round trip
        self._handlers: dict[str, Callable[[Any], Awaitable[None] | None]] = {
            name: getattr(self, f"_op_{name}") for name in ops.CLIENT_OP_MODELS
        }

    # ---- incoming -----------------------------------------------------------------------------------------------
    async def handle_frame(self, frame: Frame, *, reassembled: bool = False) -> None:
        self.counters["frames_in"] += 1
        if len(frame) > self.settings.max_message_size:
            self.status("error", f"a frame of {len(frame)} bytes is over this server's limit of "
                                 f"{self.settings.max_message_size} bytes: send it in pieces with the 'fragment' op, "
                                 f"or start the server with a larger --max-message-size")
            return
        try:
            raw = decode_frame(frame)
        except FrameError as exc:
            self.status("error", str(exc))
            return
        raw_id = raw.get("id")
        msg_id = raw_id if isinstance(raw_id, (str, int)) and not isinstance(raw_id, bool) else None
        name = raw["op"]
        if self.tap is not None and name != "publish":  # published messages are recorded from the bus
            self.tap(self.name, "in", frame)
        model = ops.CLIENT_OP_MODELS.get(name)
        if model is None:
            self.status("error", f"unknown op '{name[:60]}'; this server understands: "
                                 f"{', '.join(sorted(ops.CLIENT_OP_MODELS))}", msg_id)
            return
        if reassembled and name == "fragment":
            self.status("error", "a reassembled message is itself a fragment; fragments do not nest", msg_id)
            return
        try:
            op = _well_formed_publish(raw) if name == "publish" else None
            if op is None:
                op = model.model_validate(raw)
        except ValidationError as exc:
            self.status("error", f"{name}: {describe_validation_error(exc)}", msg_id)
            return
        try:
            if not self.policy.open:  # getattr on a model that lacks the field raises inside pydantic: costly
                fields = op.__dict__
                self.policy.check(self.role, name, fields.get("service") or fields.get("topic") or "")
        except AccessDenied as exc:
            self.status("error", f"{name}: refused: {exc}", msg_id)
            return
        try:
            result = self._handlers[name](op)
            if result is not None:
                await result
        except (ProtocolError, BusError) as exc:
            self.status(getattr(exc, "level", "error"), f"{name}: {exc}", msg_id)
        except Exception as exc:
            log.exception("%s: %s (id %r) failed", self.name, name, msg_id)
            self.status("error", f"{name}: internal error ({type(exc).__name__}: {exc}); the server logged it",
                        msg_id)

    # ---- topics -------------------------------------------------------------------------------------------------
    def _op_advertise(self, op: ops.Advertise) -> None:
        known = self.advertised.get(op.topic)
        topic = self.bus.advertise(self.name, op.topic, op.type, latched=op.latch) if known is None \
            else self.bus.declare_topic(op.topic, op.type)
        self.advertised[op.topic] = topic.type

    def _op_unadvertise(self, op: ops.Unadvertise) -> None:
        if op.topic not in self.advertised:
            raise ProtocolError(f"topic {op.topic} is not advertised by this client", "warning")
        del self.advertised[op.topic]
        self.bus.unadvertise(self.name, op.topic)

    def _op_publish(self, op: ops.Publish) -> None:
        topic = self.bus.topics.get(op.topic)
        text = None
        if topic is not None and not topic.known:
            # Relayed as the JSON it came in as, so it must be JSON: not CBOR's bytes, tags or undefined, and no
            # NaN or Infinity, which strict parsers (JavaScript's JSON.parse) refuse.
            try:
                text = json.dumps(op.msg, separators=(",", ":"), allow_nan=False)
            except (TypeError, ValueError) as exc:
                raise ProtocolError(f"{op.topic} carries {topic.type}, a type this server does not know, so its "
                                    f"messages are relayed as JSON, and this one cannot be: {exc}") from None
        published = self.bus.publish(op.topic, op.msg, latch=op.latch, sender=self.name)
        if text is not None:
            published.encoded.setdefault("msg_json", text)

    def _op_subscribe(self, op: ops.Subscribe) -> None:
        if op.type:
            self.bus.declare_topic(op.topic, op.type)
        sub = self.subscriptions.get(op.topic)
        if sub is None:
            topic = self.bus.topics.get(op.topic)
            if topic is None:
                raise BusError(f"topic {op.topic} does not exist yet, so its type is unknown: give 'type' when "
                               f"subscribing, or subscribe after it is advertised")
            if op.compression == "cbor-raw" and not topic.known:
                raise ProtocolError(f"cbor-raw needs a type this server knows; {topic.type} is carried as JSON only")
            sub = TopicSubscription(op.topic, topic.queue_bound or self.settings.queue_bound)
            sub.requests[op.id] = SubscriptionRequest(op.throttle_rate, op.queue_length, op.fragment_size,
                                                      op.compression)
            sub.update()
            self.subscriptions[op.topic] = sub
            sub.token = self.bus.subscribe(self.name, op.topic, None, lambda p, s=sub: self._deliver(s, p))
        else:
            sub.requests[op.id] = SubscriptionRequest(op.throttle_rate, op.queue_length, op.fragment_size,
                                                      op.compression)
            sub.update()

    def _op_unsubscribe(self, op: ops.Unsubscribe) -> None:
        sub = self.subscriptions.get(op.topic)
        if sub is None:
            raise ProtocolError(f"this client is not subscribed to {op.topic}", "warning")
        if op.id is not None:
            if op.id not in sub.requests:
                raise ProtocolError(f"no subscription to {op.topic} has id {op.id!r}", "warning")
            del sub.requests[op.id]
        else:
            sub.requests.clear()
        if sub.requests:
            sub.update()
            return
        del self.subscriptions[op.topic]
        self._pending.pop(op.topic, None)
        self.bus.unsubscribe(op.topic, sub.token)

    def _deliver(self, sub: TopicSubscription, published: Published) -> None:
        if len(sub.queue) == sub.queue.maxlen:
            sub.dropped += 1
            self.counters["dropped"] += 1
        sub.queue.append(published)
        if sub.topic not in self._pending:
            self._pending[sub.topic] = sub
        self._wake.set()

    # ---- services -----------------------------------------------------------------------------------------------
    def _op_call_service(self, op: ops.CallService) -> None:
        if len(self._tasks) >= self.settings.max_pending_calls:
            raise ProtocolError(f"this client already has {len(self._tasks)} calls in progress; wait for answers")
        self._spawn(self._call_service(op))

    async def _call_service(self, op: ops.CallService) -> None:
        timeout = op.timeout or self.settings.service_timeout
        try:
            response = await self.bus.call_service(op.service, op.args, timeout, caller=self.name)
        except BusError as exc:
            self.status("error", f"call_service: {exc}", op.id)
            self._reply(self._with_id({"op": "service_response", "service": op.service, "values": str(exc),
                                       "result": False}, op.id), op.compression, op.fragment_size, op.id)
            return
        self._reply(self._with_id({"op": "service_response", "service": op.service,
                                   "values": json_value(response), "result": True}, op.id),
                    op.compression, op.fragment_size, op.id)

    def _op_advertise_service(self, op: ops.AdvertiseService) -> None:
        self.bus.advertise_service(self.name, op.service, op.type,
                                   lambda request, timeout, name=op.service: self._serve_call(name, request))
        self.services.add(op.service)

    def _op_unadvertise_service(self, op: ops.UnadvertiseService) -> None:
        if op.service not in self.services:
            raise ProtocolError(f"service {op.service} is not advertised by this client", "warning")
        self.services.discard(op.service)
        self.bus.unadvertise_service(self.name, op.service)
        for call_id, future in list(self._calls_to_me.items()):
            if call_id.startswith(f"service_request:{op.service}:") and not future.done():
                future.set_exception(BusError(f"service {op.service} was withdrawn by its provider"))

    async def _serve_call(self, service: str, request: Any) -> Any:
        """Forwards a call to this client, which provides the service, and waits for its service_response."""
        call_id = f"service_request:{service}:{next(self._ids)}"
        future: asyncio.Future[Any] = asyncio.get_running_loop().create_future()
        self._calls_to_me[call_id] = future
        self._send({"op": "call_service", "id": call_id, "service": service, "args": json_value(request)})
        try:
            return await future
        finally:
            self._calls_to_me.pop(call_id, None)

    def _op_service_response(self, op: ops.ServiceResponse) -> None:
        future = self._calls_to_me.get(str(op.id)) if op.id is not None else None
        if future is None or future.done():
            raise ProtocolError(f"no call with id {op.id!r} is waiting for an answer (it may have timed out)",
                                "warning")
        if not op.result:
            future.set_exception(BusError(f"service {op.service} reported failure: {op.values}"))
            return
        service = self.bus.services.get(op.service)
        try:
            values = self.bus.validate_response(service, op.values) if service is not None else op.values
        except BusError as exc:
            future.set_exception(exc)
            raise
        future.set_result(values)

    # ---- actions ------------------------------------------------------------------------------------------------
    def _op_advertise_action(self, op: ops.AdvertiseAction) -> None:
        self.bus.advertise_action(self.name, op.action, op.type, _ClientActionProvider(self))
        self.actions.add(op.action)

    def _op_unadvertise_action(self, op: ops.UnadvertiseAction) -> None:
        if op.action not in self.actions:
            raise ProtocolError(f"action {op.action} is not advertised by this client", "warning")
        self.actions.discard(op.action)
        self.bus.unadvertise_action(self.name, op.action)

    def _op_send_action_goal(self, op: ops.SendActionGoal) -> None:
        caller_id = op.id if op.id is not None else f"goal:{op.action}:{next(self._ids)}"
        if caller_id in self._my_goals:
            raise ProtocolError(f"a goal with id {caller_id!r} is already running")

        def on_feedback(values: Any) -> None:
            if op.feedback:
                self._reply({"op": "action_feedback", "id": caller_id, "action": op.action,
                             "values": json_value(values)}, op.compression, op.fragment_size, caller_id)

        def on_result(status: int, values: Any, result: bool) -> None:
            self._my_goals.pop(caller_id, None)
            self._reply({"op": "action_result", "id": caller_id, "action": op.action, "values": json_value(values),
                         "status": status, "result": result}, op.compression, op.fragment_size, caller_id)

        try:
            self._my_goals[caller_id] = self.bus.send_goal(op.action, op.action_type, op.args, on_feedback,
                                                           on_result)
        except BusError as exc:
            self._my_goals.pop(caller_id, None)
            on_result(GOAL_STATUS_ABORTED, str(exc), False)
            raise

    def _op_cancel_action_goal(self, op: ops.CancelActionGoal) -> None:
        goal = self._my_goals.get(op.id)
        if goal is None:
            raise ProtocolError(f"no goal with id {op.id!r} is running on {op.action}", "warning")
        self.bus.cancel_goal(goal)

    def _op_action_feedback(self, op: ops.ActionFeedback) -> None:
        goal = self._goals_to_me.get(str(op.id))
        if goal is None:
            raise ProtocolError(f"no goal with id {op.id!r} is being served by this client", "warning")
        goal.feedback(op.values)

    def _op_action_result(self, op: ops.ActionResult) -> None:
        goal = self._goals_to_me.pop(str(op.id), None)
        if goal is None:
            raise ProtocolError(f"no goal with id {op.id!r} is being served by this client", "warning")
        goal.finish(op.status, op.values, op.result)

    # ---- fragments, levels, logs --------------------------------------------------------------------------------
    async def _op_fragment(self, op: ops.Fragment) -> None:
        limit = self.settings.max_message_size
        entry = self._fragments.get(op.id)
        if entry is None:
            entry = FragmentSet(op.total, {}, 0)
            self._fragments[op.id] = entry
            entry.expiry = asyncio.get_running_loop().call_later(
                self.settings.fragment_timeout, self._expire_fragments, op.id, entry)
        if op.total != entry.total:
            self._drop_fragments(op.id)
            raise ProtocolError(f"fragment {op.num} of id {op.id!r} says total {op.total}, earlier pieces said "
                                f"{entry.total}; the set is discarded")
        if op.num >= op.total:
            raise ProtocolError(f"fragment num {op.num} is out of range for total {op.total} (num counts from 0)")
        previous = entry.parts.get(op.num)
        if previous is not None and previous != op.data:
            self._drop_fragments(op.id)
            raise ProtocolError(f"fragment {op.num} of id {op.id!r} arrived twice with different data; "
                                f"the set is discarded")
        if previous is None:
            entry.size += len(op.data)
            entry.parts[op.num] = op.data
        if entry.size > limit:
            self._drop_fragments(op.id)
            raise ProtocolError(f"the fragments of id {op.id!r} add up to more than {limit} bytes; discarded")
        if len(entry.parts) == entry.total:
            self._drop_fragments(op.id)
            await self.handle_frame("".join(entry.parts[i] for i in range(entry.total)), reassembled=True)

    def _expire_fragments(self, frag_id: Any, entry: FragmentSet) -> None:
        if self._fragments.get(frag_id) is entry:
            del self._fragments[frag_id]
            self.status("warning", f"fragments of id {frag_id!r} were discarded after "
                                   f"{self.settings.fragment_timeout:g} s: {len(entry.parts)} of {entry.total} arrived",
                        frag_id)

    def _drop_fragments(self, frag_id: Any) -> None:
        entry = self._fragments.pop(frag_id, None)
        if entry is not None and entry.expiry is not None:
            entry.expiry.cancel()

    def _op_auth(self, op: ops.Auth) -> None:
        role = self.policy.role_for(op.mac)
        if role is None:
            raise ProtocolError("this token is not known; ask whoever runs the server for one")
        self.role = role
        log.info("%s authenticated as %s", self.name, role)

    def _op_set_level(self, op: ops.SetLevel) -> None:
        self.level = op.level

    def _op_status(self, op: ops.Status) -> None:
        log.log({"info": logging.INFO, "warning": logging.WARNING}.get(op.level, logging.ERROR),
                "%s reports (id %r): %s", self.name, op.id, op.msg)

    # ---- outgoing -----------------------------------------------------------------------------------------------
    def status(self, level: str, message: str, msg_id: Any = None) -> None:
        if level == "error":
            self.counters["errors"] += 1
        log.debug("%s status %s (id %r): %s", self.name, level, msg_id, message)
        if LEVELS[level] >= LEVELS[self.level] and level != "none":
            self._send(self._with_id({"op": "status", "level": level, "msg": message}, msg_id))

    @staticmethod
    def _with_id(frame: dict[str, Any], msg_id: Any) -> dict[str, Any]:
        return frame if msg_id is None else {"op": frame["op"], "id": msg_id, **frame}

    def _send(self, frame: dict[str, Any]) -> None:
        self._push(dumps(frame))

    def _reply(self, frame: dict[str, Any], compression: str, fragment_size: int | None, msg_id: Any) -> None:
        for piece in encode_for_client(dumps(frame), compression, fragment_size,
                                       f"{msg_id if msg_id is not None else 'reply'}:{next(self._ids)}"):
            self._push(piece)

    def _push(self, frame: Frame) -> None:
        if self.closed:
            return
        if self.tap is not None:
            self.tap(self.name, "out", frame)
        self._control.append(frame)
        self._wake.set()

    def _encode(self, sub: TopicSubscription, published: Published) -> list[Frame]:
        if sub.compression in ("cbor", "cbor-raw"):
            return [publish_cbor(published, self.registry, raw=sub.compression == "cbor-raw")]
        text = publish_text(published)
        if sub.compression == "png":
            packed = published.encoded.get("png")
            if packed is None:
                packed = published.encoded["png"] = png_pack(text)
            if sub.fragment_size and len(packed) > sub.fragment_size:
                return list(split_fragments("png", packed, sub.fragment_size, self._fragment_id(published)))
            return [dumps({"op": "png", "data": packed})]
        if sub.fragment_size and len(text) > sub.fragment_size:
            return split_fragments("fragment", text, sub.fragment_size, self._fragment_id(published))
        return [text]

    def _fragment_id(self, published: Published) -> str:
        return f"{published.topic}:{next(self._ids)}"

    def _encode_or_drop(self, sub: TopicSubscription, published: Published) -> list[Frame]:
        """A message that cannot be encoded is dropped and logged: it must not stop this client's stream."""
        try:
            return self._encode(sub, published)
        except Exception:
            log.exception("%s: a message on %s could not be encoded and was dropped", self.name, sub.topic)
            self.counters["dropped"] += 1
            return []

    async def next_frames(self) -> list[Frame]:
        """Waits for and returns the frames that may go out now (replies first, then topics, throttles obeyed)."""
        while True:
            frames: list[Frame] = []
            while self._control:
                frames.append(self._control.popleft())
            now = time.monotonic()
            wake_at = math.inf
            for topic, sub in list(self._pending.items()):
                if sub.throttle_s > 0:
                    due = sub.last_sent + sub.throttle_s
                    if now < due:
                        wake_at = min(wake_at, due)
                        continue
                    frames.extend(self._encode_or_drop(sub, sub.queue.popleft()))
                    sub.last_sent = now
                else:
                    while sub.queue:
                        frames.extend(self._encode_or_drop(sub, sub.queue.popleft()))
                if not sub.queue:
                    del self._pending[topic]
                elif sub.throttle_s > 0:
                    wake_at = min(wake_at, now + sub.throttle_s)
            if frames:
                return frames
            self._wake.clear()
            if wake_at == math.inf:
                await self._wake.wait()
            else:
                try:
                    await asyncio.wait_for(self._wake.wait(), wake_at - now)
                except TimeoutError:
                    pass

    # ---- lifetime -----------------------------------------------------------------------------------------------
    def _spawn(self, coro: Awaitable[Any]) -> None:
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def close(self) -> None:
        """Releases everything the client held: subscriptions, advertisements, services, goals, pending calls."""
        if self.closed:
            return
        self.closed = True
        for task in list(self._tasks):
            task.cancel()
        for future in self._calls_to_me.values():
            if not future.done():
                future.set_exception(BusError("the client providing this service disconnected"))
        for goal in list(self._goals_to_me.values()):
            goal.finish(GOAL_STATUS_ABORTED, "the client serving this goal disconnected", False)
        for goal in list(self._my_goals.values()):
            self.bus.cancel_goal(goal)
        for frag_id in list(self._fragments):
            self._drop_fragments(frag_id)
        self.bus.drop_owner(self.name)
        self.subscriptions.clear()
        self._pending.clear()
        self._control.clear()


class _ClientActionProvider:
    """Serves an action's goals by forwarding them to the client that advertised it."""

    def __init__(self, session: Session) -> None:
        self.session = session

    def start_goal(self, goal: GoalHandle) -> None:
        action = self.session.bus.actions[goal.action]
        self.session._goals_to_me[goal.goal_id] = goal
        self.session._send({"op": "send_action_goal", "id": goal.goal_id, "action": goal.action,
                            "action_type": action.type, "args": json_value(goal.args), "feedback": True})

    def cancel_goal(self, goal: GoalHandle) -> None:
        self.session._send({"op": "cancel_action_goal", "id": goal.goal_id, "action": goal.action})

