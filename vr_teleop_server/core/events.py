"""The event channel: server events (engage, e-stop, backend lost, menu picks...) on one topic that recordings, the
dashboard and logs all read. Any feature publishes here without knowing who else does; each kind's detail is
checked against its model in client_protocol.events, so a page reads typed fields, never a sentence."""

from __future__ import annotations

from typing import Any

from client_protocol import names
from client_protocol.events import EventDetail, EventKind, EventLevel, detail_json

from .bus import Bus


def declare_event_topic(bus: Bus) -> None:
    bus.declare_topic(names.EVENT_TOPIC, "vr_teleop_msgs/Event", persistent=True)


def publish_event(bus: Bus, source: str, kind: EventKind | str, level: EventLevel | str = EventLevel.INFO,
                  detail: EventDetail | dict[str, Any] | None = None) -> None:
    """Puts a server event on /vr_teleop/events (recordings, the dashboard and logs all read it there); a kind or
    a detail its model does not know raises ValueError."""
    kind, text = detail_json(kind, detail if detail is not None else {})
    bus.publish(names.EVENT_TOPIC, {"header": {"stamp": bus.registry.now()}, "source": source, "kind": kind,
                                    "level": EventLevel(level).value, "detail": text})
