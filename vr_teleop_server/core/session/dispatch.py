"""One client's rosbridge session: parses each frame, dispatches it by op, and keeps what the client owns.

A handler per op (as rosbridge_suite's capabilities, without their globals). Errors become `status` replies that
name the problem and echo the operation's `id`; the connection always goes on. Outgoing messages wait in a
bounded outbox that the transport drains: a client that reads slowly loses its oldest messages per
subscription, and never slows a publisher or another client.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import math
from collections.abc import Awaitable, Callable
from typing import Any

from pydantic import ValidationError

from client_protocol import ops, pose_frame
from client_protocol.registry import describe_validation_error

from ..access import AccessDenied, AccessPolicy, Login, Role
from ..bus import GOAL_STATUS_ABORTED, Bus, BusError, CallFailed, GoalHandle
from ..settings import CoreSettings
from ..wire import FrameError, decode_frame, dumps, encode_for_client, restyle_times
from .actions import ActionOps
from .fragments import Reassembly
from .outbox import Frame, Outbox
from .protocol import ProtocolError, json_value
from .services import ServiceOps
from .topics import TopicOps, TopicSubscription, _PublishOp, _well_formed_publish

log = logging.getLogger(__name__)

LEVELS = {"info": 0, "warning": 1, "error": 2, "none": 3}


class Session(TopicOps, ServiceOps, ActionOps):
    """One client's session (the op handlers of topics, services and actions are in the mixins)."""

    def __init__(self, name: str, bus: Bus, settings: CoreSettings, peer: str = "", *,
                 policy: AccessPolicy | None = None, tap: Callable[[str, str, Frame], None] | None = None,
                 ping: Callable[[], Awaitable[float]] | None = None) -> None:
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
        self._wake = asyncio.Event()
        self._tasks: set[asyncio.Task[Any]] = set()
        self._calls_to_me: dict[str, asyncio.Future[Any]] = {}  # server-made call id -> caller's future
        self._goals_to_me: dict[str, GoalHandle] = {}  # goals this client serves, by the bus's goal id
        self._my_goals: dict[Any, GoalHandle] = {}  # goals this client sent, by its own id
        self.fragments = Reassembly(settings.max_message_size, settings.fragment_timeout, self._fragments_expired)
        self._ids = itertools.count(1)
        self.counters = {"frames_in": 0, "errors": 0, "dropped": 0}
        self.last_error = ""  # the newest status error's text (the poses data channel reports it)
        self.outbox = Outbox(self.registry, settings.control_queue_bound, wake=self._wake.set, counters=self.counters,
                             ids=self._ids, name=name)
        # Sees every frame but topic messages, in ("in") and out ("out"): (session name, direction, frame).
        self.tap = tap
        self.policy = policy if policy is not None else AccessPolicy({})  # none given: open
        self.role: Role | None = None  # set by a successful auth op, or by a token at the handshake
        # The operator this connection belongs to: connections presenting the same operator token (or, with open
        # access, the same ?operator= key) share it, and control is held by an operator, not a connection.
        self.operator = name
        # Time style of what is sent: None is the registry's (--time-style). Learned from the first stamp the
        # client sends unless the URL set it (?time=ros2).
        self._style_learned = False
        self.ping = ping  # a WebSocket ping's round trip, from the transport (link telemetry)

    def apply_login(self, login: Login) -> None:
        """What the WebSocket handshake said (URL query, Authorization header): role, operator, time style."""
        if login.role is not None:
            self.role = login.role
        if login.operator:
            self.operator = login.operator
        if login.time_style is not None:
            self.set_time_style(login.time_style)
            self._style_learned = True

    @property
    def time_style(self) -> str:
        return self.outbox.time_style or self.registry.time_style

    def set_time_style(self, style: str) -> None:
        self.outbox.time_style = None if style == self.registry.time_style else style

    def _learn_time_style(self, msg: Any) -> None:
        """The first stamp a client sends tells its style ({sec, nanosec}: ROS 2; {secs, nsecs}: ROS 1)."""
        header = msg.get("header") if isinstance(msg, dict) else None
        stamp = header.get("stamp") if isinstance(header, dict) else None
        if isinstance(stamp, dict):
            if "sec" in stamp or "nanosec" in stamp:
                self.set_time_style("ros2")
                self._style_learned = True
            elif "secs" in stamp or "nsecs" in stamp:
                self.set_time_style("ros1")
                self._style_learned = True

    # ---- incoming -----------------------------------------------------------------------------------------------
    async def handle_frame(self, frame: Frame, *, reassembled: bool = False) -> None:
        pending = self.receive(frame, reassembled=reassembled)
        if pending is not None:
            await pending

    def receive(self, frame: Frame, *, reassembled: bool = False) -> Awaitable[None] | None:
        """handle_frame without a coroutine of its own: what the frame's op does at once is done here, and what it
        must wait for is returned to be awaited before the next frame (None: nothing). A publish, the hot path, is
        done at once, without the two coroutines (this method's and _dispatch's) it used to make."""
        self.counters["frames_in"] += 1
        if len(frame) > self.settings.max_message_size:
            self.status("error", f"a frame of {len(frame)} bytes is over this server's limit of "
                                 f"{self.settings.max_message_size} bytes: send it in pieces with the 'fragment' op, "
                                 f"or start the server with a larger --max-message-size")
            return None
        if isinstance(frame, bytes) and frame[:2] == pose_frame.MAGIC:  # CBOR's 22-byte string: never an op
            return self._pose_frame(frame)
        try:
            raw = decode_frame(frame)
        except FrameError as exc:
            self.status("error", str(exc))
            return None
        raw_id = raw.get("id")
        msg_id = raw_id if isinstance(raw_id, (str, int)) and not isinstance(raw_id, bool) else None
        name = raw["op"]
        if self.tap is not None and name != "publish":  # published messages are recorded from the bus
            # a token never reaches a recording: the auth op is recorded without it
            self.tap(self.name, "in", dumps({"op": "auth", "mac": "***"}) if name == "auth" else frame)
        model = ops.CLIENT_OP_MODELS.get(name)
        if model is None:
            self.status("error", f"unknown op '{name[:60]}'; this server understands: "
                                 f"{', '.join(sorted(ops.CLIENT_OP_MODELS))}", msg_id)
            return None
        if reassembled and name == "fragment":
            self.status("error", "a reassembled message is itself a fragment; fragments do not nest", msg_id)
            return None
        try:
            op = _well_formed_publish(raw) if name == "publish" else None
            if op is None:
                op = model.model_validate(raw)
        except ValidationError as exc:
            self.status("error", f"{name}: {describe_validation_error(exc)}", msg_id)
            return None
        return self._dispatch(name, op, msg_id, learn_style=True)

    async def _pose_frame(self, frame: bytes) -> None:
        """A binary pose frame (client_protocol/pose_frame.py, as the poses data channel takes them): each of its
        poses and Joy goes the way its JSON publish frame would (access, the bus's typed validation, the holder
        rule), without the JSON. Its stamps' style is the decoder's, not the client's: none is learned from it."""
        try:
            messages = pose_frame.decode(frame)
        except pose_frame.PoseFrameError as exc:
            self.status("error", f"{exc}; a binary frame is a pose frame, CBOR or UTF-8 JSON")
            return
        for topic, msg in messages:
            pending = self._dispatch("publish", _PublishOp(topic, msg, False, None), None, learn_style=False)
            if pending is not None:
                await pending

    def _dispatch(self, name: str, op: Any, msg_id: Any, *, learn_style: bool) -> Awaitable[None] | None:
        """An op whose envelope is valid: the access policy, then its handler; errors become status replies. An
        async handler's coroutine is returned, wrapped to report its errors likewise."""
        try:
            if not self.policy.open or self.role == "participant":  # getattr on a model that lacks the field
                # raises inside pydantic: costly
                fields = op.__dict__
                self.policy.check(self.role, name, fields.get("service") or fields.get("topic") or "")
        except AccessDenied as exc:
            self.status("error", f"{name}: refused: {exc}", msg_id)
            if name == "call_service":  # answered too, so that a client that ignores status (ROS#) can read it
                self._answer_refused_call(op, f"refused: {exc}")
            return None
        if learn_style and not self._style_learned and name == "publish":
            self._learn_time_style(op.msg)
        try:
            result = _HANDLERS_BY_NAME[name](self, op)
        except Exception as exc:
            self._failed(name, msg_id, exc)
            return None
        return None if result is None else self._finish(name, msg_id, result)

    async def _finish(self, name: str, msg_id: Any, handling: Awaitable[None]) -> None:
        try:
            await handling
        except Exception as exc:
            self._failed(name, msg_id, exc)

    def _failed(self, name: str, msg_id: Any, exc: Exception) -> None:
        """An op's handler raised: a refusal is the client's status reply; anything else is logged, and said."""
        if isinstance(exc, (ProtocolError, BusError)):
            self.status(getattr(exc, "level", "error"), f"{name}: {exc}", msg_id)
            return
        log.error("%s: %s (id %r) failed", self.name, name, msg_id, exc_info=exc)
        self.status("error", f"{name}: internal error ({type(exc).__name__}: {exc}); the server logged it", msg_id)

    def _answer_refused_call(self, op: ops.CallService, reason: str) -> None:
        refused = self.bus.refusal_response(op.service, reason)
        frame = {"op": "service_response", "service": op.service, "values": reason, "result": False} \
            if refused is None else {"op": "service_response", "service": op.service,
                                     "values": json_value(refused), "result": True}
        self._reply(self._with_id(frame, op.id), op.compression, op.fragment_size, op.id)

    # ---- fragments, levels, logs --------------------------------------------------------------------------------
    async def _op_fragment(self, op: ops.Fragment) -> None:
        whole = self.fragments.add(op)
        if whole is not None:
            await self.handle_frame(whole, reassembled=True)

    def _fragments_expired(self, frag_id: Any, arrived: int, total: int) -> None:
        self.status("warning", f"fragments of id {frag_id!r} were discarded after "
                               f"{self.settings.fragment_timeout:g} s: {arrived} of {total} arrived", frag_id)

    def _op_auth(self, op: ops.Auth) -> None:
        role = self.policy.role_for(op.mac)
        if role is None:
            raise ProtocolError("this token is not known; ask whoever runs the server for one")
        self.role = role
        self.operator = self.policy.operator_key(op.mac) or self.operator
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
            self.last_error = message
        log.debug("%s status %s (id %r): %s", self.name, level, msg_id, message)
        if LEVELS[level] >= LEVELS[self.level] and level != "none":
            self._send(self._with_id({"op": "status", "level": level, "msg": message}, msg_id))

    @staticmethod
    def _with_id(frame: dict[str, Any], msg_id: Any) -> dict[str, Any]:
        return frame if msg_id is None else {"op": frame["op"], "id": msg_id, **frame}

    def _dumps(self, frame: dict[str, Any]) -> str:
        text = dumps(frame)
        style = self.outbox.time_style
        return text if style is None else restyle_times(text, style)

    def _send(self, frame: dict[str, Any]) -> None:
        self._push(self._dumps(frame))

    def _reply(self, frame: dict[str, Any], compression: str, fragment_size: int | None, msg_id: Any,
               redacted: str | None = None) -> None:
        """`redacted`: what the tap (the recording) sees instead of the frame, whose values are secret."""
        if redacted is not None and self.tap is not None and not self.closed:
            self.tap(self.name, "out", redacted)
        for piece in encode_for_client(self._dumps(frame), compression, fragment_size,
                                       f"{msg_id if msg_id is not None else 'reply'}:{next(self._ids)}"):
            self._push(piece, tap=redacted is None)

    def _push(self, frame: Frame, tap: bool = True) -> None:
        if self.closed:
            return
        if self.tap is not None and tap:
            self.tap(self.name, "out", frame)
        self.outbox.push(frame)

    async def next_frames(self) -> list[Frame]:
        """Waits for and returns the frames that may go out now (replies first, then topics, throttles obeyed)."""
        outbox, wake = self.outbox, self._wake
        while True:
            now = asyncio.get_running_loop().time()  # the clock of the wait below
            frames, wake_at = outbox.take(now)
            if frames:
                return frames
            wake.clear()
            if wake_at == math.inf:
                await wake.wait()
            else:
                try:
                    await asyncio.wait_for(wake.wait(), wake_at - now)
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
                future.set_exception(CallFailed("the client providing this service disconnected"))
        for goal in list(self._goals_to_me.values()):
            goal.finish(GOAL_STATUS_ABORTED, "the client serving this goal disconnected", False)
        for goal in list(self._my_goals.values()):
            self.bus.cancel_goal(goal)
        self.fragments.clear()
        self.bus.drop_owner(self.name)
        self.subscriptions.clear()
        self.outbox.clear()


