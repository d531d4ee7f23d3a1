"""The event channel: server events (engage, e-stop, backend lost, menu picks...) on one topic that recordings, the
dashboard and logs all read. Any feature publishes here without knowing who else does."""

from __future__ import annotations

import json
from typing import Any

from client_protocol import names

from .bus import Bus


def declare_event_topic(bus: Bus) -> None:
    bus.declare_topic(names.EVENT_TOPIC, "vr_teleop_msgs/Event", persistent=True)


def publish_event(bus: Bus, source: str, kind: str, level: str = "info", detail: Any = "") -> None:
    """Puts a server event on /vr_teleop/events (recordings, the dashboard and logs all read it there)."""
    text = detail if isinstance(detail, str) else json.dumps(detail, sort_keys=True)
    bus.publish(names.EVENT_TOPIC, {"header": {"stamp": bus.registry.now()}, "source": source, "kind": kind,
                                    "level": level, "detail": text})
