"""The real QTrobot, reached through its own rosbridge (LuxAI's /qt_robot/* API) with roslibpy.

roslibpy runs its own networking thread; what arrives there (joint states, camera frames, connection changes) is
stored under a lock and handed to asyncio waiters with call_soon_threadsafe. roslibpy reconnects with backoff
(0.5 s growing to MAX_BACKOFF_S) and re-subscribes by itself. While the robot is unreachable, `connected` is False
and `connection_changed` listeners hear it on the event loop: joint commands are refused (reported as ignored, never
queued to burst out later), explicit control holds and says so, and services answer with an error.

Audio. The robot's microphone is LuxAI's qt_respeaker_app channel 0 (names.ROBOT_MICROPHONE_TOPIC, AudioData
carrying mono S16LE at 16 kHz: the ReSpeaker's processed channel), read only while someone listens (the WebRTC
mixer, through `listen`) and handed to the listeners on the event loop. LuxAI's ROS 1 API has no way to stream
sound into the robot (`/qt_robot/audio/play` plays a file already on it), so the operator's voice goes out on our
own topic (names.ROBOT_SPEAKER_TOPIC: AudioData, mono S16LE at 16 kHz, 40 ms a message), which audio_common's
`audio_play` node, run on the robot, plays on its speaker (README). While the robot is away the voice is dropped,
never queued to burst out later.

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
from collections.abc import Callable, Mapping, Sequence
from typing import Any
from urllib.parse import urlparse

import av
import numpy as np
import roslibpy
from roslibpy.comm.comm_autobahn import AutobahnRosBridgeClientFactory

from client_protocol import names
from client_protocol.errors import Refusal
from robot_models import RobotModel, load_qtrobot

from ..interface import (
    CameraFrame,
    ClampReport,
    FrameMailbox,
    Gesture,
    GestureResult,
    JointState,
    MotorMode,
    MotorStatus,
    Robot,
    SpeechResult,
    clamp_command,
    held_level,
    pcm_level,
    stream_waypoints,
)

log = logging.getLogger(__name__)

MAX_BACKOFF_S = 5.0
CALL_TIMEOUT_S = 10.0  # for an answer that does not wait for the robot to finish something
MOTOR_STATE_TYPE = "qt_motors_controller/MotorState"  # LuxAI's: string[] name, float32[] temperature, voltage
MICROPHONE_RATE = 16000  # qt_respeaker_app's channels: the ReSpeaker array's rate, mono S16LE
SPEAKER_RATE = 16000  # the operator's voice for the robot's speaker: speech, at the rate audio_play defaults to
SPEAKER_CHUNK_S = 0.04


class RobotUnreachable(RuntimeError):
    """The robot's rosbridge did not answer at start-up: the server cannot run this backend."""


class RobotDisconnected(Refusal):
    """A request refused while the robot is away; the client sees the message as it is."""


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


