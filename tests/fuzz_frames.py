"""Hostile frames for the fuzz campaign (tests/test_fuzz_campaign.py), and the oracle that says which of them
the server must answer with an error.

Wrong-typed fields are derived from the op models in client_protocol/ops.py and from the message definitions in
the type registry, so that a new op or field is fuzzed without editing this file. The oracle is the protocol's
own specification (the op models, the registry), never the server's code.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import cbor2
from hypothesis import strategies as st
from pydantic import ValidationError

from client_protocol import ops
from client_protocol.interface import ENDPOINTS
from client_protocol.registry import TypeRegistry

REGISTRY = TypeRegistry()
MAX_MESSAGE = 64 * 1024  # the campaign's server runs with this --max-message-size ...
HARD_FACTOR = 4  # ... and closes with 1009 above this many times it
PROBE_PREFIX = "/fuzz/probe"  # each fuzzing client's own liveness topic; the fuzzer never touches it
# Server streams that would flood a fuzzing client that subscribes to them with a tiny fragment size.
STREAMS = {"/qt_robot/joints/state", "/camera/color/image_raw/compressed", "/vr_teleop/teleop_state",
           "/vr_teleop/audio/robot", "/vr_teleop/hardware", "/vr_teleop/motors", "/vr_teleop/dialog"}
PUBLISHED = {e.name: e for e in ENDPOINTS if e.direction == "publish"}
CALLS = {e.name: e for e in ENDPOINTS if e.direction == "call"}
JOINT_COMMANDS = {"/qt_robot/head_position/command": 2, "/qt_robot/left_arm_position/command": 3,
                  "/qt_robot/right_arm_position/command": 3}
POSES = ("/vr/head/pose", "/vr/left_controller/pose", "/vr/right_controller/pose")
SHARED_IDS = ("1", "dup", "f", 1, 0, "goal")  # ids every fuzzing client uses, so that they collide
WRONG_POOL: tuple[Any, ...] = (None, True, False, 0, -1, 7, 2**64, 1.5, -0.0, math.inf, "", "s", "/fuzz/x", [],
                               [1, "a"], {}, {"k": 1})


@dataclass(frozen=True)
class Frame:
    """One frame to send. `conn` picks the fuzzing client; `expect` is what the sender must see before its next
    probe comes back: "error" (a status error), "close" (closed with 1009), "echo:TEXT" (a publish of TEXT on
    its probe topic, e.g. a reassembled fragment set) or None (anything well-formed, or nothing)."""

    conn: int
    payload: str | bytes
    expect: str | None
    kind: str


# ---- deriving valid and wrong-typed ops from the models ---------------------------------------------------------
def _valid_from_schema(schema: dict[str, Any]) -> Any:
    if "const" in schema:
        return schema["const"]
    if "enum" in schema:
        return schema["enum"][0]
    if "anyOf" in schema:
        branches = [b for b in schema["anyOf"] if b.get("type") != "null"]
        return _valid_from_schema(branches[0])
    kind = schema.get("type")
    if kind == "string":
        return "/fuzz/x"
    if kind == "integer":
        return schema.get("minimum", schema.get("exclusiveMinimum", -1) + 1)
    if kind == "number":
        return 1.0
    if kind == "boolean":
        return False
    if kind == "array":
        return []
    if kind == "object":
        return {}
    return {"data": "x"}  # Any


def valid_op(model: type[ops.Op]) -> dict[str, Any]:
    """A frame of this op with every field the model names set to a valid value."""
    schema = model.model_json_schema()
    frame = {name: _valid_from_schema(field) for name, field in schema["properties"].items()}
    model.model_validate(frame)  # the derivation itself must be right
    return frame


def _rejected(model: type[ops.Op], frame: dict[str, Any]) -> bool:
    try:
        model.model_validate(frame)
    except ValidationError:
        return True
    return False


def wrong_typed_ops() -> list[dict[str, Any]]:
    """For every op and every field: the op with that field missing or replaced by each value of the wrong JSON
    type (or out of range) that the model rejects."""
    frames = []
    for model in ops.CLIENT_OPS:
        base = valid_op(model)
        for name in base:
            if name == "op":
                continue
            missing = {k: v for k, v in base.items() if k != name}
            if _rejected(model, missing):
                frames.append(missing)
            for value in WRONG_POOL:
                frame = {**base, name: value}
                if _rejected(model, frame):
                    frames.append(frame)
        frames += [{**base, "op": value} for value in WRONG_POOL if not isinstance(value, str) or value in ("", "s")]
    return frames


def _valid_message(type_name: str) -> Any:
    value = REGISTRY.validate(type_name, {})
    return json.loads(value.model_dump_json(by_alias=True))


def _message_paths(type_name: str, prefix: tuple[Any, ...] = ()) -> list[tuple[tuple[Any, ...], str, int | None]]:
    """Every field of a message type, nested ones included: (path, primitive or type, array length)."""
    out = []
    for f in REGISTRY.spec(type_name).fields:
        path = prefix + (f.name,)
        out.append((path, f.type, f.array_len))
        if f.array_len is None and REGISTRY.is_known_message(f.type):
            out += _message_paths(f.type, path)
    return out


def _set_path(value: Any, path: tuple[Any, ...], new: Any) -> Any:
    value = json.loads(json.dumps(value))
    target = value
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = new
    return value


def message_rejected(type_name: str, msg: Any) -> bool:
    try:
        REGISTRY.validate(type_name, msg)
    except ValidationError:
        return True
    return False


def wrong_typed_messages() -> list[dict[str, Any]]:
    """For every topic a client publishes: the example message with each field (nested too) replaced by each
    wrong-typed value its ROS type rejects."""
    frames = []
    for name, endpoint in PUBLISHED.items():
        base = endpoint.example or _valid_message(endpoint.type)
        for path, _ftype, _array in _message_paths(endpoint.type):
            for value in WRONG_POOL:
                try:
                    msg = _set_path(base, path, value)
                except (KeyError, TypeError, IndexError):
                    continue
                if message_rejected(endpoint.type, msg):
                    frames.append({"op": "publish", "topic": name, "msg": msg})
    return frames


# ---- the oracle -------------------------------------------------------------------------------------------------
def _decode(payload: str | bytes) -> Any:
    if isinstance(payload, str):
        return json.loads(payload)
    if payload.lstrip()[:1] in (b"{", b"["):
        return json.loads(payload.decode("utf-8"))
    return cbor2.loads(payload)


def _has_lone_surrogate(value: Any) -> bool:
    stack = [value]
    while stack:
        v = stack.pop()
        if isinstance(v, str):
            try:
                v.encode("utf-8")
            except UnicodeEncodeError:
                return True
        elif isinstance(v, dict):
            stack += list(v.keys()) + list(v.values())
        elif isinstance(v, list):
            stack += v
    return False


def expected(payload: str | bytes) -> str | None:
    """What the protocol requires of the server for this frame alone: "close", "error" or None (no rule)."""
    size = len(payload.encode("utf-8", "surrogatepass") if isinstance(payload, str) else payload)
    if size > MAX_MESSAGE * HARD_FACTOR:
        return "close"
    if len(payload) > MAX_MESSAGE:
        return "error"
    try:
        raw = _decode(payload)
    except (ValueError, RecursionError, cbor2.CBORDecodeError, UnicodeDecodeError):
        return "error"
    except Exception:  # noqa: BLE001 (cbor2 raises assorted types on corrupt input)
        return "error"
    if not isinstance(raw, dict) or not isinstance(raw.get("op"), str):
        return "error"
    model = ops.CLIENT_OP_MODELS.get(raw["op"])
    if model is None or _has_lone_surrogate(raw):
        return "error"
    if _rejected(model, raw):
        return "error"
    if raw["op"] == "publish" and raw["topic"] in PUBLISHED and message_rejected(PUBLISHED[raw["topic"]].type,
                                                                                  raw.get("msg")):
        return "error"
    if raw["op"] == "publish" and raw["topic"] in JOINT_COMMANDS:
        data = raw.get("msg", {}).get("data") if isinstance(raw.get("msg"), dict) else None
        if isinstance(data, list) and (len(data) != JOINT_COMMANDS[raw["topic"]] or any(
                isinstance(x, float) and not math.isfinite(x) for x in data)):
            return "error"
    return None


# ---- strategies -------------------------------------------------------------------------------------------------
WRONG_OPS = wrong_typed_ops()
WRONG_MESSAGES = wrong_typed_messages()
json_leaf = (st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=12)
             | st.sampled_from(["/fuzz/x", "std_msgs/String", "geometry_msgs/PoseStamped", "\u202e\u200b", "\x00"]))
json_values = st.recursive(json_leaf, lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=8), c,
                                                                                           max_size=4), max_leaves=12)
op_names = st.sampled_from(sorted(ops.CLIENT_OP_MODELS) + ["", "bogus", "PUBLISH", "publish\x00"])
field_names = st.sampled_from(sorted({f for m in ops.CLIENT_OPS for f in m.model_fields}))
names = st.sampled_from(sorted(PUBLISHED) + sorted(CALLS) + sorted(JOINT_COMMANDS) + sorted(STREAMS)
                        + ["/fuzz/x", "/fuzz/unknown", "/rosapi/get_time", "", "/\u00e9\u202e", "/\U0001f916"])
ids = st.sampled_from(SHARED_IDS) | st.text(max_size=6) | st.integers(-5, 5)


def _dumps(value: Any) -> str:
    return json.dumps(value)  # allow_nan: NaN and Infinity go out as the literals some clients send


def _sanitize(frame: dict[str, Any]) -> dict[str, Any]:
    """Keeps the fuzzer off the probe channels, and off subscribing to the server's streams (which would make
    this test about bandwidth rather than hostile input)."""
    for key in ("topic", "service"):
        if isinstance(frame.get(key), str) and frame[key].startswith(PROBE_PREFIX):
            frame[key] = "/fuzz/x"
    if frame.get("op") == "subscribe" and isinstance(frame.get("topic"), str) and frame["topic"] in STREAMS:
        frame["topic"] = "/fuzz/x"
    return frame


@st.composite
def envelopes(draw: st.DrawFn) -> dict[str, Any]:
    body = draw(st.dictionaries(field_names, json_values | names | ids, max_size=6))
    return _sanitize({"op": draw(op_names), **body})


@st.composite
def endpoint_frames(draw: st.DrawFn) -> dict[str, Any]:
    """A real topic or service of the server, with its example message, perhaps with one field made hostile."""
    endpoint = draw(st.sampled_from(list(PUBLISHED.values()) + list(CALLS.values())))
    frame = endpoint.example_frame()
    frame["id"] = draw(ids)
    if draw(st.booleans()):
        body = "msg" if "msg" in frame else "args"
        paths = [p for p, _t, _a in _message_paths(endpoint.type)] if body == "msg" else []
        if paths:
            path = draw(st.sampled_from(paths))
            try:
                frame[body] = _set_path(frame[body] or _valid_message(endpoint.type), path, draw(json_values))
            except (KeyError, TypeError, IndexError):
                pass
    return frame


def _float_hostile() -> st.SearchStrategy[float]:
    return st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 5e-324, 0.0])


@st.composite
def non_finite_frames(draw: st.DrawFn) -> dict[str, Any]:
    """NaN, infinities and extremes in poses and in joint commands."""
    if draw(st.booleans()):
        topic = draw(st.sampled_from(POSES))
        msg = json.loads(json.dumps(PUBLISHED[topic].example))
        group = draw(st.sampled_from(["position", "orientation"]))
        axis = draw(st.sampled_from(["x", "y", "z"] + (["w"] if group == "orientation" else [])))
        msg["pose"][group][axis] = draw(_float_hostile())
        return {"op": "publish", "topic": topic, "msg": msg}
    topic = draw(st.sampled_from(sorted(JOINT_COMMANDS)))
    data = draw(st.lists(_float_hostile() | st.floats(-400, 400), min_size=JOINT_COMMANDS[topic],
                         max_size=JOINT_COMMANDS[topic]))
    return {"op": "publish", "topic": topic, "msg": {"data": data}}


@st.composite
def huge_frames(draw: st.DrawFn) -> str:
    n = draw(st.sampled_from([1_000, 10_000, 20_000, 100_000]))
    topic = draw(st.sampled_from(sorted(JOINT_COMMANDS) + ["/fuzz/x"]))
    return _dumps({"op": "publish", "topic": topic, "msg": {"data": [draw(st.floats(-1, 1))] * n}})


@st.composite
def deep_frames(draw: st.DrawFn) -> str | bytes:
    depth = draw(st.sampled_from([50, 500, 990, 2_000, 30_000]))
    where = draw(st.sampled_from(["msg", "op", "top", "cbor"]))
    if where == "cbor":
        return b"\xa3bopgpublishetopicg/fuzz/xcmsg" + b"\x81" * depth + b"\x00"
    nest = "[" * depth + "]" * depth
    if where == "top":
        return nest
    if where == "op":
        return '{"op":' + nest + "}"
    return '{"op":"publish","topic":' + json.dumps(draw(st.sampled_from(["/fuzz/x", "/vr/head/pose"]))) + \
        ',"msg":{"data":' + nest + "}}"


@st.composite
def unicode_frames(draw: st.DrawFn) -> str:
    """Strings at the edges of Unicode: lone surrogates (as JSON escapes), non-characters, NUL, RTL overrides,
    zero-width joiners, astral characters, in topic names and in message strings."""
    odd = draw(st.sampled_from(["\\ud800", "\\udfff", "\\ud83e\\udd16", "\\uffff", "\\ufffe", "\\u0000",
                                "\\u202e", "\\u200d", "\U0010ffff", "\u00e9\u0301", "a" * 300]))
    where = draw(st.sampled_from(["data", "topic", "op", "key", "type"]))
    text = draw(st.text(max_size=5)).replace("\\", "").replace('"', "")
    s = json.dumps(text)[1:-1] + odd
    if where == "data":
        topic = draw(st.sampled_from(["/fuzz/x", "/qt_robot/emotion/show", "/qt_robot/speech/say", "/fuzz/unknown"]))
        return f'{{"op":"publish","topic":"{topic}","msg":{{"data":"{s}"}}}}'
    if where == "topic":
        return f'{{"op":"subscribe","topic":"/{s}","type":"std_msgs/String"}}'
    if where == "type":
        return f'{{"op":"advertise","topic":"/fuzz/u","type":"{s}"}}'
    if where == "key":
        return f'{{"op":"publish","topic":"/fuzz/unknown","msg":{{"{s}":1}}}}'
    return f'{{"op":"{s}"}}'


@st.composite
def malformed(draw: st.DrawFn) -> str | bytes:
    good = _dumps(draw(envelopes()))
    how = draw(st.sampled_from(["truncate", "garbage", "bytes", "bad-utf8", "cbor-truncate", "cbor-odd", "text"]))
    if how == "truncate":
        return good[:draw(st.integers(0, max(0, len(good) - 1)))]
    if how == "garbage":
        return good + draw(st.sampled_from(["}", ",", " x", "\x00", "{}"]))
    if how == "bytes":
        return draw(st.binary(max_size=64))
    if how == "bad-utf8":
        return b'{"op":"publish","topic":"/fuzz/x","msg":{"data":"' + draw(st.sampled_from(
            [b"\xff", b"\xc0\xaf", b"\xed\xa0\x80", b"\xf4\x90\x80\x80"])) + b'"}}'
    if how == "cbor-truncate":
        data = cbor2.dumps(draw(envelopes()))
        return data[:draw(st.integers(0, max(0, len(data) - 1)))]
    if how == "cbor-odd":
        odd = draw(st.sampled_from([cbor2.CBORTag(99, 1), b"\x00\x01", cbor2.undefined, {1, 2}, 2**80,
                                    math.nan, {b"k": 1}, {1: 2}]))
        return cbor2.dumps({"op": "publish", "topic": draw(st.sampled_from(["/fuzz/unknown", "/fuzz/x",
                                                                              "/vr/head/pose"])),
                            "msg": {"data": odd}})
    return draw(st.text(max_size=40))


@st.composite
def frame_payloads(draw: st.DrawFn) -> str | bytes:
    kind = draw(st.sampled_from(["wrong-op", "wrong-msg", "envelope", "endpoint", "non-finite", "huge", "deep",
                                 "unicode", "malformed", "cbor"]))
    if kind == "wrong-op":
        return _dumps(_sanitize(dict(draw(st.sampled_from(WRONG_OPS)))))
    if kind == "wrong-msg":
        return _dumps(draw(st.sampled_from(WRONG_MESSAGES)))
    if kind == "envelope":
        return _dumps(draw(envelopes()))
    if kind == "endpoint":
        return _dumps(draw(endpoint_frames()))
    if kind == "non-finite":
        frame = draw(non_finite_frames())
        return cbor2.dumps(frame) if draw(st.booleans()) else _dumps(frame)
    if kind == "huge":
        return draw(huge_frames())
    if kind == "deep":
        return draw(deep_frames())
    if kind == "unicode":
        return draw(unicode_frames())
    if kind == "cbor":
        return cbor2.dumps(draw(envelopes() | endpoint_frames()))
    return draw(malformed())


def fragment_frames(conn: int, frag_id: Any, inner: str, pieces: int, how: str, order: list[int]) -> list[Frame]:
    """One fragment set of `inner` (JSON text) from `conn`: complete, shuffled, overlapping, conflicting, with a
    wrong total, with a num out of range, or never finished."""
    size = max(1, math.ceil(len(inner) / pieces))
    parts = [inner[i:i + size] for i in range(0, len(inner), size)]
    total = len(parts)

    def frag(num: int, data: str, tot: int = total) -> str:
        return _dumps({"op": "fragment", "id": frag_id, "data": data, "num": num, "total": tot})

    seq = [i for i in order if i < total] if how == "shuffled" else list(range(total))
    marker = json.loads(inner)["msg"]["data"]
    done = f"echo:{marker}"
    if how in ("in-order", "shuffled"):
        return [Frame(conn, frag(n, parts[n]), None, "fragment") for n in seq[:-1]] + \
            [Frame(conn, frag(seq[-1], parts[seq[-1]]), done, "fragment")]
    if how == "overlapping":  # every piece but the last twice, identical: harmless
        return [Frame(conn, frag(n, parts[n]), None, "fragment") for n in range(total - 1) for _ in (0, 1)] + \
            [Frame(conn, frag(total - 1, parts[-1]), done, "fragment")]
    if how == "conflicting" and total > 1:
        return [Frame(conn, frag(0, parts[0]), None, "fragment"),
                Frame(conn, frag(0, parts[0] + "x"), "error", "fragment")]
    if how == "wrong-total" and total > 1:
        return [Frame(conn, frag(0, parts[0]), None, "fragment"),
                Frame(conn, frag(1, parts[1], total + 1), "error", "fragment")]
    if how == "num-out-of-range":
        return [Frame(conn, frag(total, parts[0]), "error", "fragment")]
    # never finished: all but one piece; the set expires later
    if total == 1:
        return [Frame(conn, frag(0, parts[0], 2), None, "fragment")]
    return [Frame(conn, frag(n, parts[n]), None, "fragment") for n in range(total - 1)]


@st.composite
def fragment_sets(draw: st.DrawFn, conn: int, probe_topic: str, counter: list[int]) -> list[Frame]:
    counter[0] += 1
    marker = f"frag-{conn}-{counter[0]}"
    inner = _dumps({"op": "publish", "topic": probe_topic, "msg": {"data": marker}})
    how = draw(st.sampled_from(["in-order", "shuffled", "overlapping", "conflicting", "wrong-total",
                                "num-out-of-range", "unfinished"]))
    frag_id = draw(st.sampled_from(SHARED_IDS))
    if how == "unfinished":
        frag_id = f"never-{marker}"  # a shared id would be completed by a later set with the same id
    elif how in ("conflicting", "wrong-total", "num-out-of-range"):
        frag_id = f"bad-{marker}"
    pieces = draw(st.integers(1, 8))
    order = draw(st.permutations(list(range(pieces))))
    return fragment_frames(conn, frag_id, inner, pieces, how, list(order))
