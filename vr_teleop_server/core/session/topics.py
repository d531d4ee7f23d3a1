"""The topic ops: advertise, unadvertise, publish, subscribe, unsubscribe (what a client asks of topics)."""

from __future__ import annotations

import functools
import json
from typing import Any

from client_protocol import ops

from ..access import AccessPolicy, Role
from ..bus import Bus, BusError
from ..settings import CoreSettings
from .outbox import Outbox, SubscriptionRequest, TopicSubscription
from .protocol import ProtocolError


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


class TopicOps:
    """Mixed into Session: its handlers of the topic ops (bound once into Session's dispatch table)."""

    name: str
    bus: Bus
    policy: AccessPolicy
    role: Role | None
    settings: CoreSettings
    outbox: Outbox
    subscriptions: dict[str, TopicSubscription]
    advertised: dict[str, str]

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
            source = self.policy.topic_view(self.role, op.topic)
            sub = TopicSubscription(op.topic, topic.queue_bound or self.settings.queue_bound, source)
            sub.requests[op.id] = SubscriptionRequest(op.throttle_rate, op.queue_length, op.fragment_size,
                                                      op.compression)
            sub.update()
            self.subscriptions[op.topic] = sub
            if source == op.topic:
                sub.token = self.bus.subscribe(self.name, op.topic, None, functools.partial(self.outbox.deliver, sub))
            else:  # served from its blurred view, under the name the client asked for
                sub.token = self.bus.subscribe(self.name, source, None, lambda p, s=sub, deliver=self.outbox.deliver:
                                               deliver(s, p.renamed(s.topic)))
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
        self.outbox.forget(op.topic)
        self.bus.unsubscribe(sub.source, sub.token)
