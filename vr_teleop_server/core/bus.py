"""The in-process topic, service and action bus: one per server.

Clients (through their sessions) and the server's own features are equal parties here: a feature publishes,
subscribes and provides services exactly as a client does, so nothing reaches the robot by a back door.
Subscribers read a message one way, `Published.data`: validated plain data (dicts with the type's field names)
for known types, however the message was published; the JSON value the client sent, untouched, for types the
server does not know. Plain data is what the publish hot path makes anyway (PlainCodec), so reading it costs
nothing; pydantic models (`Published.value`) are made only for the encoders that need one (CBOR, raw ROS 1).
"""

from __future__ import annotations

import asyncio
import contextvars
import itertools
import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from pydantic import BaseModel, ValidationError

from client_protocol.errors import Refusal
from client_protocol.registry import PlainCodec, TypeRegistry, describe_validation_error, normalize_type_name

log = logging.getLogger(__name__)


class BusError(Refusal):
    """A request the bus refuses; the message is shown to the client as it is."""


class CallFailed(BusError):
    """A service call that could not run at all (no such service, arguments that do not fit, timeout, provider
    gone or answering nonsense): the caller gets `result: false`. Any other Refusal a provider raises is a refusal
    the service answers inside its response (see Bus.refusal_response)."""


class Published:
    """One message as published, with its wire encodings computed once and shared by every subscriber."""

    __slots__ = ("topic", "type", "_value", "known", "sender", "encoded", "plain", "codec", "_data")

    def __init__(self, topic: str, type_name: str, value: Any, known: bool, sender: str,
                 plain: dict[str, Any] | None = None, codec: PlainCodec | None = None) -> None:
        self.topic = topic
        self.sender = sender  # the owner that published it: a client session's name, or a feature's
        self.type = type_name
        self._value = value
        self.known = known
        self.encoded: dict[str, Any] = {}
        # A known type's message as validated plain data, when a client published it: subscribers that only pass
        # it on never need the model (see PlainCodec).
        self.plain = plain
        self.codec = codec
        self._data = plain if plain is not None else None if known else value

    @property
    def data(self) -> Any:
        """The message as subscribers read it: validated plain data for a known type (the type's field names, times
        in the registry's style, byte arrays as bytes), the JSON value as sent for the others."""
        if self._data is None:
            self._data = self._value.model_dump()  # published as a model: dumped once, on first read
        return self._data

    @property
    def value(self) -> Any:
        """A pydantic model for known types, the JSON value as sent for the others (for encoders; subscribers
        read `data`)."""
        if self._value is None and self.plain is not None:
            self._value = self.codec.to_model(self.plain)
        return self._value

    def renamed(self, topic: str) -> Published:
        """This message as if published on `topic` (a blurred camera view served under the camera's name: core/
        access.py), made once and shared, with its encodings, by every subscriber that reads it so."""
        key = "as " + topic
        alias = self.encoded.get(key)
        if alias is None:
            alias = self.encoded[key] = Published(topic, self.type, self._value, self.known, self.sender, self.plain,
                                                  self.codec)
        return alias


Subscriber = Callable[[Published], None]


@dataclass
class Topic:
    name: str
    type: str
    known: bool
    latched: bool = False
    # Its last message is the server's current state (the robot's description, the autonomy level, who is in the
    # classroom), not an event: a recording that starts later opens with it. A trial's own events (/study/*) are
    # history and never are: latched for a late subscriber, but the next recording must not begin with them.
    state: bool = False
    last: Published | None = None
    subscribers: dict[int, tuple[str, Subscriber]] = field(default_factory=dict)  # token -> (owner, callback)
    publishers: dict[str, int] = field(default_factory=dict)  # owner -> advertise count
    persistent: bool = False  # created by the server itself: kept when no client uses it
    queue_bound: int | None = None  # per-subscriber queue when the subscriber asks for none (1: newest only)
    on_subscriber_count: Callable[[int], None] | None = None  # a feature that works only while watched
    codec: PlainCodec | None = None  # the known type's validation, looked up once rather than per message


@dataclass
class Service:
    name: str
    type: str
    known: bool
    owner: str
    provider: Callable[[Any, float], Awaitable[Any]]
    confidential: bool = False  # its responses carry secrets (credentials): never recorded or logged verbatim


class GoalHandle:
    """One action goal on its way from a caller to a provider; feedback and the result flow back through it."""

    def __init__(self, action: str, goal_id: str, args: Any, on_feedback: Callable[[Any], None],
                 on_result: Callable[[int, Any, bool], None]) -> None:
        self.action = action
        self.goal_id = goal_id  # the bus's own id, unique across clients
        self.args = args
        self._on_feedback = on_feedback
        self._on_result = on_result
        self.done = False
        self.cancel_requested = False

    def feedback(self, values: Any) -> None:
        if not self.done:
            self._on_feedback(values)

    def finish(self, status: int, values: Any, result: bool) -> None:
        if not self.done:
            self.done = True
            self._on_result(status, values, result)


