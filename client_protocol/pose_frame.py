"""One XR frame's poses and Joy in one binary message for the poses data channel (issue 30): the head, both
controllers and both Joy states of a frame, fixed layout, versioned, little-endian, about a fifth of the JSON
publish frames' bytes and one message (one SCTP chunk) per frame instead of up to five.

Layout, version 1 (all little-endian):

    offset  size  field
    0       2     magic b"VP"
    2       1     version (1)
    3       1     flags: bit 0 head, 1 left controller pose, 2 right controller pose, 3 left Joy, 4 right Joy
                  (which blocks follow); bit 5: the poses are in Unity's axes (frame_id "unity_left_handed"),
                  else in a right-handed ROS frame (frame_id "")
    4       8     stamp: float64 seconds since 1970 (the XR frame's time; every message of the frame gets it)
    12      28    per pose present, in the order head, left, right: float32 x, y, z (metres), qx, qy, qz, qw
    ...     17    per Joy present, in the order left, right: float32 thumbstick x, thumbstick y, trigger, grip;
                  uint8 buttons (bit 0 A/X, 1 B/Y, 2 thumbstick click, 3 menu)

Decoding gives the same messages the JSON frames carry (geometry_msgs/PoseStamped, sensor_msgs/Joy as in
interface.py), so the server hands them to the same publish path and every rule still applies.
"""

from __future__ import annotations

import math
import struct
from typing import Any

from . import names

MAGIC = b"VP"
VERSION = 1
UNITY_FRAME = "unity_left_handed"
_HEADER = struct.Struct("<2sBBd")
_POSE = struct.Struct("<7f")
_JOY = struct.Struct("<4fB")
POSE_TOPICS = (names.HEAD_POSE_TOPIC, names.CONTROLLER_POSE_TOPICS["left"], names.CONTROLLER_POSE_TOPICS["right"])
JOY_TOPICS = (names.JOY_TOPICS["left"], names.JOY_TOPICS["right"])
UNITY_FLAG = 1 << 5
JOY_BUTTONS = 4


class PoseFrameError(ValueError):
    """A binary message that is not a pose frame this version reads; the text names what is wrong."""


def _header(stamp: float, frame_id: str) -> dict[str, Any]:
    secs = math.floor(stamp)
    return {"seq": 0, "stamp": {"secs": secs, "nsecs": min(999_999_999, int(round((stamp - secs) * 1e9)))},
            "frame_id": frame_id}


def decode(data: bytes) -> list[tuple[str, dict[str, Any]]]:
    """(topic, message) for each pose and Joy in the frame, poses first. Raises PoseFrameError."""
    if len(data) < _HEADER.size:
        raise PoseFrameError(f"a pose frame has at least {_HEADER.size} bytes, this one {len(data)}")
    magic, version, flags, stamp = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise PoseFrameError(f"not a pose frame: it starts {magic!r}, not {MAGIC!r} (client_protocol/pose_frame.py)")
    if version != VERSION:
        raise PoseFrameError(f"pose frame version {version}; this server reads version {VERSION}")
    if flags & ~0b111111:
        raise PoseFrameError(f"unknown flag bits {flags & ~0b111111:#04x} in a version {VERSION} pose frame")
    poses = [i for i in range(3) if flags & (1 << i)]
    joys = [i for i in range(2) if flags & (1 << (3 + i))]
    expected = _HEADER.size + len(poses) * _POSE.size + len(joys) * _JOY.size
    if len(data) != expected:
        raise PoseFrameError(f"a pose frame with these flags ({flags:#04x}) has {expected} bytes, this one "
                             f"{len(data)}")
    if not (math.isfinite(stamp) and stamp > 0):
        raise PoseFrameError(f"the stamp must be seconds since 1970, not {stamp}")
    frame_id = UNITY_FRAME if flags & UNITY_FLAG else ""
    out: list[tuple[str, dict[str, Any]]] = []
    offset = _HEADER.size
    for i in poses:
        x, y, z, qx, qy, qz, qw = _POSE.unpack_from(data, offset)
        offset += _POSE.size
        out.append((POSE_TOPICS[i], {"header": _header(stamp, frame_id),
                                     "pose": {"position": {"x": x, "y": y, "z": z},
                                              "orientation": {"x": qx, "y": qy, "z": qz, "w": qw}}}))
    for i in joys:
        *axes, buttons = _JOY.unpack_from(data, offset)
        offset += _JOY.size
        out.append((JOY_TOPICS[i], {"header": _header(stamp, ""), "axes": list(axes),
                                    "buttons": [(buttons >> b) & 1 for b in range(JOY_BUTTONS)]}))
    return out


def encode(stamp: float, poses: dict[str, tuple[float, ...]] | None = None,
           joys: dict[str, tuple[tuple[float, ...], tuple[int, ...]]] | None = None, unity: bool = True) -> bytes:
    """A frame from poses {topic: (x, y, z, qx, qy, qz, qw)} and joys {topic: (4 axes, 4 buttons)}."""
    poses, joys = poses or {}, joys or {}
    unknown = (set(poses) - set(POSE_TOPICS)) | (set(joys) - set(JOY_TOPICS))
    if unknown:
        raise ValueError(f"not a pose frame's topics: {sorted(unknown)}")
    flags = (UNITY_FLAG if unity else 0)
    body = b""
    for i, topic in enumerate(POSE_TOPICS):
        if topic in poses:
            flags |= 1 << i
            body += _POSE.pack(*poses[topic])
    for i, topic in enumerate(JOY_TOPICS):
        if topic in joys:
            axes, buttons = joys[topic]
            flags |= 1 << (3 + i)
            body += _JOY.pack(*axes, sum(1 << b for b, on in enumerate(buttons[:JOY_BUTTONS]) if on))
    return _HEADER.pack(MAGIC, VERSION, flags, stamp) + body
