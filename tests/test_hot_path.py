"""The publish hot path's shortcuts decide exactly as the slow path they stand in for.

pydantic-core parses frames and a plain check accepts well-formed publish envelopes because json.loads and the
op model cost a third of a publish (bench/suite.py's profile); these properties hold them to the same answers.
"""

from __future__ import annotations

import json

from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from client_protocol.ops import Publish
from vr_teleop_server.session import _well_formed_publish
from vr_teleop_server.wire import FrameError, _loads_json

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
