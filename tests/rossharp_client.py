"""A test client that behaves on the wire as a stock ROS# (siemens/ros-sharp 2.x) Unity rig does.

Written from the facts in /work/shared/reference/rossharp.md, not from ROS#'s code:
- every frame sent is UTF-8 JSON in a *binary* WebSocket frame; received frames are decoded as ASCII, every byte
  above 127 becoming '?' (so only JSON's \\u escapes carry non-ASCII text intact);
- ROS 2 message classes by default: type names `pkg/msg/Type` and `pkg/srv/Type`, time `{sec, nanosec}`, and a
  missing field keeps its default (a time with neither key reads as zero);
- `advertise` with id = topic; `subscribe` with queue_length 1, fragment_size int max, compression "none";
  `call_service` with args as an object and an id string;
- on receive it handles publish, service_response and call_service; `status` is ignored (errors are invisible),
  `fragment` and `png` are not reassembled or decoded;
- `service_response`: `result` is ignored and `values` deserialised as the response type. Values that are not an
  object make the handler throw; with System.Net.WebSockets the exception leaves the receive loop and the
  connection silently stops receiving. Here that surfaces as RosSharpBroken in the waiting call and in every call
  after it, so tests show the breakage instead of hanging;
- one connection per component (each Unity publisher/subscriber carries its own RosConnector), and whatever the
  server needs at connect time (a token, a time style) comes from the URL's query: ROS# has no `auth` op.
Built on the `websockets` library's threaded client, so tests stay synchronous like the other client tests.
"""

from __future__ import annotations

import itertools
import json
import threading
import time
from collections.abc import Callable
from typing import Any
from urllib.parse import urlencode, urlsplit, urlunsplit

import numpy as np
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

INT_MAX = 2**31 - 1  # ROS#'s fragment_size: int.MaxValue
_ASCII = bytes(b if b < 128 else ord("?") for b in range(256))  # Encoding.ASCII's lossy decoding, as a table

# Unity's axes (x right, y up, z forward; left-handed) to ROS's (x forward, y left, z up): v_ros = M v_unity.
UNITY_TO_ROS = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


class RosSharpBroken(RuntimeError):
    """The connection stopped receiving, as ROS#'s does when a response handler throws."""


def msg_type(name: str) -> str:
    """`pkg/Type` as ROS#'s ROS 2 classes name it: `pkg/msg/Type`."""
    package, _, type_name = name.partition("/")
    return f"{package}/msg/{type_name}"


def srv_type(name: str) -> str:
    package, _, type_name = name.partition("/")
    return f"{package}/srv/{type_name}"


