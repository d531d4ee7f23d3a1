"""Frames in and out: JSON and CBOR decoding, and the outgoing encodings rosbridge defines (none, png, cbor,
cbor-raw, fragments)."""

from __future__ import annotations

import base64
import functools
import json
import math
import re
from typing import Any

import cbor2
import cv2
import numpy as np
from pydantic_core import from_json

from client_protocol.registry import TypeRegistry

from .bus import Published


class FrameError(ValueError):
    """A frame that cannot be read as a rosbridge message; the text says why."""


def decode_frame(frame: str | bytes) -> dict[str, Any]:
    """TEXT frames carry JSON. BINARY frames carry UTF-8 JSON (as ROS# sends it) or CBOR."""
    if isinstance(frame, str):
        try:
            value = from_json(frame)  # _loads_json's first step, spared a call on the hot path
        except (ValueError, TypeError):
            value = _loads_json(frame)
        return _check_envelope(value)
    stripped = frame.lstrip()
    if stripped[:1] in (b"{", b"["):
        try:
            text = frame.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise FrameError(f"binary frame looks like JSON but is not valid UTF-8 ({exc.reason} at byte "
                             f"{exc.start})") from None
        return _check_envelope(_loads_json(text))
    try:
        value = cbor2.loads(frame)
    except Exception as exc:  # cbor2 raises several types for corrupt input
        raise FrameError(f"binary frame is neither JSON nor valid CBOR ({exc})") from None
    return _check_envelope(value)


def _loads_json(text: str) -> Any:
    try:
        # pydantic-core's parser takes a third of json.loads's time on a pose (py-spy). It refuses lone
        # surrogates, deep nesting and anything else json.loads would refuse, and where it accepts, the value is
        # the same; whatever it refuses, the standard parser decides and words the error.
        return from_json(text)
    except (ValueError, TypeError):
        pass
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FrameError(f"invalid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from None
    except RecursionError:
        raise FrameError("invalid JSON: nested too deeply") from None
    if _SURROGATE_ESCAPE.search(text) is not None:
        _refuse_lone_surrogates(value)
    return value


# A \uD800-\uDFFF escape: paired, json.loads joins it into one character; alone, it leaves a string that cannot
# be sent on as UTF-8, which would stop every subscriber's connection.
_SURROGATE_ESCAPE = re.compile(r"\\u[dD][89a-fA-F]")


def _refuse_lone_surrogates(value: Any) -> None:
    stack = [value]
    while stack:
        item = stack.pop()
        if isinstance(item, str):
            try:
                item.encode("utf-8")
            except UnicodeEncodeError:
                raise FrameError(f"invalid JSON: the string {item[:40]!r} holds a lone UTF-16 surrogate "
                                 f"(\\u{ord(item[_first_surrogate(item)]):04x}); characters beyond U+FFFF need "
                                 f"both halves of the pair") from None
        elif isinstance(item, dict):
            stack.extend(item.keys())
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item)


def _first_surrogate(text: str) -> int:
    return next(i for i, c in enumerate(text) if 0xD800 <= ord(c) <= 0xDFFF)


def _check_envelope(value: Any) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise FrameError(f"a rosbridge message must be a JSON object with an 'op' field, not {type(value).__name__}")
    op = value.get("op")
    if not isinstance(op, str):
        raise FrameError("the message has no 'op' field (a string such as \"publish\")" if op is None
                         else f"'op' must be a string, not {type(op).__name__}")
    return value


def dumps(value: Any) -> str:
    return json.dumps(value, separators=(",", ":"))  # ensure_ascii: \u escapes, as ascii_json below


_NON_ASCII = re.compile(r"[^\x00-\x7f]")


def _escape(match: re.Match[str]) -> str:
    code = ord(match.group())
    if code > 0xFFFF:  # beyond the BMP: a UTF-16 surrogate pair, as JSON spells it
        code -= 0x10000
        return "\\u%04x\\u%04x" % (0xD800 + (code >> 10), 0xDC00 + (code & 0x3FF))
    return "\\u%04x" % code


def ascii_json(text: str) -> str:
    """JSON text with every non-ASCII character as a \\u escape: clients that decode frames as ASCII (ROS#) read
    "Tr\\u00e8s" intact. Outside strings JSON has no non-ASCII characters, so escaping every one is exact.
    str.isascii() is a C loop: the common, all-ASCII message costs next to nothing."""
    return text if text.isascii() else _NON_ASCII.sub(_escape, text)