class RosRobot(Robot):
    def __init__(self, url: str, model: RobotModel | None = None, connect_timeout: float = 10.0) -> None:
        parsed = urlparse(url)
        if parsed.scheme not in ("ws", "wss") or not parsed.hostname:
            raise ValueError(f"robot URL must look like ws://HOST:PORT, not {url!r}")
        self.url = url
        self._model = model or load_qtrobot()
        AutobahnRosBridgeClientFactory.set_initial_delay(0.5)
        AutobahnRosBridgeClientFactory.set_max_delay(MAX_BACKOFF_S)
        self._ros = roslibpy.Ros(host=parsed.hostname, port=parsed.port or 9090, is_secure=parsed.scheme == "wss")
        self._lock = threading.Lock()
        self._connected = False
        self._state: JointState | None = None
        self._commanded: dict[str, float] = {}
        self._modes = {n: MotorMode.ON for n in self._model.names}
        self._frames = FrameMailbox()
        self._frame_seq = 0
        self._camera_count = 0
        self._gesture_stop: asyncio.Event | None = None
        self._sentences = 0  # say calls sent and not answered yet
        self._stops = 0  # stop requests: a sentence that saw one while spoken (or waiting) was cut short
        self._stopping: asyncio.Future | None = None  # the newest stop, until the robot answers it
        self._motor_readings: dict[str, tuple[float | None, float | None]] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self.connection_changed: list[Callable[[bool], None]] = []  # called on the event loop with the new state
        self._ros.on("close", self._on_close)
        self._ros.on("ready", self._on_ready)
        try:
            self._ros.run(timeout=connect_timeout)
        except roslibpy.core.RosTimeoutError:  # roslibpy kept retrying (refused, unreachable) until the timeout
            self._stop_reconnecting()
            raise RobotUnreachable(f"cannot reach the robot's rosbridge at {url} within {connect_timeout:g} s") \
                from None
        self._connected = True
        self._publishers = {part: roslibpy.Topic(self._ros, topic, "std_msgs/Float64MultiArray")
                            for part, topic in names.PART_COMMAND_TOPICS.items()}
        for topic in self._publishers.values():
            topic.advertise()
        self._joints_topic = roslibpy.Topic(self._ros, names.JOINT_STATE_TOPIC, "sensor_msgs/JointState")
        self._joints_topic.subscribe(self._on_joint_state)
        self._motors_topic = roslibpy.Topic(self._ros, names.MOTOR_STATES_TOPIC, MOTOR_STATE_TYPE)
        self._motors_topic.subscribe(self._on_motor_states)
        self._camera_topic = roslibpy.Topic(self._ros, names.CAMERA_TOPIC, "sensor_msgs/CompressedImage",
                                            queue_length=1)
        self._microphone_topic = roslibpy.Topic(self._ros, names.ROBOT_MICROPHONE_TOPIC, "audio_common_msgs/AudioData")
        self._listeners: list[Callable[[bytes, int, int], None]] = []
        self._speaker_topic = roslibpy.Topic(self._ros, names.ROBOT_SPEAKER_TOPIC, "audio_common_msgs/AudioData")
        self._speaker_topic.advertise()
        self._speaker_format: tuple[int, int] = (0, 0)
        self._speaker_resampler: av.AudioResampler | None = None
        self._speaker_pending = bytearray()
        self._voice = (0.0, 0.0)  # (level, monotonic time) of the newest piece of voice

    @classmethod
    async def create(cls, url: str, model: RobotModel | None = None) -> RosRobot:
        robot = await asyncio.to_thread(cls, url, model)
        robot._loop = asyncio.get_running_loop()
        return robot

    # ---- connection ---------------------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self._ros.is_connected

    def _on_ready(self, *_args: Any) -> None:
        if not self._connected:
            log.info("robot rosbridge %s connected", self.url)
            self._connected = True
            self._announce(True)

    def _on_close(self, *_args: Any) -> None:
        if self._connected:
            log.warning("robot rosbridge %s disconnected; reconnecting", self.url)
            self._connected = False
            self._announce(False)

    def _announce(self, connected: bool) -> None:
        """From roslibpy's thread to the listeners on the event loop (none before start-up completed)."""
        loop = self._loop
        if loop is None:
            return
        with contextlib.suppress(RuntimeError):  # the loop has closed: nobody to tell
            loop.call_soon_threadsafe(self._notify, connected)

    def _notify(self, connected: bool) -> None:
        for listener in list(self.connection_changed):
            try:
                listener(connected)
            except Exception:  # one faulty listener must not silence the others
                log.exception("robot connection listener failed")

    @property
    def model(self) -> RobotModel:
        return self._model

    # ---- motion -------------------------------------------------------------------------------------------------
    def set_joint_targets(self, targets: Mapping[str, float]) -> ClampReport:
        clamped, report = clamp_command(self._model, targets)
        if not self.connected:
            return ClampReport(report.names, report.requested, report.applied, report.clamped, tuple(clamped))
        with self._lock:
            current = self._state.as_dict() if self._state is not None else {}
        for part, joints in self._model.parts.items():
            if not any(n in clamped for n in joints):
                continue
            values = []
            for n in joints:
                value = clamped.get(n, self._commanded.get(n, current.get(n, self._model.joint(n).home)))
                values.append(float(value))
                self._commanded[n] = float(value)
            self._publishers[part].publish(roslibpy.Message({"data": values}))
        return report

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
    def _refuse_if_disconnected(self, name: str) -> None:
        if not self.connected:
            raise RobotDisconnected(f"{name}: the robot's rosbridge at {self.url} is disconnected (reconnecting); "
                                    "try again once it is back")

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

    async def play_gesture(self, gesture: Gesture, speed: float = 1.0) -> GestureResult:
        """Streams the gesture's waypoints as position commands, so recordings the robot does not hold play too."""
        gesture.validate(self._model)
        self._refuse_if_disconnected(names.GESTURE_PLAY_SERVICE)
        if not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"gesture speed must be a positive number, got {speed!r}")
        self.stop_gesture()
        stop = self._gesture_stop = asyncio.Event()
        streamed = await stream_waypoints(self.set_joint_targets, gesture, speed, stop)
        if self._gesture_stop is stop:
            self._gesture_stop = None
        stopped = stop.is_set()
        completed = not stopped and streamed.sent == len(gesture.waypoints) and not streamed.ignored
        return GestureResult(gesture.name, completed, stopped, streamed.sent, streamed.clamps, streamed.ignored, None)

    def stop_gesture(self) -> None:
        if self._gesture_stop is not None:
            self._gesture_stop.set()

    # ---- camera -------------------------------------------------------------------------------------------------
    def add_camera_subscriber(self) -> None:
        self._camera_count += 1
        if self._camera_count == 1:
            self._camera_topic.subscribe(self._on_camera)

    def remove_camera_subscriber(self) -> None:
        self._camera_count = max(0, self._camera_count - 1)
        if self._camera_count == 0 and self._camera_topic.is_subscribed:
            self._camera_topic.unsubscribe()

    def _on_camera(self, msg: dict[str, Any]) -> None:
        data = msg.get("data", "")
        jpeg = base64.b64decode(data) if isinstance(data, str) else bytes(data)
        width, height = _jpeg_size(jpeg)
        self._frame_seq += 1  # only roslibpy's thread counts
        self._frames.put(CameraFrame(jpeg, width, height, self._frame_seq, time.monotonic(), time.time()))

    def latest_frame(self) -> CameraFrame | None:
        return self._frames.newest

    async def next_frame(self, after_seq: int = 0, timeout: float | None = None) -> CameraFrame | None:
        return await self._frames.next(after_seq, timeout)

    def camera_closed(self) -> bool:
        return self._frames.closed

    # ---- microphone ---------------------------------------------------------------------------------------------
    def listen(self, listener: Callable[[bytes, int, int], None]) -> Callable[[], None]:
        self._listeners.append(listener)
        if len(self._listeners) == 1:
            self._microphone_topic.subscribe(self._on_microphone)

        def stop() -> None:
            if listener in self._listeners:
                self._listeners.remove(listener)
            if not self._listeners and self._microphone_topic.is_subscribed:
                self._microphone_topic.unsubscribe()

        return stop

    def _on_microphone(self, msg: dict[str, Any]) -> None:
        """On roslibpy's thread: rosbridge sends uint8[] as base64 (ROS 1) or a list of numbers."""
        data = msg.get("data", "")
        try:
            pcm = base64.b64decode(data) if isinstance(data, str) else bytes(data)
        except (ValueError, TypeError):
            log.warning("%s: a message whose data is not audio bytes was ignored", names.ROBOT_MICROPHONE_TOPIC)
            return
        loop = self._loop
        if loop is None or not pcm:
            return
        with contextlib.suppress(RuntimeError):  # the loop has closed: nobody listens
            loop.call_soon_threadsafe(self._hear, pcm)

    def _hear(self, pcm: bytes) -> None:
        for listener in list(self._listeners):
            try:
                listener(pcm, MICROPHONE_RATE, 1)
            except Exception:
                log.exception("a microphone listener failed")

    # ---- the operator's voice -----------------------------------------------------------------------------------
    def play_voice(self, pcm: bytes, sample_rate: int, channels: int) -> None:
        self._voice = (pcm_level(pcm), time.monotonic())
        if not self.connected:
            self._speaker_pending.clear()
            return
        if (sample_rate, channels) != self._speaker_format:
            self._speaker_format = (sample_rate, channels)
            self._speaker_resampler = av.AudioResampler(format="s16", layout="mono", rate=SPEAKER_RATE)
            self._speaker_pending.clear()
        samples = np.frombuffer(pcm[:len(pcm) - len(pcm) % (2 * channels)], "<i2")
        frame = av.AudioFrame.from_ndarray(samples.reshape(1, -1), format="s16",
                                           layout="stereo" if channels == 2 else "mono")
        frame.sample_rate = sample_rate
        for out in self._speaker_resampler.resample(frame):
            self._speaker_pending += out.to_ndarray().tobytes()
        step = int(SPEAKER_RATE * SPEAKER_CHUNK_S) * 2
        while len(self._speaker_pending) >= step:
            chunk = bytes(self._speaker_pending[:step])
            del self._speaker_pending[:step]
            self._speaker_topic.publish(roslibpy.Message({"data": base64.b64encode(chunk).decode("ascii")}))

    @property
    def voice_level(self) -> float:
        return held_level(self._voice, time.monotonic())

    def _stop_reconnecting(self) -> None:
        from twisted.internet import reactor

        reactor.callFromThread(self._ros.factory.stopTrying)

    def close(self) -> None:
        self._frames.close()
        self._loop = None  # our own closing is no news for the listeners
        self._stop_reconnecting()
        with contextlib.suppress(Exception):  # already gone
            self._ros.close(timeout=2)


