"""Typed events: every kind's detail is checked against its model before it reaches the bus, the wire keeps
vr_teleop_msgs/Event's four strings, and headers are on the clock the registry was given."""

from __future__ import annotations

import json

import pytest

from client_protocol import names
from client_protocol.events import KINDS, EventKind, GestureRecording, PartSwitch, parse_detail
from client_protocol.registry import TypeRegistry
from simclock import EPOCH, SimulatedClock
from vr_teleop_server.core.bus import SERVER_NODE, Bus
from vr_teleop_server.core.events import declare_event_topic, publish_event


def bus_and_events(clock=None) -> tuple[Bus, list]:
    bus = Bus(TypeRegistry(clock=clock) if clock is not None else TypeRegistry())
    declare_event_topic(bus)
    got: list = []
    bus.subscribe(SERVER_NODE, names.EVENT_TOPIC, None, got.append)
    return bus, got


def test_every_kind_has_a_model_and_a_source():
    assert set(KINDS) == set(EventKind)
    assert {spec.source for spec in KINDS.values()} == {"teleop", "menu", "gestures", "motivation", "backend",
                                                        "experimenter", "autonomy"}


def test_a_detail_as_a_model_or_a_dict_reaches_the_wire_as_the_same_json_text():
    bus, got = bus_and_events()
    publish_event(bus, "teleop", EventKind.HEAD_OFF, "info", PartSwitch(by="c1", part="head", enabled=False))
    publish_event(bus, "teleop", "head_off", "info", {"by": "c1", "part": "head", "enabled": False})
    first, second = (p.data for p in got)
    assert first["kind"] == second["kind"] == "head_off" and first["level"] == "info"
    assert first["detail"] == second["detail"] == '{"by": "c1", "enabled": false, "part": "head"}'
    assert parse_detail(first["kind"], first["detail"]) == PartSwitch(by="c1", part="head", enabled=False)


def test_a_kind_or_a_detail_its_model_does_not_know_is_refused_before_the_bus():
    bus, got = bus_and_events()
    with pytest.raises(ValueError, match="unknown event kind 'head_of'"):
        publish_event(bus, "teleop", "head_of", "info", {"by": "c1"})
    with pytest.raises(ValueError, match="recording"):
        publish_event(bus, "gestures", EventKind.GESTURE_RECORDING, "info", {"parts": ["head"]})
    with pytest.raises(ValueError, match="extra"):
        publish_event(bus, "backend", EventKind.MOTOR_OK, "info", {"motor": "HeadYaw", "motr": "typo"})
    with pytest.raises(ValueError):
        publish_event(bus, "backend", EventKind.MOTOR_OK, "loud", {"motor": "HeadYaw"})
    assert got == []


def test_the_detail_keeps_the_fields_clients_read_today():
    bus, got = bus_and_events()
    publish_event(bus, "backend", "motor_error", "danger", {"motor": "RightElbowRoll", "faults": ["overload_limit"]})
    publish_event(bus, "gestures", EventKind.GESTURE_RECORDING, "info", GestureRecording(recording=True,
                                                                                         parts=["head"]))
    assert json.loads(got[0].data["detail"]) == {"motor": "RightElbowRoll", "faults": ["overload_limit"]}
    assert json.loads(got[1].data["detail"]) == {"recording": True, "parts": ["head"]}


def test_event_headers_are_on_the_registrys_clock():
    clock = SimulatedClock()
    clock.advance(12.5)
    bus, got = bus_and_events(clock)
    publish_event(bus, "teleop", EventKind.ENGAGE, "info", {"holder": "c1"})
    assert got[0].data["header"]["stamp"] == {"secs": int(EPOCH) + 12, "nsecs": 500_000_000}
    assert got[0].plain is not None  # stamped as plain data: the server's own messages take the plain path too
    assert TypeRegistry(clock=clock, time_style="ros2").now() == {"sec": int(EPOCH) + 12, "nanosec": 500_000_000}


def test_a_motivation_event_names_its_variable_in_the_kind_as_it_always_has():
    bus, got = bus_and_events()
    publish_event(bus, "motivation", EventKind.MOTIVATION_HIGH, "warning",
                  {"variable": "frustration", "value": 81.0, "side": "high", "limit": 80.0})
    (event,) = (p.data for p in got)
    assert event["kind"] == "frustration_high"
    assert parse_detail(EventKind.MOTIVATION_HIGH, event["detail"]).variable == "frustration"
