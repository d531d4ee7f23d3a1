"""The publish hot path's shortcuts decide exactly as the slow path they stand in for.

pydantic-core parses frames, a plain check accepts well-formed publish envelopes, and known messages are validated
to plain dicts (PlainCodec), because json.loads, the op model and model instances were most of a relayed
publish's cost (py-spy); these properties hold the shortcuts to the slow path's answers.
"""

from __future__ import annotations

import base64
import json

import pytest

from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from client_protocol.ops import Publish
from client_protocol.registry import TypeRegistry
from vr_teleop_server.core.session.topics import _well_formed_publish
from vr_teleop_server.core.wire import FrameError, _loads_json

scalars = (st.none() | st.booleans() | st.integers() | st.integers(min_value=2**63, max_value=2**80)
           | st.floats() | st.text(max_size=12))
values = st.recursive(scalars, lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=6), c, max_size=4),
                      max_leaves=12)
# JSON text as clients write it, plus the corners where parsers differ: NaN and Infinity, escapes, surrogates
# (paired and lone), control characters, trailing data, duplicate keys, deep nesting, leading zeros
corners = st.sampled_from(['{"a":NaN}', '{"a":-Infinity}', '{"a":"\\ud83d\\ude00"}', '{"a":"\\ud800"}',
                           '{"a":"\\udc00x"}', '{"a":"x\ty"}', '{"a":1} x', '{"a":1,"a":2}', "[" * 400 + "]" * 400,
                           '{"a":01}', '{"a":1e400}', '{"a":-0}', '\ufeff{}', '{"a":"\\u0000"}', "{'a':1}", ""])
texts = values.map(lambda v: json.dumps(v)) | corners | st.text(max_size=30)


def _decide(parse, text):
    try:
        return "ok", repr(parse(text))
    except (FrameError, ValueError, RecursionError) as exc:
        return "refused", str(exc) if isinstance(exc, FrameError) else type(exc).__name__


@settings(max_examples=600, deadline=None)
@given(texts)
def test_frames_parse_as_json_loads_parses_them(text):
    def reference(t: str):
        value = json.loads(t)
        try:  # what the server refuses after json.loads: lone surrogates
            json.dumps(value, ensure_ascii=False).encode("utf-8")
        except UnicodeEncodeError:
            raise ValueError("lone surrogate") from None
        return value

    ours = _decide(_loads_json, text)
    expected = _decide(reference, text)
    assert ours[0] == expected[0], (text, ours, expected)
    if ours[0] == "ok":
        assert ours[1] == expected[1], text


envelope_values = st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5) | st.lists(
    st.integers(), max_size=2) | st.dictionaries(st.text(max_size=3), st.integers(), max_size=2)


@settings(max_examples=800, deadline=None)
@given(st.dictionaries(st.sampled_from(["topic", "msg", "latch", "id", "extra"]), envelope_values))
def test_publish_envelopes_are_accepted_only_where_the_model_accepts_them(body):
    raw = {"op": "publish", **body}
    fast = _well_formed_publish(raw)
    try:
        model = Publish.model_validate(raw)
    except ValidationError:
        model = None
    if fast is None:
        return  # the model decides, as before
    assert model is not None, raw
    assert (fast.topic, fast.msg, fast.latch, fast.id) == (model.topic, model.msg, model.latch, model.id)


# ---- known message types: PlainCodec against the models ---------------------------------------------------------
REGISTRY = TypeRegistry()
_INT_BOUNDS = {"int8": (-128, 127), "byte": (-128, 127), "uint8": (0, 255), "char": (0, 255),
               "int16": (-2**15, 2**15 - 1), "uint16": (0, 2**16 - 1), "int32": (-2**31, 2**31 - 1),
               "uint32": (0, 2**32 - 1), "int64": (-2**63, 2**63 - 1), "uint64": (0, 2**64 - 1)}
wrong = st.sampled_from([None, True, "1", 1.5, [], {}, {"bogus": 1}, 2**70, -1, float("nan"), float("inf")])


def _element(ftype: str, depth: int):
    if ftype in _INT_BOUNDS:
        lo, hi = _INT_BOUNDS[ftype]
        good = st.integers(lo, hi) | st.sampled_from([lo, hi]) | st.sampled_from([lo - 1, hi + 1])
    elif ftype in ("float32", "float64"):
        good = st.floats() | st.integers(-2**60, 2**60) | st.just(10**400)
    elif ftype == "bool":
        good = st.booleans()
    elif ftype == "string":
        good = st.text(max_size=8)
    elif ftype in ("time", "duration"):
        secs = st.integers(-2**31 - 1, 2**32)
        nsecs = st.integers(-1, 10**9)
        good = (st.fixed_dictionaries({}, optional={"secs": secs, "nsecs": nsecs})
                | st.fixed_dictionaries({}, optional={"sec": secs, "nanosec": nsecs})
                | st.fixed_dictionaries({"secs": secs, "sec": secs}))
    else:
        good = _message(ftype, depth + 1)
    return good | wrong if depth < 3 else good


def _field(f, depth: int):
    if f.is_byte_array:
        data = st.binary(max_size=8) if not f.array_len else st.binary(min_size=f.array_len, max_size=f.array_len)
        return (data.map(lambda b: base64.b64encode(b).decode()) | data.map(list) | st.just("not base64!")
                | st.lists(st.integers(-1, 256), max_size=4) | wrong)
    element = _element(f.type, depth)
    if f.array_len is None:
        return element
    size = {"min_size": f.array_len, "max_size": f.array_len} if f.array_len else {"max_size": 3}
    return st.lists(element, **size) | st.lists(element, max_size=2) | wrong


def _message(name: str, depth: int = 0):
    spec = REGISTRY.spec(name)
    fields = {f.name: _field(f, depth) for f in spec.fields}
    body = st.fixed_dictionaries({}, optional=fields)
    return body | body.map(lambda d: {**d, "extra_field": 1}) if depth == 0 else body


def _without_default_stamps(given, dumped):
    """Stamps the sender left out are the time of validation: they differ between two validations."""
    if isinstance(dumped, dict):
        given = given if isinstance(given, dict) else {}
        return {k: ("now" if k == "stamp" and "stamp" not in given else _without_default_stamps(given.get(k), v))
                for k, v in dumped.items()}
    if isinstance(dumped, list):
        given = given if isinstance(given, list) else []
        return [_without_default_stamps(given[i] if i < len(given) else None, v) for i, v in enumerate(dumped)]
    return dumped


@pytest.mark.parametrize("name", REGISTRY.message_names())
def test_known_messages_validate_and_dump_as_their_models_do(name):
    codec = REGISTRY.codec(name)
    model = REGISTRY.model(name)

    @settings(max_examples=60, deadline=None)
    @given(_message(name) | st.none() | wrong)
    def check(data):
        try:
            expected = model.model_validate({} if data is None else data)
        except ValidationError:
            expected = None
        try:
            plain = codec.validate(data)
        except ValidationError:
            plain = None
        assert (plain is None) == (expected is None), (data, plain, expected)
        if plain is not None:
            ours = json.loads(codec.to_json(plain))
            theirs = json.loads(expected.model_dump_json(by_alias=True))
            assert _without_default_stamps(data, ours) == _without_default_stamps(data, theirs)
            assert codec.to_model(plain).model_dump_json() == model.model_validate(plain).model_dump_json()

    check()