# Each client op's handler, by the op's model (client_protocol.ops.CLIENT_OPS): one entry per op, as rosbridge
# registers its capabilities. tests/test_protocol_ops.py holds it to the models.
OP_HANDLERS: dict[type[ops.Op], Callable[[Session, Any], Awaitable[None] | None]] = {
    ops.Advertise: Session._op_advertise,
    ops.Unadvertise: Session._op_unadvertise,
    ops.Publish: Session._op_publish,
    ops.Subscribe: Session._op_subscribe,
    ops.Unsubscribe: Session._op_unsubscribe,
    ops.CallService: Session._op_call_service,
    ops.AdvertiseService: Session._op_advertise_service,
    ops.UnadvertiseService: Session._op_unadvertise_service,
    ops.ServiceResponse: Session._op_service_response,
    ops.AdvertiseAction: Session._op_advertise_action,
    ops.UnadvertiseAction: Session._op_unadvertise_action,
    ops.SendActionGoal: Session._op_send_action_goal,
    ops.CancelActionGoal: Session._op_cancel_action_goal,
    ops.ActionFeedback: Session._op_action_feedback,
    ops.ActionResult: Session._op_action_result,
    ops.Fragment: Session._op_fragment,
    ops.SetLevel: Session._op_set_level,
    ops.Status: Session._op_status,
    ops.Auth: Session._op_auth,
}
_HANDLERS_BY_NAME = {ops.op_name(model): handler for model, handler in OP_HANDLERS.items()}
