"""The real QTrobot (ROS 1), reached through its own rosbridge (LuxAI's /qt_robot/* API) with roslibpy.

This class only translates the Robot interface to roslibpy; lost and back, command gating, the voice's resampling,
gestures and the camera's reference counting are the link's (robot/link.py). roslibpy runs its own networking
thread; what arrives there (joint states, camera frames, connection changes) is stored under a lock and handed on.
roslibpy reconnects by itself (with the link's backoff, set on this connection's factory only) and re-subscribes.
The heartbeat is /qt_robot/joints/state.

Audio. The robot's microphone is LuxAI's qt_respeaker_app channel 0 (names.ROBOT_MICROPHONE_TOPIC, AudioData
carrying mono S16LE at 16 kHz: the ReSpeaker's processed channel), read only while someone listens (the WebRTC
mixer, through `listen`). LuxAI's ROS 1 API has no way to stream sound into the robot (`/qt_robot/audio/play`
plays a file already on it), so the operator's voice goes out on our own topic (names.ROBOT_SPEAKER_TOPIC:
AudioData, mono S16LE at 16 kHz, 40 ms a message), which audio_common's `audio_play` node, run on the robot, plays
on its speaker (docs/guides/qtrobot-ros1.md).

Hearing. qt_respeaker_app's `is_speaking` (std_msgs/Bool) and `sound_direction` (std_msgs/Int32, the ReSpeaker
array's own angle in degrees) are subscribed from the start; `respeaker_to_base` is the one place that angle becomes
the robot's base frame (its assumptions are written there).

Speech. ROS 1's rosbridge answers each service call from a thread of its own, so two calls sent back to back may
reach LuxAI's nodes in either order. A stop is therefore sent only while one of our sentences is being spoken, and
the next sentence waits for the stop's answer: a stop can never cut the sentence that follows it. Speech speed,
pitch and language go to the robot's own voice through /qt_robot/speech/config.

Motor states. /qt_robot/motors/states is subscribed with LuxAI's type (qt_motors_controller/MotorState): ROS 1's
rosbridge refuses a subscription without a type string.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import logging
import math
import threading
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any
from urllib.parse import urlparse

import roslibpy

from client_protocol import names
from client_protocol.errors import Refusal
from robot_models import RobotModel, load_qtrobot

from ..interface import (
    JointState,
    MotorMode,
    MotorStatus,
    SpeechResult,
)
from ..link import RETRY_MAX_S, RETRY_MIN_S, RobotLink, RobotUnreachable, wrap_deg

if TYPE_CHECKING:
    from simclock import Clock

    from ...settings import ServerSettings

log = logging.getLogger(__name__)

CALL_TIMEOUT_S = 10.0  # for an answer that does not wait for the robot to finish something
CONNECT_TIMEOUT_S = 10.0
MOTOR_STATE_TYPE = "qt_motors_controller/MotorState"  # LuxAI's: string[] name, float32[] temperature, voltage
MICROPHONE_RATE = 16000  # qt_respeaker_app's channels: the ReSpeaker array's rate, mono S16LE
RESPEAKER_FRONT_DEG = 0.0  # the array's angle that points where the face looks (assumed, see respeaker_to_base)


def respeaker_to_base(array_deg: float, head_yaw_deg: float) -> float:
    """qt_respeaker_app's sound_direction as an azimuth in the robot's base frame (degrees, positive left).

    Assumed (no LuxAI document states it): the ReSpeaker Mic Array v2.0 sits on top of QTrobot's head and turns
    with HeadYaw; its angle (0..359) grows clockwise seen from above (towards the robot's right), as the array's
    firmware reports its direction of arrival; its 0 points where the face looks (RESPEAKER_FRONT_DEG; change it if
    a voice straight ahead reads otherwise on a robot). Head pitch, which tilts the array by a few degrees, is
    ignored."""
    return wrap_deg(head_yaw_deg - (array_deg - RESPEAKER_FRONT_DEG))


def _stamp(msg: dict[str, Any]) -> float | None:
    """A message's header stamp in seconds (ROS 1's secs/nsecs or ROS 2's sec/nanosec), None when it has none (0)."""
    stamp = (msg.get("header") or {}).get("stamp") or {}
    try:
        seconds = float(stamp.get("secs", stamp.get("sec", 0)) or 0) + \
            float(stamp.get("nsecs", stamp.get("nanosec", 0)) or 0) / 1e9
    except (TypeError, ValueError, AttributeError):
        return None
    return seconds or None


def _jpeg_size(data: bytes) -> tuple[int, int]:
    """(width, height) from a JPEG's start-of-frame marker, without decoding the image."""
    i = 2
    while i + 9 < len(data):
        if data[i] != 0xFF:
            break
        marker, length = data[i + 1], int.from_bytes(data[i + 2:i + 4], "big")
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            return int.from_bytes(data[i + 7:i + 9], "big"), int.from_bytes(data[i + 5:i + 7], "big")
        i += 2 + length
    return 0, 0


class RosRobot(RobotLink):
    backend = "ros"

    def __init__(self, url: str, model: RobotModel | None = None, connect_timeout: float = CONNECT_TIMEOUT_S) -> None:
        super().__init__(self.check_url(url), model or load_qtrobot())
        self._connect_timeout = connect_timeout
        self._ros: roslibpy.Ros | None = None
        self._lock = threading.Lock()
        self._state: JointState | None = None
        self._commanded: dict[str, float] = {}
        self._modes = {n: MotorMode.ON for n in self._model.names}
        self._sentences = 0  # say calls sent and not answered yet
        self._stops = 0  # stop requests: a sentence that saw one while spoken (or waiting) was cut short
        self._stopping: asyncio.Future | None = None  # the newest stop, until the robot answers it
        self._motor_readings: dict[str, tuple[float | None, float | None]] = {}
        self._topics: dict[str, roslibpy.Topic] = {}

    @staticmethod
    def check_url(url: str, _robot_id: str | None = None) -> str:
        """The URL if it can name a rosbridge, else a ValueError saying what to give."""
        parsed = urlparse(url)
        if parsed.scheme not in ("ws", "wss") or not parsed.hostname:
            raise ValueError(f"robot URL must look like ws://HOST:PORT, not {url!r}")
        return url

    @classmethod
    def from_settings(cls, settings: ServerSettings, model: RobotModel, _clock: Clock | None = None) -> RosRobot:
        return cls(settings.resolved_robot_url, model)

    # ---- connection ---------------------------------------------------------------------------------------------
    def _connect(self) -> None:
        parsed = urlparse(self.url)
        ros = self._ros = roslibpy.Ros(host=parsed.hostname, port=parsed.port or 9090,
                                       is_secure=parsed.scheme == "wss")
        factory = ros.factory  # this connection's backoff only: the class's stays as roslibpy has it
        factory.initialDelay = factory.delay = RETRY_MIN_S
        factory.maxDelay = RETRY_MAX_S
        ros.on("close", lambda *_: self._transport(False))
        ros.on("ready", lambda *_: self._transport(True))
        try:
            ros.run(timeout=self._connect_timeout)
        except roslibpy.core.RosTimeoutError:  # roslibpy kept retrying (refused, unreachable) until the timeout
            raise RobotUnreachable(f"cannot reach the robot's rosbridge at {self.url} within "
                                   f"{self._connect_timeout:g} s") from None

        def topic(name: str, type_name: str, **options: Any) -> roslibpy.Topic:
            made = self._topics[name] = roslibpy.Topic(ros, name, type_name, **options)
            return made

        for part_topic in names.PART_COMMAND_TOPICS.values():
            topic(part_topic, "std_msgs/Float64MultiArray").advertise()
        topic(names.ROBOT_SPEAKER_TOPIC, "audio_common_msgs/AudioData").advertise()
        topic(names.JOINT_STATE_TOPIC, "sensor_msgs/JointState").subscribe(self._on_joint_state)
        topic(names.MOTOR_STATES_TOPIC, MOTOR_STATE_TYPE).subscribe(self._on_motor_states)
        topic(names.RESPEAKER_SPEAKING_TOPIC, "std_msgs/Bool").subscribe(
            lambda m: self._heard_voice(bool(m.get("data")), None))
        topic(names.RESPEAKER_DIRECTION_TOPIC, "std_msgs/Int32").subscribe(
            lambda m: self._heard_voice(None, float(m.get("data") or 0)))
        topic(names.CAMERA_TOPIC, "sensor_msgs/CompressedImage", queue_length=1)
        topic(names.ROBOT_MICROPHONE_TOPIC, "audio_common_msgs/AudioData")

    def _disconnect(self) -> None:
        ros = self._ros
        if ros is None:
            return
        from twisted.internet import reactor

        reactor.callFromThread(ros.factory.stopTrying)
        with contextlib.suppress(Exception):  # already gone
            ros.close(timeout=2)

    def _to_base(self, array_deg: float) -> float:
        return respeaker_to_base(array_deg, self.joint_state().as_dict().get("HeadYaw", 0.0))

    def _send_targets(self, targets: dict[str, float]) -> tuple[str, ...]:
        """Each part the targets touch, whole (LuxAI's part arrays), the others of it at what they were given last."""
        with self._lock:
            current = self._state.as_dict() if self._state is not None else {}
        for part, joints in self._model.parts.items():
            if not any(n in targets for n in joints):
                continue
            values = []
            for n in joints:
                value = targets.get(n, self._commanded.get(n, current.get(n, self._model.joint(n).home)))
                values.append(float(value))
                self._commanded[n] = float(value)
            self._topics[names.PART_COMMAND_TOPICS[part]].publish(roslibpy.Message({"data": values}))
        return ()

    def _on_joint_state(self, msg: dict[str, Any]) -> None:
        positions = dict(zip(msg.get("name", []), msg.get("position", [])))
        velocities = dict(zip(msg.get("name", []), msg.get("velocity", []) or []))
        efforts = dict(zip(msg.get("name", []), msg.get("effort", []) or []))
        names = tuple(n for n in self._model.names if n in positions)
        state = JointState(names, tuple(float(positions[n]) for n in names),
                           tuple(float(velocities.get(n, 0.0)) for n in names),
                           tuple(float(efforts.get(n, 0.0)) for n in names), time.monotonic(), time.time())
        with self._lock:
            self._state = state
        self._joints_heard(positions, _stamp(msg))

    def joint_state(self) -> JointState:
        with self._lock:
            state = self._state
        if state is None:  # no state yet: the commanded (or home) pose, so callers always get all joints
            names = self._model.names
            home = tuple(self._commanded.get(n, self._model.joint(n).home) for n in names)
            return JointState(names, home, tuple(0.0 for _ in names), tuple(0.0 for _ in names), time.monotonic(),
                              time.time())
        return state

    def set_control_mode(self, parts: Sequence[str], mode: MotorMode) -> None:
        mode = MotorMode(mode)
        self._call_nowait(names.MOTORS_CONTROL_MODE_SERVICE, "qt_motors_controller/set_control_mode",
                          {"parts": list(parts), "mode": int(mode)})
        for part in parts:
            for n in self._model.part_joints(part):
                self._modes[n] = mode

    def _on_motor_states(self, msg: dict[str, Any]) -> None:
        """Reads the firmware's per-motor arrays leniently: name with temperature and/or voltage."""
        names = msg.get("name") or []
        temperatures = list(msg.get("temperature") or [])
        voltages = list(msg.get("voltage") or [])
        readings = {}
        for i, name in enumerate(names):
            t = temperatures[i] if i < len(temperatures) else None
            v = voltages[i] if i < len(voltages) else None
            readings[str(name)] = (None if t is None else float(t), None if v is None else float(v))
        with self._lock:
            self._motor_readings.update(readings)

    def motor_status(self) -> tuple[MotorStatus, ...]:
        positions = self.joint_state().as_dict()
        with self._lock:
            readings = dict(self._motor_readings)
        out = []
        for part, joints in self._model.parts.items():
            for n in joints:
                temperature, voltage = readings.get(n, (None, None))
                out.append(MotorStatus(n, part, positions.get(n, math.nan), temperature, voltage, self._modes[n],
                                       "measured"))
        return tuple(out)

    # ---- services -----------------------------------------------------------------------------------------------
    def _call_nowait(self, name: str, type_name: str, args: dict[str, Any]) -> None:
        self._refuse_if_disconnected(name)
        roslibpy.Service(self._ros, name, type_name).call(
            roslibpy.ServiceRequest(args), lambda _r: None, lambda err: log.warning("%s failed: %s", name, err))

    async def _call(self, name: str, type_name: str, args: dict[str, Any],
                    timeout: float = CALL_TIMEOUT_S) -> dict[str, Any]:
        self._refuse_if_disconnected(name)
        loop = asyncio.get_running_loop()
        fut: asyncio.Future = loop.create_future()

        def done(result: Any) -> None:
            loop.call_soon_threadsafe(lambda: fut.done() or fut.set_result(dict(result)))

        def failed(error: Any) -> None:
            loop.call_soon_threadsafe(lambda: fut.done() or fut.set_exception(RuntimeError(f"{name}: {error}")))

        roslibpy.Service(self._ros, name, type_name).call(roslibpy.ServiceRequest(args), done, failed)
        return await asyncio.wait_for(fut, timeout)

    def show_emotion(self, name: str) -> None:
        short = name.removeprefix("QT/")
        if short not in self._model.emotions:
            raise ValueError(f"unknown emotion {name!r}; valid emotions: {', '.join(self._model.emotions)}")
        self._call_nowait(names.EMOTION_SHOW_SERVICE, "qt_robot_interface/emotion_show", {"name": f"QT/{short}"})

    async def say(self, text: str, duration_s: float | None = None) -> SpeechResult:
        """Answers once the robot has spoken (LuxAI's say blocks until then), after any stop still on its way."""
        self._refuse_if_disconnected(names.SPEECH_SAY_SERVICE)
        start, stops = time.monotonic(), self._stops
        if self._stopping is not None:
            with contextlib.suppress(Exception):  # a failed stop was logged; the sentence goes out regardless
                await asyncio.shield(self._stopping)
            if self._stops != stops:  # stopped (or replaced) before it was sent
                return SpeechResult(text, False, time.monotonic() - start, audible=True)
        self._sentences += 1
        try:
            response = await self._call(names.SPEECH_SAY_SERVICE, "qt_robot_interface/speech_say",
                                        {"message": text}, CALL_TIMEOUT_S + (duration_s or 0.0))
        finally:
            self._sentences -= 1
        completed = bool(response.get("status")) and self._stops == stops
        return SpeechResult(text, completed, time.monotonic() - start, audible=True)

    def stop_speech(self) -> None:
        """Sends a stop only while a sentence of ours is being spoken; the next say() waits for its answer."""
        if self._stopping is not None and not self._stopping.done():
            self._stops += 1  # the stop on its way cuts what is spoken; a sentence waiting for it is dropped
            return
        if not self._sentences:
            return  # nothing of ours is being spoken: a stop could only cut the sentence that follows
        self._stops += 1
        stopping = self._stopping = asyncio.ensure_future(
            self._call(names.SPEECH_STOP_SERVICE, "qt_robot_interface/speech_stop", {}))
        stopping.add_done_callback(self._stop_answered)

    def _stop_answered(self, stopping: asyncio.Future) -> None:
        if self._stopping is stopping:
            self._stopping = None
        if not stopping.cancelled() and stopping.exception() is not None:
            log.warning("%s failed: %s", names.SPEECH_STOP_SERVICE, stopping.exception())

    async def configure_speech(self, language: str, pitch: int, speed: int) -> None:
        response = await self._call(names.SPEECH_CONFIG_SERVICE, "qt_robot_interface/speech_config",
                                    {"language": language, "pitch": int(pitch), "speed": int(speed)})
        if not response.get("status"):
            raise Refusal(f"{names.SPEECH_CONFIG_SERVICE}: the robot refused language {language!r}, pitch {pitch}, "
                          f"speed {speed}")

    # ---- camera -------------------------------------------------------------------------------------------------
    def _start_camera(self) -> None:
        self._topics[names.CAMERA_TOPIC].subscribe(self._on_camera)

    def _stop_camera(self) -> None:
        self._topics[names.CAMERA_TOPIC].unsubscribe()

    def _on_camera(self, msg: dict[str, Any]) -> None:
        data = msg.get("data", "")
        arrived = (time.monotonic(), time.time())
        jpeg = base64.b64decode(data) if isinstance(data, str) else bytes(data)
        self._put_jpeg(jpeg, *_jpeg_size(jpeg), stamp=_stamp(msg), arrived=arrived)

    # ---- microphone ---------------------------------------------------------------------------------------------
    def _start_microphone(self) -> None:
        self._topics[names.ROBOT_MICROPHONE_TOPIC].subscribe(self._on_microphone)

    def _stop_microphone(self) -> None:
        self._topics[names.ROBOT_MICROPHONE_TOPIC].unsubscribe()

    @property
    def microphone_read(self) -> bool:
        """Whether the microphone's topic is subscribed (only while someone listens)."""
        return bool(self._topics) and self._topics[names.ROBOT_MICROPHONE_TOPIC].is_subscribed

    def _on_microphone(self, msg: dict[str, Any]) -> None:
        """On roslibpy's thread: rosbridge sends uint8[] as base64 (ROS 1) or a list of numbers."""
        data = msg.get("data", "")
        try:
            pcm = base64.b64decode(data) if isinstance(data, str) else bytes(data)
        except (ValueError, TypeError):
            log.warning("%s: a message whose data is not audio bytes was ignored", names.ROBOT_MICROPHONE_TOPIC)
            return
        self._heard(pcm, MICROPHONE_RATE, 1)

    # ---- the operator's voice -----------------------------------------------------------------------------------
    def _send_voice(self, chunk: bytes) -> bool:
        self._topics[names.ROBOT_SPEAKER_TOPIC].publish(
            roslibpy.Message({"data": base64.b64encode(chunk).decode("ascii")}))
        return True