def ros2_now() -> dict[str, int]:
    t = time.time_ns()
    return {"sec": t // 1_000_000_000, "nanosec": t % 1_000_000_000}


def read_ros2_time(stamp: Any) -> tuple[int, int]:
    """A builtin_interfaces/Time as ROS#'s ROS 2 class reads it: unknown keys ignored, missing ones zero."""
    stamp = stamp if isinstance(stamp, dict) else {}
    return int(stamp.get("sec", 0)), int(stamp.get("nanosec", 0))


def unity_to_ros_position(xyz: tuple[float, float, float]) -> dict[str, float]:
    x, y, z = (UNITY_TO_ROS @ np.asarray(xyz, dtype=float)).tolist()
    return {"x": x, "y": y, "z": z}


def unity_to_ros_quaternion(xyzw: tuple[float, float, float, float]) -> dict[str, float]:
    """The same physical rotation in ROS's axes. The basis change M has det -1, and a quaternion's vector part is
    an axis (a pseudovector), so it maps to det(M) * M v; the scalar part is unchanged."""
    q = np.asarray(xyzw, dtype=float)
    x, y, z = (np.linalg.det(UNITY_TO_ROS) * (UNITY_TO_ROS @ q[:3])).tolist()
    return {"x": x, "y": y, "z": z, "w": float(q[3])}


def with_query(url: str, **query: str | None) -> str:
    """The RosConnector URL with the given query parameters (None values left out)."""
    parts = urlsplit(url)
    pairs = [p for p in parts.query.split("&") if p] + [urlencode({k: v}) for k, v in query.items() if v is not None]
    return urlunsplit(parts._replace(query="&".join(pairs)))


class RosSharpConnection:
    """One RosConnector's RosSocket."""

    def __init__(self, url: str, *, token: str | None = None, time: str | None = None, **query: str) -> None:
        self.url = with_query(url, token=token, time=time, **query)
        # no permessage-deflate (ROS#'s sockets do not offer it); the socket lives as long as its RosConnector,
        # not a `with` block, hence __enter__ by hand
        self.ws: ClientConnection = connect(self.url, compression=None, max_size=None, open_timeout=30).__enter__()
        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        self._subscribers: dict[str, list[Callable[[dict[str, Any]], None]]] = {}
        self._pending: dict[str, tuple[threading.Event, list[Any]]] = {}
        self.broken: BaseException | None = None
        self.ignored_ops: dict[str, int] = {}  # status, fragment, png...: what ROS# drops without a word
        self.advertised: set[str] = set()
        self._reader = threading.Thread(target=self._receive_loop, name="rossharp-recv", daemon=True)
        self._reader.start()

    # ---- sending -------------------------------------------------------------------------------------------------
    def _send(self, frame: dict[str, Any]) -> None:
        self.ws.send(json.dumps(frame, ensure_ascii=False).encode("utf-8"))  # binary frame, raw UTF-8

    def advertise(self, topic: str, type_name: str) -> None:
        self._send({"op": "advertise", "id": topic, "topic": topic, "type": type_name})
        self.advertised.add(topic)

    def publish(self, topic: str, msg: dict[str, Any]) -> None:
        self._send({"op": "publish", "id": topic, "topic": topic, "msg": msg})

    def unadvertise(self, topic: str) -> None:
        self._send({"op": "unadvertise", "id": topic, "topic": topic})
        self.advertised.discard(topic)

    def subscribe(self, topic: str, type_name: str, callback: Callable[[dict[str, Any]], None],
                  throttle_rate: int = 0) -> str:
        sub_id = f"subscribe:{topic}:{next(self._ids)}"
        with self._lock:
            self._subscribers.setdefault(topic, []).append(callback)
        self._send({"op": "subscribe", "id": sub_id, "topic": topic, "type": type_name,
                    "throttle_rate": throttle_rate, "queue_length": 1, "fragment_size": INT_MAX,
                    "compression": "none"})
        return sub_id

    def unsubscribe(self, sub_id: str, topic: str) -> None:
        self._send({"op": "unsubscribe", "id": sub_id, "topic": topic})

    def call_service(self, service: str, type_name: str, args: dict[str, Any] | None = None,
                     timeout: float = 10.0) -> dict[str, Any]:
        """The response's values, as ROS# hands them to the callback. RosSharpBroken if the connection is (or
        gets) broken; TimeoutError if no response came (which ROS# would wait for forever)."""
        if self.broken is not None:
            raise RosSharpBroken(f"the connection stopped receiving earlier: {self.broken}")
        call_id = f"call_service:{service}:{next(self._ids)}"
        done, box = threading.Event(), []
        with self._lock:
            self._pending[call_id] = (done, box)
        self._send({"op": "call_service", "id": call_id, "service": service, "type": type_name,
                    "args": args or {}})
        if not done.wait(timeout):
            raise TimeoutError(f"no response to {service} in {timeout} s (ignored ops so far: {self.ignored_ops})")
        if self.broken is not None:
            raise RosSharpBroken(f"{service}: {self.broken}")
        return box[0]

    # ---- receiving -----------------------------------------------------------------------------------------------
    def _receive_loop(self) -> None:
        try:
            while True:
                raw = self.ws.recv()
                data = raw if isinstance(raw, bytes) else raw.encode("utf-8")
                frame = json.loads(data.translate(_ASCII).decode("ascii"))
                self._handle(frame)
        except ConnectionClosed:
            pass
        except Exception as exc:  # what escapes ROS#'s handlers ends its receive loop
            self.broken = exc
        finally:
            with self._lock:
                pending = list(self._pending.values())
                self._pending.clear()
            for done, _ in pending:
                done.set()

    def _handle(self, frame: dict[str, Any]) -> None:
        op = frame.get("op")
        if op == "publish":
            with self._lock:
                callbacks = list(self._subscribers.get(frame.get("topic", ""), ()))
            for callback in callbacks:
                callback(frame.get("msg", {}))
        elif op == "service_response":
            values = frame.get("values")  # `result` is not read
            if not isinstance(values, dict):
                raise TypeError(f"cannot deserialise the response of {frame.get('service')} as its type: values "
                                f"is {type(values).__name__} {values!r}")
            with self._lock:
                done, box = self._pending.pop(str(frame.get("id")), (None, None))
            if done is not None:
                box.append(values)
                done.set()
        else:  # status (ignored), fragment and png (not handled), call_service (no provider here)
            self.ignored_ops[str(op)] = self.ignored_ops.get(str(op), 0) + 1

    def close(self) -> None:
        self.ws.close()
        self._reader.join(5)


class Subscriber:
    """A UnitySubscriber component: its own connection, the newest message kept, every message counted."""

    def __init__(self, url: str, topic: str, type_name: str, **connect: Any) -> None:
        self.connection = RosSharpConnection(url, **connect)
        self.messages: list[dict[str, Any]] = []
        self.connection.subscribe(topic, type_name, self.messages.append)

    @property
    def latest(self) -> dict[str, Any]:
        return self.messages[-1] if self.messages else {}

    def close(self) -> None:
        self.connection.close()


class PoseStampedPublisher:
    """ROS#'s PoseStampedPublisher: in FixedUpdate (50 Hz) publishes a Unity transform converted to ROS axes,
    with header.frame_id "Unity" (the inspector's default) and a ROS 2 stamp, on its own connection."""

    def __init__(self, url: str, topic: str, *, frame_id: str = "Unity", rate_hz: float = 50.0,
                 connection: RosSharpConnection | None = None, **connect: Any) -> None:
        self.connection = connection or RosSharpConnection(url, **connect)
        self.topic = topic
        self.frame_id = frame_id
        self.period = 1.0 / rate_hz
        self.position = (0.0, 1.6, 0.0)  # Unity axes: a seated operator's eyes 1.6 m up
        self.rotation = (0.0, 0.0, 0.0, 1.0)  # Unity quaternion (x, y, z, w)
        self.sent = 0
        self._stop = threading.Event()
        self.connection.advertise(topic, msg_type("geometry_msgs/PoseStamped"))
        self._thread = threading.Thread(target=self._run, name=f"rossharp-pub{topic}", daemon=True)
        self._thread.start()

    def message(self) -> dict[str, Any]:
        return {"header": {"stamp": ros2_now(), "frame_id": self.frame_id},
                "pose": {"position": unity_to_ros_position(self.position),
                         "orientation": unity_to_ros_quaternion(self.rotation)}}

    def _run(self) -> None:
        next_at = time.monotonic()
        while not self._stop.is_set():
            try:
                self.connection.publish(self.topic, self.message())
            except ConnectionClosed:
                return
            self.sent += 1
            next_at += self.period
            self._stop.wait(max(0.0, next_at - time.monotonic()))

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)


class JoyPublisher:
    """ROS#'s JoyPublisher: sensor_msgs/Joy from the scene's axis and button readers, in the scene's order."""

    def __init__(self, url: str, topic: str, axes: int = 4, buttons: int = 4, rate_hz: float = 50.0,
                 **connect: Any) -> None:
        self.connection = RosSharpConnection(url, **connect)
        self.topic = topic
        self.axes, self.buttons = [0.0] * axes, [0] * buttons
        self._stop = threading.Event()
        self.connection.advertise(topic, msg_type("sensor_msgs/Joy"))
        self._thread = threading.Thread(target=self._run, args=(1.0 / rate_hz,), daemon=True)
        self._thread.start()

    def _run(self, period: float) -> None:
        while not self._stop.wait(period):
            try:
                self.connection.publish(self.topic, {"header": {"stamp": ros2_now(), "frame_id": "Unity"},
                                                     "axes": list(self.axes), "buttons": list(self.buttons)})
            except ConnectionClosed:
                return

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