# Time values in the other style, rewritten in JSON text the serializer made ({"secs":S,"nsecs":N}, compact, in
# that order). Inside a JSON string a quote is always escaped, so `{"` never matches there.
_TIME_TEXT = {
    "ros2": (re.compile(r'\{"secs":(-?\d+),"nsecs":(\d+)\}'), r'{"sec":\1,"nanosec":\2}'),
    "ros1": (re.compile(r'\{"sec":(-?\d+),"nanosec":(\d+)\}'), r'{"secs":\1,"nsecs":\2}'),
}


def restyle_times(text: str, style: str) -> str:
    """`text` (made in the other style) with its times as `style` spells them."""
    pattern, replacement = _TIME_TEXT[style]
    return pattern.sub(replacement, text)


def message_json(published: Published) -> str:
    """The message's JSON text, made once per message."""
    text = published.encoded.get("msg_json")
    if text is None:
        if published.plain is not None:
            text = published.codec.to_json(published.plain)
        else:
            value = published.value
            text = value.model_dump_json(by_alias=True) if published.known else dumps(value)
        # (the serializer's ensure_ascii would spare this pass, but is slower: 2.0 against 1.5 µs a pose)
        text = ascii_json(text)
        published.encoded["msg_json"] = text
    return text


def publish_text(published: Published) -> str:
    text = published.encoded.get("none")
    if text is None:
        text = f'{{"op":"publish","topic":{_quoted(published.topic)},"msg":{message_json(published)}}}'
        published.encoded["none"] = text
    return text


@functools.lru_cache(maxsize=1024)
def _quoted(topic: str) -> str:
    """A topic's name as a JSON string, made once per topic rather than once per message."""
    return json.dumps(topic)


def publish_text_in_style(published: Published, style: str) -> str:
    """publish_text for a client whose time style is not the registry's (cached per style)."""
    key = f"none:{style}"
    text = published.encoded.get(key)
    if text is None:
        text = publish_text(published)
        if published.known:
            text = restyle_times(text, style)
        published.encoded[key] = text
    return text


def publish_cbor(published: Published, registry: TypeRegistry, raw: bool) -> bytes:
    key = "cbor-raw" if raw else "cbor"
    frame = published.encoded.get(key)
    if frame is None:
        if raw:
            secs, nsecs = registry.now().values()
            msg: Any = {"secs": secs, "nsecs": nsecs,
                        "bytes": registry.serialize_ros1(published.type, published.value)}
        elif published.known:
            msg = registry.to_cbor_value(published.type, published.value)
        else:
            msg = published.value
        frame = cbor2.dumps({"op": "publish", "topic": published.topic, "msg": msg})
        published.encoded[key] = frame
    return frame


def png_pack(text: str) -> str:
    """rosbridge's png encoding: the JSON text's bytes as the RGB pixels of a square image, padded with
    newlines (which JSON ignores), PNG-encoded, then base64."""
    data = text.encode("utf-8")
    side = max(1, math.ceil(math.sqrt(len(data) / 3)))
    padded = data + b"\n" * (side * side * 3 - len(data))
    rgb = np.frombuffer(padded, dtype=np.uint8).reshape(side, side, 3)
    ok, png = cv2.imencode(".png", rgb[:, :, ::-1])  # OpenCV writes BGR
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return base64.b64encode(png.tobytes()).decode("ascii")


def png_unpack(data: str) -> str:
    """The inverse of png_pack (clients do this; tests use it)."""
    png = np.frombuffer(base64.b64decode(data), dtype=np.uint8)
    bgr = cv2.imdecode(png, cv2.IMREAD_COLOR)
    return bgr[:, :, ::-1].tobytes().decode("utf-8").rstrip("\n")


def split_fragments(op: str, text: str, size: int, frag_id: str) -> list[str]:
    """Splits `text` into rosbridge `fragment` (or `png`) frames of at most `size` characters of data."""
    pieces = [text[i:i + size] for i in range(0, len(text), size)] or [""]
    total = len(pieces)
    return [dumps({"op": op, "id": frag_id, "data": piece, "num": num, "total": total})
            for num, piece in enumerate(pieces)]


def encode_for_client(text: str, compression: str, fragment_size: int | None, frag_id: str) -> list[str]:
    """A JSON reply (service response, action result...) as the client asked: plain, png, and/or fragmented."""
    if compression == "png":
        packed = png_pack(text)
        if fragment_size and len(packed) > fragment_size:
            return split_fragments("png", packed, fragment_size, frag_id)
        return [dumps({"op": "png", "data": packed})]
    if fragment_size and len(text) > fragment_size:
        return split_fragments("fragment", text, fragment_size, frag_id)
    return [text]
