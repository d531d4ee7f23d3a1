"""Property-based: arbitrary JSON and arbitrary bytes never break the server or the connection."""

from __future__ import annotations

import json

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from client_protocol.ops import CLIENT_OP_MODELS

json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=20),
    lambda children: st.lists(children, max_size=5) | st.dictionaries(st.text(max_size=10), children, max_size=5),
    max_leaves=20,
)
op_names = st.sampled_from(sorted(CLIENT_OP_MODELS) + ["", "bogus", "PUBLISH"])
fields = st.sampled_from(["id", "topic", "type", "msg", "service", "args", "values", "result", "num", "total",
                          "data", "level", "action", "action_type", "throttle_rate", "queue_length",
                          "fragment_size", "compression", "timeout", "latch", "status", "feedback"])
envelopes = st.builds(lambda op, body: {"op": op, **body}, op_names,
                      st.dictionaries(fields, json_values | st.sampled_from(["/t", "std_msgs/String"]),
                                      max_size=6))

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _answers_or_ignores_then_still_works(client) -> None:
    """Whatever came back must be a well-formed rosbridge message; then a valid publish still arrives."""
    client.send({"op": "publish", "topic": "/fuzz/check", "msg": {"data": "ok"}})
    for _ in range(200):
        frame = client.recv_frame(timeout=3)
        message = json.loads(frame) if isinstance(frame, str) else None
        if message is None:
            continue  # a cbor subscription the fuzzer made; it is still a valid frame
        assert isinstance(message.get("op"), str), message
        if message["op"] == "publish" and message.get("topic") == "/fuzz/check":
            return
    raise AssertionError("the valid publish never arrived")


@pytest.fixture
def fuzz_client(client):
    client.send({"op": "subscribe", "id": "check", "topic": "/fuzz/check", "type": "std_msgs/String"})
    client.send({"op": "advertise", "topic": "/fuzz/check", "type": "std_msgs/String"})
    return client


@FUZZ
@given(message=envelopes)
def test_arbitrary_ops_with_arbitrary_fields(fuzz_client, message):
    if message.get("topic") == "/fuzz/check" and message["op"] in ("unsubscribe", "unadvertise", "subscribe",
                                                                    "advertise"):
        message["topic"] = "/elsewhere"  # keep the check channel itself intact
    fuzz_client.send_raw(json.dumps(message))
    _answers_or_ignores_then_still_works(fuzz_client)


@FUZZ
@given(value=json_values)
def test_arbitrary_json_values(fuzz_client, value):
    fuzz_client.send_raw(json.dumps(value))
    _answers_or_ignores_then_still_works(fuzz_client)


@FUZZ
@given(data=st.binary(max_size=300) | st.text(max_size=300))
def test_arbitrary_bytes_and_text(fuzz_client, data):
    fuzz_client.send_raw(data)
    _answers_or_ignores_then_still_works(fuzz_client)
