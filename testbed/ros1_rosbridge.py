"""A ROS 1 QTrobot's rosbridge, as the ros backend meets it on a real robot (rosbridge_server 0.11.17 and LuxAI's
nodes behind it), for tests that must not lean on this server's own rosbridge semantics.

What it copies from ROS 1, where the backend depends on it:
- every `call_service` is answered from a thread of its own (rosbridge 0.11's ServiceCaller), so two calls sent back
  to back may reach the robot's nodes in either order; `stop_holds_for_next_call` makes the reordering happen on
  purpose: a speech stop is held until a later call has begun (or `hold_s` has passed), as a busy robot might;
- `subscribe` needs a type string: an empty or unknown one is refused with a `status` error carrying rosbridge's
  text (`subscribe:  is not a valid type string`), and the subscription does not exist;
- messages and service requests are checked against LuxAI's real definitions (`qt_robot_interface`,
  `qt_gesture_controller`, `qt_motors_controller`, written here from LuxAI's headers, not taken from the server's
  own list), with the project's TypeRegistry doing the checking; a request that does not fit fails as rosbridge
  fails it (`result: false`, the reason as the values);
- LuxAI's speech node: `/qt_robot/speech/say` answers once the sentence is spoken, `/qt_robot/speech/stop` cuts
  whatever is being spoken at the moment it runs, `/qt_robot/speech/config` sets language, pitch and speed;
- LuxAI's motor controller publishes `/qt_robot/joints/state` all the time (JOINT_STATE_HZ; each joint at the
  position its part was last commanded), the robot's heartbeat; `beating = False` stops it with the socket up,
  as a hung robot would;
- qt_respeaker_app's `is_speaking` (std_msgs/Bool) and `sound_direction` (std_msgs/Int32) are latched: a new
  subscriber gets the last message at once (`publish(..., latch=True)`).

Everything the robot received is recorded (`calls` in arrival order, `utterances` with whether each was cut).
"""

from __future__ import annotations

import asyncio
import json
import threading
from dataclasses import dataclass, field
from typing import Any

import websockets
from pydantic import ValidationError

from client_protocol.definitions import MESSAGES
from testbed.waiting import Pace
from client_protocol.registry import TypeRegistry, describe_validation_error

# The packages a QTrobot's ROS 1 knows that the backend meets (our own vr_teleop_msgs are not on a robot).
ROS1_PACKAGES = ("std_msgs", "geometry_msgs", "sensor_msgs", "audio_common_msgs")
LUXAI_MESSAGES = {
    "qt_motors_controller/MotorState": "string[] name\nfloat32[] temperature\nfloat32[] voltage",
}
LUXAI_SERVICES = {
    "qt_robot_interface/speech_say": "string message\n---\nbool status",
    "qt_robot_interface/speech_config": "string language\nint16 pitch\nint16 speed\n---\nbool status",
    "qt_robot_interface/speech_stop": "---\nbool status",
    "qt_robot_interface/behavior_talk_text": "string message\n---\nbool status",
    "qt_robot_interface/audio_play": "string filename\nstring filepath\n---\nbool status",
    "qt_robot_interface/emotion_show": "string name\n---\nbool status",
    "qt_robot_interface/emotion_stop": "---\nbool status",
    "qt_gesture_controller/gesture_play": "string name\nfloat32 speed\n---\nbool status",
    "qt_gesture_controller/gesture_list": "---\nstring[] gestures",
    "qt_gesture_controller/gesture_stop": "---\nbool status",
    "qt_motors_controller/home": "string[] parts\n---\nbool status",
    "qt_motors_controller/set_control_mode": "string[] parts\nuint8 mode\n---\nbool status",
    "qt_motors_controller/set_velocity": "string[] parts\nuint8 velocity\n---\nbool status",
    "rosapi/TopicType": "string topic\n---\nstring type",
}
SERVICE_TYPES = {
    "/qt_robot/speech/say": "qt_robot_interface/speech_say",
    "/qt_robot/speech/config": "qt_robot_interface/speech_config",
    "/qt_robot/speech/stop": "qt_robot_interface/speech_stop",
    "/qt_robot/emotion/show": "qt_robot_interface/emotion_show",
    "/qt_robot/gesture/play": "qt_gesture_controller/gesture_play",
    "/qt_robot/motors/home": "qt_motors_controller/home",
    "/qt_robot/motors/setControlMode": "qt_motors_controller/set_control_mode",
    "/qt_robot/motors/setVelocity": "qt_motors_controller/set_velocity",
    "/rosapi/topic_type": "rosapi/TopicType",
}
TOPIC_TYPES = {  # what LuxAI's nodes publish or subscribe to, before anyone advertises
    "/qt_robot/joints/state": "sensor_msgs/JointState",
    "/qt_robot/motors/states": "qt_motors_controller/MotorState",
    "/qt_robot/head_position/command": "std_msgs/Float64MultiArray",
    "/qt_robot/right_arm_position/command": "std_msgs/Float64MultiArray",
    "/qt_robot/left_arm_position/command": "std_msgs/Float64MultiArray",
    "/camera/color/image_raw/compressed": "sensor_msgs/CompressedImage",
    "/qt_respeaker_app/is_speaking": "std_msgs/Bool",
    "/qt_respeaker_app/sound_direction": "std_msgs/Int32",
}
PARTS = {  # LuxAI's part command topics and the joints of their arrays, in order
    "/qt_robot/head_position/command": ("HeadYaw", "HeadPitch"),
    "/qt_robot/right_arm_position/command": ("RightShoulderPitch", "RightShoulderRoll", "RightElbowRoll"),
    "/qt_robot/left_arm_position/command": ("LeftShoulderPitch", "LeftShoulderRoll", "LeftElbowRoll"),
}
JOINT_STATE_HZ = 30.0


