"""The operator's poses and Joy over a WebRTC data channel ("poses": unordered, no retransmissions).

Over a lossy WAN a lost TCP segment holds up every pose behind it; on an unordered, unreliable channel a lost
pose is simply gone and the next one is not held up. The client sends on it the very publish frames it would send
over rosbridge for /vr/head/pose, the controller poses and Joy, and each one that passes the channel's checks is
handed to the client's own session as if it had come over its WebSocket: the same parsing, typed validation,
access policy and bus publish with the session as sender, so that explicit control's holder rule applies and there
is no back door to the robot.

The channel's own checks, in front: a text JSON publish frame, for one of the operator's stream topics, from a
client whose operator holds control (before engaging, poses go over the WebSocket: engage needs one). Refusals
are counted for the telemetry and the client hears why in a status on its WebSocket, at most once a second.
Newest wins: unordered delivery may hand over a message after a newer one of its topic; one stamped before the
newest taken on that topic is dropped and counted (a stamp more than CLOCK_RESET_S behind is a headset clock that
started over, and is taken).

A binary message is one XR frame's poses and Joy in the compact layout of client_protocol/pose_frame.py: it is
decoded into the same publish frames, each checked and handed over as above (JSON frames stay accepted).
"""

from __future__ import annotations

import json
import math
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from client_protocol import names, pose_frame
from simclock import WALL, Clock

OPERATOR_TOPICS = frozenset({names.HEAD_POSE_TOPIC, *names.CONTROLLER_POSE_TOPICS.values(),
                             *names.JOY_TOPICS.values()})
REFUSAL_INTERVAL_S = 1.0  # a refused client hears about it at most this often, not 90 times a second
CLOCK_RESET_S = 2.0  # as the watchdog's pose link (teleop/link.py)


class ChannelSession(Protocol):
    """What the channel needs of the client's rosbridge session (core.session.Session)."""

    name: str
    closed: bool
    counters: dict[str, int]
    last_error: str

    def handle_frame(self, frame: str) -> Awaitable[None]: ...

    def status(self, level: str, message: str) -> None: ...


@dataclass
class ChannelCounts:
    received: int = 0
    pose_frames: int = 0  # of the received, binary pose frames decoded (the rest: JSON publish frames or refused)
    handed: int = 0  # publish frames handed to the session: one per JSON frame, one per pose and Joy of a pose frame
    refused: int = 0
    stale_dropped: int = 0
    last_refusal: str = ""


@dataclass
class PoseChannel:
    """One client's data channels (one peer connection's): checks each message, then hands it to the client's
    session as a publish. Only the channel labelled POSES_CHANNEL carries poses; another's messages are refused."""

    session: ChannelSession
    holds_control: Callable[[str], bool]  # the session's name -> whether its operator holds control
    clock: Clock = WALL  # the server's: refusals are told at most once a second of it
    counts: ChannelCounts = field(default_factory=ChannelCounts)
    _newest: dict[str, float] = field(default_factory=dict)  # topic -> newest stamp taken
    _last_told: float = -1e9

    async def on_message(self, message: str | bytes, label: str = names.POSES_CHANNEL) -> None:
        session = self.session
        if session.closed:
            return
        self.counts.received += 1
        if isinstance(message, bytes) and label == names.POSES_CHANNEL:
            try:
                decoded = pose_frame.decode(message)
            except pose_frame.PoseFrameError as exc:
                self._refuse(f"a binary message that is not a pose frame: {exc}; send pose frames "
                             "(client_protocol/pose_frame.py) or publish frames as text (JSON)")
                return
            self.counts.pose_frames += 1
            for topic, msg in decoded:  # the frame's messages, each as its JSON publish frame would be
                await self._take(json.dumps({"op": "publish", "topic": topic, "msg": msg}))
                if session.closed:
                    return
            return
        await self._take(message, label)

    async def _take(self, message: str | bytes, label: str = names.POSES_CHANNEL) -> None:
        session = self.session
        frame, reason = self._check(message, label)
        if reason:
            self._refuse(reason)
            return
        topic = frame["topic"]
        stamp = _stamp_seconds(frame.get("msg"))
        newest = self._newest.get(topic)
        if stamp is not None and newest is not None and 0 < newest - stamp <= CLOCK_RESET_S:
            self.counts.stale_dropped += 1  # overtaken by a newer one: never replayed
            return
        errors = session.counters.get("errors", 0)
        self.counts.handed += 1
        await session.handle_frame(message)  # the WebSocket's own path: validation, access, bus, holder rule
        if session.counters.get("errors", 0) != errors:  # it answered with a status error (already sent)
            self.counts.refused += 1
            self.counts.last_refusal = session.last_error[:200]
        elif stamp is not None:
            self._newest[topic] = stamp

    def _check(self, message: str | bytes, label: str) -> tuple[dict[str, Any], str]:
        if label != names.POSES_CHANNEL:
            return {}, (f"data channel {label[:40]!r} is not one this server reads: open one labelled "
                        f"{names.POSES_CHANNEL!r} for poses")
        if not isinstance(message, str):
            return {}, "a binary message: send each publish frame as text (JSON)"
        try:
            frame = json.loads(message)
        except ValueError as exc:
            return {}, f"not JSON ({exc}): send rosbridge publish frames, {{\"op\": \"publish\", ...}}"
        if not isinstance(frame, dict) or frame.get("op") != "publish":
            op = frame.get("op") if isinstance(frame, dict) else None
            return {}, (f"op {str(op)[:40]!r} is not 'publish': this channel carries publish frames of the "
                        "operator's poses and Joy only; other ops go over the WebSocket")
        topic = frame.get("topic")
        if topic not in OPERATOR_TOPICS:
            return {}, (f"topic {str(topic)[:80]!r} is not one of the operator's streams on this channel "
                        f"({', '.join(sorted(OPERATOR_TOPICS))}); publish it over the WebSocket")
        if not self.holds_control(self.session.name):
            return {}, (f"{topic}: this client does not hold control: send poses over the WebSocket until "
                        f"{names.ENGAGE_SERVICE} succeeds, then over this channel")
        return frame, ""

    def _refuse(self, reason: str) -> None:
        self.counts.refused += 1
        self.counts.last_refusal = reason
        now = self.clock.monotonic()
        if now - self._last_told >= REFUSAL_INTERVAL_S:
            self._last_told = now
            self.session.status("error", f"{names.POSES_CHANNEL} data channel: refused: {reason}")


def _stamp_seconds(msg: Any) -> float | None:
    """header.stamp in seconds (ROS 1 or ROS 2 style), None when absent, zero or not numbers."""
    header = msg.get("header") if isinstance(msg, Mapping) else None
    stamp = header.get("stamp") if isinstance(header, Mapping) else None
    if not isinstance(stamp, Mapping):
        return None
    secs = stamp.get("secs", stamp.get("sec", 0))
    nsecs = stamp.get("nsecs", stamp.get("nanosec", 0))
    if type(secs) not in (int, float) or type(nsecs) not in (int, float):
        return None
    value = secs + nsecs / 1e9
    return value if value > 0 and math.isfinite(value) else None