class ActionProvider(Protocol):
    def start_goal(self, goal: GoalHandle) -> None: ...
    def cancel_goal(self, goal: GoalHandle) -> None: ...


@dataclass
class Action:
    name: str
    type: str
    owner: str
    provider: ActionProvider
    goals: dict[str, GoalHandle] = field(default_factory=dict)


SERVER_NODE = "/vr_teleop_server"  # the owner name of the server's own topics and services
# Who made the service call being served: a session name, or SERVER_NODE. Providers that care (who holds
# control, what a role may do) read it with Bus.caller(); it is set for the duration of each call.
_CALLER: contextvars.ContextVar[str] = contextvars.ContextVar("caller", default=SERVER_NODE)
GOAL_STATUS_CANCELED = 5
GOAL_STATUS_ABORTED = 6


class Bus:
    def __init__(self, registry: TypeRegistry, reporter: Callable[[str, str, str], None] | None = None) -> None:
        self.registry = registry
        self.topics: dict[str, Topic] = {}
        self.services: dict[str, Service] = {}
        self.actions: dict[str, Action] = {}
        self._tokens = itertools.count(1)
        self._goal_ids = itertools.count(1)
        # How features tell the client that sent a message about a problem with it (the server passes one that
        # finds the session); without one, the problem is logged.
        self.reporter: Callable[[str, str, str], None] = reporter or (lambda owner, level, text: log.log(
            logging.ERROR if level == "error" else logging.WARNING, "%s: %s", owner, text))
        # Called with the owner's name after a client has gone and everything it held was dropped.
        self.owner_dropped: list[Callable[[str], None]] = []
        # Called with every message published, before its subscribers (e.g. a session recording).
        self.taps: list[Callable[[Published], None]] = []

    @staticmethod
    def caller() -> str:
        """The session (or SERVER_NODE) whose service call is being served right now."""
        return _CALLER.get()

    def report(self, owner: str, level: str, text: str) -> None:
        """Tells `owner` (the sender of a message) about a problem the message caused: a rosbridge status."""
        self.reporter(owner, level, text)

    # ---- topics -------------------------------------------------------------------------------------------------
    def declare_topic(self, name: str, type_name: str, *, latched: bool = False, persistent: bool = False,
                      state: bool = False, queue_bound: int | None = None) -> Topic:
        """Creates `name` with `type_name`, or checks that it already has that type. `state`: latched, and its
        last message opens every recording (Topic.state)."""
        type_name = normalize_type_name(type_name)
        topic = self.topics.get(name)
        if topic is None:
            topic = Topic(name, type_name, self.registry.is_known_message(type_name), latched, persistent=persistent,
                          queue_bound=queue_bound)
            if topic.known:
                topic.codec = self.registry.codec(type_name)
            self.topics[name] = topic
        elif topic.type != type_name:
            raise BusError(f"topic {name} has type {topic.type}, not {type_name}")
        topic.latched = topic.latched or latched or state
        topic.persistent = topic.persistent or persistent
        topic.state = topic.state or state
        return topic

    def advertise(self, owner: str, name: str, type_name: str, *, latched: bool = False) -> Topic:
        topic = self.declare_topic(name, type_name, latched=latched)
        topic.publishers[owner] = topic.publishers.get(owner, 0) + 1
        return topic

    def unadvertise(self, owner: str, name: str) -> None:
        topic = self.topics.get(name)
        if topic is None or owner not in topic.publishers:
            raise BusError(f"topic {name} is not advertised by this client")
        del topic.publishers[owner]
        self._forget_if_unused(topic)

    def subscribe(self, owner: str, name: str, type_name: str | None, callback: Subscriber) -> int:
        """Returns a token for `unsubscribe`. A latched topic's last message is delivered at once."""
        if type_name:
            topic = self.declare_topic(name, type_name)
        else:
            topic = self.topics.get(name)
            if topic is None:
                raise BusError(f"topic {name} does not exist yet, so its type is unknown: give 'type' when "
                               f"subscribing, or wait until it is advertised")
        token = next(self._tokens)
        topic.subscribers[token] = (owner, callback)
        self._count_changed(topic)
        if topic.latched and topic.last is not None:
            callback(topic.last)
        return token

    def unsubscribe(self, name: str, token: int) -> None:
        topic = self.topics.get(name)
        if topic is not None and topic.subscribers.pop(token, None) is not None:
            self._count_changed(topic)
            self._forget_if_unused(topic)

    @staticmethod
    def _count_changed(topic: Topic) -> None:
        if topic.on_subscriber_count is not None:
            topic.on_subscriber_count(len(topic.subscribers))

    def _forget_if_unused(self, topic: Topic) -> None:
        if not topic.persistent and not topic.publishers and not topic.subscribers and topic.last is None:
            self.topics.pop(topic.name, None)

    def publish(self, name: str, msg: Any, *, latch: bool = False, sender: str = SERVER_NODE) -> Published:
        """Validates `msg` against the topic's type and hands it to every subscriber. Never blocks."""
        topic = self.topics.get(name)
        if topic is None:
            raise BusError(f"topic {name} does not exist: advertise it with a type before publishing")
        # (a client's message is a dict: the type test spares it isinstance's costlier look through BaseModel's
        # metaclass)
        if not topic.known or (type(msg) is not dict and isinstance(msg, BaseModel)):
            published = Published(name, topic.type, msg, topic.known, sender)
        else:
            try:
                published = Published(name, topic.type, None, True, sender, topic.codec.validate(msg), topic.codec)
            except ValidationError:
                # The model decides what the plain path refuses: it also takes model instances inside the
                # message (a feature's header stamped with registry.now()), and it words the error.
                try:
                    value = topic.codec.model.model_validate({} if msg is None else msg)
                except ValidationError as exc:
                    raise BusError(f"message does not fit {topic.type} on {topic.name}: "
                                   f"{describe_validation_error(exc, 'msg')}") from None
                published = Published(name, topic.type, value, True, sender)
        if topic.latched or latch:
            topic.latched = True
            topic.last = published
        for tap in self.taps:
            try:
                tap(published)
            except Exception:  # a failing recording (disk full...) must not stop the robot's traffic
                log.exception("tap on %s failed", name)
        for _owner, callback in list(topic.subscribers.values()):
            try:
                callback(published)
            except Exception:  # one faulty in-process subscriber must not starve the others
                log.exception("subscriber of %s failed", name)
        return published

    # ---- services -----------------------------------------------------------------------------------------------
    def advertise_service(self, owner: str, name: str, type_name: str,
                          provider: Callable[[Any, float], Awaitable[Any]]) -> Service:
        type_name = normalize_type_name(type_name)
        existing = self.services.get(name)
        if existing is not None and existing.owner != owner:
            raise BusError(f"service {name} is already provided by {existing.owner}")
        service = Service(name, type_name, self.registry.is_known_service(type_name), owner, provider)
        self.services[name] = service
        return service

    def unadvertise_service(self, owner: str, name: str) -> None:
        service = self.services.get(name)
        if service is None or service.owner != owner:
            raise BusError(f"service {name} is not advertised by this client")
        del self.services[name]

    def _service_request(self, service: Service, args: Any) -> Any:
        if not service.known:
            return args
        request_type, _ = self.registry.service_parts(service.type)
        if isinstance(args, list):
            names = [f.name for f in self.registry.spec(request_type).fields]
            if len(args) > len(names):
                raise CallFailed(f"{service.name} takes {len(names)} argument(s) ({', '.join(names) or 'none'}), "
                               f"{len(args)} were given")
            args = dict(zip(names, args))
        try:
            return self.registry.validate(request_type, args)
        except ValidationError as exc:
            raise CallFailed(f"arguments do not fit {service.type}: {describe_validation_error(exc, 'args')}") \
                from None

    def validate_response(self, service: Service, values: Any) -> Any:
        if not service.known:
            return values
        _, response_type = self.registry.service_parts(service.type)
        try:
            return self.registry.validate(response_type, values)
        except ValidationError as exc:
            raise CallFailed(f"the provider's response does not fit {service.type}: "
                           f"{describe_validation_error(exc, 'values')}") from None

    def refusal_response(self, name: str, reason: str) -> BaseModel | None:
        """The response of service `name` that says "refused: reason" (the ROS convention: a successful call whose
        response says so), or None when its type has no such fields. Fields looked for: `success` (bool) with
        `message` (string), as std_srvs and the project's own types have, or LuxAI's `status` (bool)."""
        service = self.services.get(name)
        if service is None or not service.known:
            return None
        _, response_type = self.registry.service_parts(service.type)
        fields = {f.name: (f.type, f.array_len) for f in self.registry.spec(response_type).fields}
        values: dict[str, Any] = {}
        if fields.get("success") == ("bool", None):
            values["success"] = False
        elif fields.get("status") == ("bool", None):
            values["status"] = False
        else:
            return None
        if fields.get("message") == ("string", None):
            values["message"] = reason
        return self.registry.validate(response_type, values)

    async def call_service(self, name: str, args: Any, timeout: float, *, caller: str = SERVER_NODE,
                           refusal_response: bool = True) -> Any:
        """Calls a service; returns its response (a model for known types). A Refusal from the provider becomes
        the response's refusal fields where the type has them (reported to the caller as a warning too); raises
        CallFailed (or BusError, a refusal the type cannot express) when there is no response to give. A feature
        calling another service in-process may ask for refusals raised (refusal_response=False) to word them."""
        service = self.services.get(name)
        if service is None:
            raise CallFailed(f"service {name} does not exist")
        request = self._service_request(service, args)
        token = _CALLER.set(caller)
        try:
            response = await asyncio.wait_for(service.provider(request, timeout), timeout)
        except asyncio.TimeoutError:
            raise CallFailed(f"service {name} did not answer within {timeout:g} s") from None
        except CallFailed:
            raise
        except Refusal as exc:  # refused by the provider (or below it: the robot away): said inside the response
            refused = self.refusal_response(name, str(exc)) if refusal_response else None
            if refused is None:
                raise BusError(str(exc)) from None
            log.info("%s refused %s: %s", name, caller, exc)
            if caller != SERVER_NODE and refusal_response:
                self.report(caller, "warning", f"{name} refused: {exc}")
            return refused
        except Exception as exc:
            log.exception("service %s failed", name)
            raise CallFailed(f"service {name} failed: {exc}") from None
        finally:
            _CALLER.reset(token)
        return response if isinstance(response, BaseModel) else self.validate_response(service, response)

    def provide(self, name: str, type_name: str, handler: Callable[[Any], Awaitable[Any]], *,
                confidential: bool = False) -> Service:
        """Registers one of the server's own services; `handler(request)` returns the response values.
        `confidential`: the responses carry secrets, which recordings and logs must not keep."""
        async def provider(request: Any, _timeout: float) -> Any:
            return await handler(request)
        service = self.advertise_service(SERVER_NODE, name, type_name, provider)
        service.confidential = confidential
        return service

    # ---- actions ------------------------------------------------------------------------------------------------
    def advertise_action(self, owner: str, name: str, type_name: str, provider: ActionProvider) -> Action:
        existing = self.actions.get(name)
        if existing is not None and existing.owner != owner:
            raise BusError(f"action {name} is already provided by {existing.owner}")
        action = Action(name, normalize_type_name(type_name), owner, provider)
        self.actions[name] = action
        return action

    def unadvertise_action(self, owner: str, name: str) -> None:
        action = self.actions.get(name)
        if action is None or action.owner != owner:
            raise BusError(f"action {name} is not advertised by this client")
        del self.actions[name]
        for goal in list(action.goals.values()):
            goal.finish(GOAL_STATUS_ABORTED, f"action {name} was withdrawn by its provider", False)

    def send_goal(self, name: str, type_name: str, args: Any, on_feedback: Callable[[Any], None],
                  on_result: Callable[[int, Any, bool], None]) -> GoalHandle:
        action = self.actions.get(name)
        if action is None:
            raise BusError(f"action {name} does not exist")
        if normalize_type_name(type_name) != action.type:
            raise BusError(f"action {name} has type {action.type}, not {normalize_type_name(type_name)}")

        def finished(status: int, values: Any, result: bool) -> None:
            action.goals.pop(goal.goal_id, None)
            on_result(status, values, result)

        goal = GoalHandle(name, f"goal_{next(self._goal_ids)}", args, on_feedback, finished)
        action.goals[goal.goal_id] = goal
        action.provider.start_goal(goal)
        return goal

    def cancel_goal(self, goal: GoalHandle) -> None:
        action = self.actions.get(goal.action)
        if action is None or goal.done:
            return
        goal.cancel_requested = True
        action.provider.cancel_goal(goal)

    # ---- introspection (rosapi) ---------------------------------------------------------------------------------
    def drop_owner(self, owner: str) -> None:
        """Removes everything a disconnected client advertised or provided."""
        for topic in list(self.topics.values()):
            topic.publishers.pop(owner, None)
            tokens = [token for token, (sub_owner, _) in topic.subscribers.items() if sub_owner == owner]
            for token in tokens:
                del topic.subscribers[token]
            if tokens:
                self._count_changed(topic)
            self._forget_if_unused(topic)
        for name, service in list(self.services.items()):
            if service.owner == owner:
                del self.services[name]
        for name, action in list(self.actions.items()):
            if action.owner == owner:
                self.unadvertise_action(owner, name)
        for listener in list(self.owner_dropped):
            try:
                listener(owner)
            except Exception:  # a faulty feature must not keep the others from cleaning up
                log.exception("owner_dropped listener failed for %s", owner)