@dataclass
class Utterance:
    text: str
    cut: bool = False
    done: threading.Event = field(default_factory=threading.Event)


class Ros1QTrobot:
    """The robot's rosbridge on ws://127.0.0.1:PORT, run in a thread of its own; `stop()` ends it."""

    def __init__(self, *, seconds_per_word: float = 0.05, stop_holds_for_next_call: bool = False,
                 hold_s: float = 1.0) -> None:
        self.registry = TypeRegistry(
            {k: v for k, v in MESSAGES.items() if k.split("/")[0] in ROS1_PACKAGES} | LUXAI_MESSAGES,
            LUXAI_SERVICES)
        self.seconds_per_word = seconds_per_word
        self.stop_holds_for_next_call = stop_holds_for_next_call
        self.hold_s = hold_s
        self.topic_types = dict(TOPIC_TYPES)
        self.calls: list[tuple[str, dict[str, Any]]] = []  # in the order they reached the robot
        self.utterances: list[Utterance] = []
        self.speech_config: list[dict[str, Any]] = []
        self.refusals: list[str] = []  # every status error sent
        self.published: dict[str, list[Any]] = {}
        self.positions = {joint: 0.0 for joints in PARTS.values() for joint in joints}
        self.beating = True
        self._latched: dict[str, Any] = {}
        self._lock = threading.Condition()
        self._begun = 0  # calls whose handling has begun (a say: once its sentence is being spoken)
        self._speaking: Utterance | None = None
        self._subscriptions: dict[Any, set[str]] = {}  # connection -> topics
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        assert self._ready.wait(10), "the fake robot's rosbridge did not start"

    # ---- the server -----------------------------------------------------------------------------------------
    def _run(self) -> None:
        asyncio.set_event_loop(self._loop)

        async def main() -> None:
            async with websockets.serve(self._connection, "127.0.0.1", 0) as server:
                self.port = server.sockets[0].getsockname()[1]
                self._stopped = asyncio.Event()
                self._ready.set()
                beat = asyncio.ensure_future(self._heartbeat())
                await self._stopped.wait()
                beat.cancel()

        self._loop.run_until_complete(main())

    async def _heartbeat(self) -> None:
        pace = Pace(JOINT_STATE_HZ, catch_up=False)  # the robot's own rate
        while True:
            await pace.tick()
            if self.beating:
                names = sorted(self.positions)
                self._deliver("/qt_robot/joints/state", {
                    "header": {"seq": 0, "stamp": {"secs": 0, "nsecs": 0}, "frame_id": ""}, "name": names,
                    "position": [self.positions[n] for n in names], "velocity": [0.0] * len(names),
                    "effort": [0.0] * len(names)})

    @property
    def url(self) -> str:
        return f"ws://127.0.0.1:{self.port}"

    def stop(self) -> None:
        with self._lock:
            for u in self.utterances:
                u.done.set()
        self._loop.call_soon_threadsafe(self._stopped.set)
        self._thread.join(10)

    async def _connection(self, ws: Any) -> None:
        self._subscriptions[ws] = set()
        try:
            async for frame in ws:
                self._dispatch(ws, json.loads(frame))
        except websockets.ConnectionClosed:
            pass
        finally:
            self._subscriptions.pop(ws, None)

    def _send(self, ws: Any, frame: dict[str, Any]) -> None:
        """From any thread."""
        async def send() -> None:
            try:
                await ws.send(json.dumps(frame))
            except websockets.ConnectionClosed:
                pass
        asyncio.run_coroutine_threadsafe(send(), self._loop)

    def _status(self, ws: Any, op: str, message: str, mid: Any) -> None:
        text = f"{op}: {message}"  # rosbridge 0.11's protocol.py: "<op>: <exception text>"
        self.refusals.append(text)
        self._send(ws, {"op": "status", "level": "error", "msg": text, **({"id": mid} if mid else {})})

    def _valid_type(self, type_name: Any) -> bool:
        return isinstance(type_name, str) and self.registry.is_known_message(type_name)

    def _dispatch(self, ws: Any, msg: dict[str, Any]) -> None:
        op, mid = msg.get("op"), msg.get("id")
        if op == "subscribe":
            topic, type_name = msg["topic"], msg.get("type")
            if type_name is None:  # rosbridge takes the topic's type when it is established
                type_name = self.topic_types.get(topic)
                if type_name is None:
                    self._status(ws, op, f"Cannot infer topic type for topic {topic} as it is not yet advertised",
                                 mid)
                    return
            if not self._valid_type(type_name):
                self._status(ws, op, f"{type_name} is not a valid type string", mid)
                return
            known = self.topic_types.setdefault(topic, type_name)
            if known != type_name:
                self._status(ws, op, f"Tried to subscribe to a topic {topic} using type {type_name} but the topic "
                                     f"is already established with type {known}", mid)
                return
            self._subscriptions[ws].add(topic)
            if topic in self._latched:
                self._send(ws, {"op": "publish", "topic": topic, "msg": self._latched[topic]})
        elif op == "unsubscribe":
            self._subscriptions[ws].discard(msg["topic"])
        elif op == "advertise":
            topic, type_name = msg["topic"], msg.get("type")
            if not self._valid_type(type_name):
                self._status(ws, op, f"{type_name} is not a valid type string", mid)
                return
            self.topic_types.setdefault(topic, type_name)
        elif op == "publish":
            topic = msg["topic"]
            try:
                self.registry.validate(self.topic_types[topic], msg.get("msg"))
            except (KeyError, ValidationError) as exc:
                self._status(ws, op, f"{topic}: {exc}", mid)
                return
            self.published.setdefault(topic, []).append(msg.get("msg"))
            if topic in PARTS:
                self.positions.update(zip(PARTS[topic], msg["msg"]["data"]))
            self._deliver(topic, msg.get("msg"), exclude=ws)
        elif op == "call_service":
            self.calls.append((msg["service"], msg.get("args") or {}))
            threading.Thread(target=self._call, args=(ws, msg), daemon=True).start()  # rosbridge's ServiceCaller
        # other ops do not occur between the backend and a robot

    def _deliver(self, topic: str, message: Any, exclude: Any = None) -> None:
        for ws, topics in list(self._subscriptions.items()):
            if topic in topics and ws is not exclude:
                self._send(ws, {"op": "publish", "topic": topic, "msg": message})

    def publish(self, topic: str, message: dict[str, Any], latch: bool = False) -> None:
        """A robot-side node publishes (checked against the topic's type); a latched message is also given to every
        later subscriber."""
        self.registry.validate(self.topic_types[topic], message)

        def deliver() -> None:
            if latch:
                self._latched[topic] = message
            self._deliver(topic, message)
        self._loop.call_soon_threadsafe(deliver)

    # ---- the robot's nodes (each call on its own thread) -----------------------------------------------------
    def _call(self, ws: Any, msg: dict[str, Any]) -> None:
        service, mid = msg["service"], msg.get("id")
        reply: dict[str, Any] = {"op": "service_response", "service": service, **({"id": mid} if mid else {})}
        try:
            type_name = SERVICE_TYPES.get(service)
            if type_name is None:
                raise LookupError(f"Service {service} does not exist")
            request_type, _ = self.registry.service_parts(type_name)
            args = msg.get("args") or {}
            try:
                request = self.registry.validate(request_type, args).model_dump()
            except ValidationError as exc:
                raise ValueError(describe_validation_error(exc)) from None
            values = getattr(self, "_" + service.rsplit("/", 2)[-2] + "_" + service.rsplit("/", 1)[-1],
                             self._other)(request)
            reply.update(values=values, result=True)
        except Exception as exc:  # rosbridge 0.11: the exception's text as the values, result false
            reply.update(values=str(exc), result=False)
        self._send(ws, reply)

    def _begin(self) -> None:
        with self._lock:
            self._begun += 1
            self._lock.notify_all()

    def _other(self, _request: dict[str, Any]) -> dict[str, Any]:
        self._begin()
        return {"status": True}

    def _speech_say(self, request: dict[str, Any]) -> dict[str, Any]:
        utterance = Utterance(request["message"])
        with self._lock:
            if self._speaking is not None:  # LuxAI's node speaks one sentence at a time: a new one replaces it
                self._speaking.cut = True
                self._speaking.done.set()
            self._speaking = utterance
            self.utterances.append(utterance)
            self._begun += 1
            self._lock.notify_all()
        utterance.done.wait(max(0.2, len(utterance.text.split()) * self.seconds_per_word))
        with self._lock:
            if self._speaking is utterance:
                self._speaking = None
        return {"status": True}

    def _speech_stop(self, _request: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            if self.stop_holds_for_next_call:
                seen = self._begun
                self._lock.wait_for(lambda: self._begun > seen, self.hold_s)
            if self._speaking is not None:
                self._speaking.cut = True
                self._speaking.done.set()
                self._speaking = None
            self._begun += 1
            self._lock.notify_all()
        return {"status": True}

    def _speech_config(self, request: dict[str, Any]) -> dict[str, Any]:
        self.speech_config.append(request)
        self._begin()
        return {"status": True}

    def _rosapi_topic_type(self, request: dict[str, Any]) -> dict[str, Any]:
        self._begin()
        return {"type": self.topic_types.get(request["topic"], "")}

    @property
    def speaking(self) -> str | None:
        with self._lock:
            return None if self._speaking is None else self._speaking.text

    def services_called(self, service: str) -> list[dict[str, Any]]:
        return [args for name, args in self.calls if name == service]
