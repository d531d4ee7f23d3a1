"""QTrobot v3 (the QTRD series), driven through LuxAI's own SDK (`luxai-robot`, on the `luxai-magpie` engine).

The SDK does the wire: ZeroMQ to the robot's service hub on the LAN (`tcp://ROBOT:50500`), or MQTT through a broker
that the robot's `qtrobot-service-hub-gateway-mqtt` also reaches (`mqtt://`, `mqtts://`, `wss://` with a robot id).
This class only maps the Robot interface onto it:

- joints: commands on the joints command stream (degrees, with each joint's velocity cap as its velocity), written
  at once from the caller (no writer queue), so nothing waits behind the robot; states from the joints state stream.
  The limits are the intersection of the robot's own (`motor.list()` at connect) and the model's.
- face, speech, gestures, motors: the SDK's RPCs. They block until the robot is done and have no timeout of their
  own, so each runs in this backend's thread pool, bounded by CALL_TIMEOUT_S (the SDK's default RPC timeout here).
- audio: the operator's voice goes to the speaker on the media foreground audio stream (PCM S16LE, 16 kHz mono);
  the microphone's channel 0 is read while someone listens; voice activity and direction of arrival become events.
- camera: the `realsense-driver` plugin's color stream (raw BGR), encoded to JPEG in the reader's thread.

Lost and back are the link's rule (robot/link.py), with the joints state stream as the heartbeat: while the robot is
lost the stream writers are closed, dropping whatever their sockets still held, and they are opened afresh when it is
back (`_resume`). The transports reconnect by themselves: ZeroMQ's sockets retry every RECONNECT interval, the MQTT
client with a back-off from 1 to MQTT_MAX_BACKOFF_S seconds.

Hearing: the microphone's events ({activity, direction}) are the link's voice activity; `_to_base` maps their
direction, assumed to be the array's azimuth counter-clockwise from the face (the base frame's sense; LuxAI documents
neither), turned with the head's yaw.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import urlparse

import cv2
import numpy as np

from client_protocol.events import CameraProblem, EventKind, EventLevel, Motor, MotorFault
from robot_models import RobotModel, load_qtrobot

from ..interface import (
    ClampReport,
    GestureResult,
    JointState,
    MotorMode,
    MotorStatus,
    SpeechResult,
    clamp_command,
)
from ..link import SPEAKER_RATE, WATCH_PERIOD_S, RobotLink, RobotUnreachable, wrap_deg

if TYPE_CHECKING:
    from simclock import Clock

    from ...settings import ServerSettings

log = logging.getLogger(__name__)

DEFAULT_HUB_PORT = 50500  # LuxAI's service hub
DEFAULT_CAMERA_PORT = 50655  # LuxAI's realsense-driver plugin
CAMERA_NODE_ID = "qtrobot-realsense-driver"  # the plugin's node id, its namespace through the MQTT gateway
CALL_TIMEOUT_S = 30.0  # the longest any SDK call may take (a gesture file or a sentence included)
CONNECT_TIMEOUT_S = 10.0
MQTT_MAX_BACKOFF_S = 5
JPEG_QUALITY = 80
FAULT_KEYS = ("overload_limit", "voltage_limit", "temperature_limit", "sensor_failure")


def _sdk():
    """The SDK, imported when this backend is chosen (it starts nothing at import)."""
    from luxai.robot.core import Robot as SdkRobot  # noqa: PLC0415
    from luxai.robot.core.frames import JointCommandFrame  # noqa: PLC0415
    from luxai.magpie.frames import AudioFrameRaw  # noqa: PLC0415

    return SdkRobot, JointCommandFrame, AudioFrameRaw


def parse_robot_url(url: str, robot_id: str | None) -> tuple[str, str]:
    """("zmq" | "mqtt", the URL with its default port): checks the URL's form, naming what to give instead."""
    parsed = urlparse(url)
    if parsed.scheme == "tcp":
        if not parsed.hostname:
            raise ValueError(f"robot URL {url!r}: give the service hub as tcp://HOST:PORT (LuxAI's port is "
                             f"{DEFAULT_HUB_PORT})")
        return "zmq", f"tcp://{parsed.hostname}:{parsed.port or DEFAULT_HUB_PORT}"
    if parsed.scheme in ("mqtt", "mqtts", "ws", "wss"):
        if not parsed.hostname:
            raise ValueError(f"robot URL {url!r}: give the broker as {parsed.scheme}://HOST:PORT")
        if not robot_id:
            raise ValueError(f"robot URL {url!r} is an MQTT broker: give the robot's id too (--robot-id QTRD000320)")
        return "mqtt", url
    raise ValueError(f"robot URL {url!r}: for --backend luxai use tcp://ROBOT:{DEFAULT_HUB_PORT} (ZeroMQ on the LAN) "
                     "or mqtt://BROKER:1883 (also mqtts://, wss://) with --robot-id")


class LuxaiRobot(RobotLink):
    """QTrobot v3 through `luxai-robot`. Construction only checks the URL; open() connects."""

    backend = "luxai"
    check_url = staticmethod(parse_robot_url)

    def __init__(self, url: str, model: RobotModel | None = None, *, robot_id: str | None = None,
                 camera_url: str | None = None, connect_timeout: float = CONNECT_TIMEOUT_S,
                 mqtt_ca_file: Path | None = None, mqtt_username: str | None = None,
                 mqtt_password: str | None = None) -> None:
        transport, url = parse_robot_url(url, robot_id)
        super().__init__(url, model or load_qtrobot())
        self.transport = transport
        self.robot_id = robot_id
        self._camera_url = camera_url
        self._connect_timeout = connect_timeout
        self._mqtt_login = (mqtt_ca_file, mqtt_username, mqtt_password)
        self._lock = threading.Lock()
        self._pool = concurrent.futures.ThreadPoolExecutor(max_workers=6, thread_name_prefix="luxai-sdk")
        self._sdk_robot: Any = None
        self.robot_limits: dict[str, dict[str, float]] = {}
        self.camera_problem = "not connected"
        self.camera_source = ""
        self._emotions: tuple[str, ...] = ()
        self._gesture_files: tuple[str, ...] = ()
        self._state: JointState | None = None
        self._readings: dict[str, tuple[float | None, float | None]] = {}
        self._faults: dict[str, tuple[str, ...]] = {}
        self._modes = {n: MotorMode.ON for n in self._model.names}
        self._commanded: dict[str, float] = {}
        self._writers_lock = threading.Lock()
        self._speech: Any = None  # the ActionHandle of the sentence being said
        self._own_gesture: Any = None  # the ActionHandle of the gesture file playing
        self._stopped: set[int] = set()  # id() of the handles stop_speech()/stop_gesture() cancelled
        self._voice_config: dict[str, Any] = {}
        self._camera_thread: threading.Thread | None = None
        self._camera_stop = threading.Event()
        self._microphone: Any = None
        self._command_writer: Any = None
        self._speaker_writer: Any = None
        self._subscriptions: list[Any] = []

    @classmethod
    def from_settings(cls, settings: ServerSettings, model: RobotModel, _clock: Clock | None = None) -> LuxaiRobot:
        return cls(settings.resolved_robot_url, model, robot_id=settings.robot_id, camera_url=settings.camera_url,
                   mqtt_ca_file=settings.mqtt_ca_file, mqtt_username=settings.mqtt_username,
                   mqtt_password=settings.mqtt_password)

    # ---- connection ---------------------------------------------------------------------------------------------
    def _connect(self) -> None:
        _, self._command_frame, self._audio_frame = _sdk()
        self._sdk_robot = self._open_sdk(self._connect_timeout)
        base = self._model
        self.robot_limits = self._read_limits(base)
        try:
            self._model = base.narrowed(self.robot_limits)
        except ValueError as exc:
            raise RobotUnreachable(f"the QTrobot v3 at {self.url} cannot be driven safely: {exc}") from None
        self._emotions = self._list("face.list_emotions", self._sdk_robot.face.list_emotions)
        self._gesture_files = tuple(f.removesuffix(".xml") for f in
                                    self._list("gesture.list_files", self._sdk_robot.gesture.list_files))
        self.camera_problem = self._enable_camera(self._camera_url)
        if self.camera_problem:
            self._event(EventKind.CAMERA_UNAVAILABLE, EventLevel.WARNING, CameraProblem(problem=self.camera_problem))
        narrowed = [f"{j.name} {j.lower:g}..{j.upper:g}" for j in self._model.joints
                    if (j.lower, j.upper) != (base.joint(j.name).lower, base.joint(j.name).upper)]
        log.info("QTrobot v3 %s (%s) at %s; %s; camera: %s", self._sdk_robot.robot_id or self.robot_id,
                 self._sdk_robot.robot_type, self.url,
                 f"its limits narrow {', '.join(narrowed)} deg" if narrowed else "the model's limits hold",
                 self.camera_problem or "realsense-driver")
        self._open_writers()
        self._subscriptions = [self._sdk_robot.motor.stream.on_joints_state(self._on_joint_state, queue_size=1),
                               *self._optional_stream("the motors' error stream", "motor", "on_joints_error",
                                                      self._on_joints_error),
                               *self._optional_stream("the microphone's events", "microphone", "on_int_event",
                                                      self._on_mic_event)]

    def _disconnect(self) -> None:
        self._camera_stop.set()
        for subscription in [*self._subscriptions, self._microphone]:
            if subscription is not None:
                with contextlib.suppress(Exception):
                    subscription.cancel()
        self._subscriptions, self._microphone = [], None
        self._close_writers()
        self._pool.shutdown(wait=False, cancel_futures=True)
        if self._sdk_robot is not None:
            with contextlib.suppress(Exception):
                self._sdk_robot.close()

    def _resume(self) -> None:
        self._open_writers()  # fresh sockets: nothing from before the loss goes out

    def _on_lost(self) -> None:
        self._close_writers()

    def _to_base(self, array_deg: float) -> float:
        return wrap_deg(array_deg + self.joint_state().as_dict().get("HeadYaw", 0.0))

    def _open_sdk(self, timeout: float) -> Any:
        SdkRobot, _, _ = _sdk()
        try:
            if self.transport == "zmq":
                return SdkRobot.connect_zmq(endpoint=self.url, connect_timeout=timeout,
                                            default_rpc_timeout=CALL_TIMEOUT_S)
            from luxai.robot import (MqttAuthOptions, MqttDefaultsOptions, MqttOptions,  # noqa: PLC0415
                                     MqttReconnectOptions, MqttTlsOptions)

            ca_file, username, password = self._mqtt_login
            # Stream frames at QoS 0: a frame the broker cannot take now is dropped, not queued for later.
            options = MqttOptions(reconnect=MqttReconnectOptions(min_delay_sec=1, max_delay_sec=MQTT_MAX_BACKOFF_S),
                                  defaults=MqttDefaultsOptions(publish_qos=0),
                                  tls=MqttTlsOptions(ca_file=str(ca_file) if ca_file else None),
                                  auth=MqttAuthOptions(mode="username_password" if username else "none",
                                                       username=username, password=password))
            return SdkRobot.connect_mqtt(self.url, self.robot_id, options=options, connect_timeout=timeout,
                                         default_rpc_timeout=CALL_TIMEOUT_S)
        except Exception as exc:  # the SDK raises RuntimeError, TimeoutError or the socket's own errors
            where = self.url if self.transport == "zmq" else f"{self.url} (robot id {self.robot_id})"
            raise RobotUnreachable(f"cannot reach the QTrobot v3 service hub at {where} within {timeout:g} s: "
                                   f"{exc}") from None

    def _read_limits(self, model: RobotModel) -> dict[str, dict[str, float]]:
        """The robot's own ranges and velocity caps, from motor.list(), for the joints the model drives."""
        try:
            motors = self._sdk_robot.motor.list()
        except Exception as exc:
            raise RobotUnreachable(f"the QTrobot v3 at {self.url} did not list its motors: {exc}") from None
        limits = {}
        for name in model.names:
            config = (motors or {}).get(name) or {}
            entry = {}
            for ours, theirs in (("lower", "position_min"), ("upper", "position_max"),
                                 ("max_velocity", "velocity_max")):
                value = config.get(theirs)
                if isinstance(value, (int, float)) and math.isfinite(value):
                    entry[ours] = float(value)
            if entry:
                limits[name] = entry
        return limits

    def _optional_stream(self, what: str, namespace: str, method: str, callback: Callable[[Any], None]) -> list[Any]:
        try:
            return [getattr(getattr(self._sdk_robot, namespace).stream, method)(callback)]
        except Exception as exc:  # a robot without it: the rest works
            log.warning("QTrobot v3: %s cannot be read (%s); continuing without it", what, exc)
            return []

    @staticmethod
    def _list(what: str, call: Callable[[], Any]) -> tuple[str, ...]:
        try:
            return tuple(str(v) for v in (call() or ()))
        except Exception as exc:  # an older firmware without it: nothing listed, the rest works
            log.warning("QTrobot v3: %s failed (%s); continuing without it", what, exc)
            return ()

    def _enable_camera(self, camera_url: str | None) -> str:
        """Starts the realsense-driver plugin; '' when it runs, else why there is no camera."""
        try:
            if self.transport == "zmq":
                endpoint = camera_url or f"tcp://{urlparse(self.url).hostname}:{DEFAULT_CAMERA_PORT}"
                self._sdk_robot.enable_plugin_zmq("realsense-driver", endpoint=endpoint)
                self.camera_source = endpoint
            else:
                self._sdk_robot.enable_plugin_mqtt("realsense-driver", node_id=CAMERA_NODE_ID)
                self.camera_source = f"{self.url} node {CAMERA_NODE_ID}"
            return ""
        except Exception as exc:
            self.camera_source = ""
            problem = f"no camera: the realsense-driver plugin did not answer ({exc})"
            log.warning("QTrobot v3: %s", problem)
            return problem

    @property
    def info(self) -> dict[str, Any]:
        sdk = self._sdk_robot
        return {**super().info, "robot_id": (sdk.robot_id if sdk else None) or self.robot_id,
                "robot_type": sdk.robot_type if sdk else None,
                "camera": {"available": not self.camera_problem, "source": self.camera_source,
                           "problem": self.camera_problem},
                "robot_limits": self.robot_limits}

    def _open_writers(self) -> None:
        stream = self._sdk_robot.motor.stream
        command = stream.open_joints_command_writer(queue_size=0)  # written at once: no queue behind the robot
        speaker = self._sdk_robot.media.stream.open_fg_audio_stream_writer(queue_size=0)
        with self._writers_lock:
            self._command_writer, self._speaker_writer = command, speaker

    def _write(self, which: str, frame: Any) -> bool:
        """Writes on the caller's thread, under the lock that closing takes too (a socket is never closed mid-send);
        False when the writer is gone (the robot was just lost): the frame is dropped."""
        with self._writers_lock:
            writer = getattr(self, which)
            if writer is None:
                return False
            try:
                writer.write(frame)
            except Exception as exc:
                log.debug("QTrobot v3: a frame was not sent: %s", exc)
                return False
        return True

    def _close_writers(self) -> None:
        with self._writers_lock:
            for writer in (self._command_writer, self._speaker_writer):
                if writer is not None:
                    with contextlib.suppress(Exception):
                        writer.close()
            self._command_writer = self._speaker_writer = None

    # ---- motion -------------------------------------------------------------------------------------------------
    def _send_targets(self, targets: dict[str, float]) -> tuple[str, ...]:
        """Joints whose motor is ON, at their velocity caps; the others are ignored (BRAKE, or OFF)."""
        ignored = tuple(n for n in targets if self._command_writer is None or self._modes[n] is not MotorMode.ON)
        moving = {n: v for n, v in targets.items() if n not in ignored}
        if moving:
            frame = self._command_frame()
            for name, value in moving.items():
                frame.set_joint(name, position=value, velocity=self._model.joint(name).max_velocity)
            self._commanded.update(moving)
            self._write("_command_writer", frame)
        return ignored

    def _on_joint_state(self, frame: Any) -> None:
        """The SDK's stream thread: {joint: {position, velocity, effort, temperature, voltage}}."""
        value = getattr(frame, "value", None) or {}
        names = tuple(n for n in self._model.names if isinstance(value.get(n), dict) and "position" in value[n])
        if not names:
            return

        def read(name: str, key: str) -> float:
            v = value[name].get(key)
            return float(v) if isinstance(v, (int, float)) else 0.0

        def maybe(name: str, key: str) -> float | None:
            v = value[name].get(key)
            return float(v) if isinstance(v, (int, float)) else None

        state = JointState(names, tuple(read(n, "position") for n in names), tuple(read(n, "velocity") for n in names),
                           tuple(read(n, "effort") for n in names), time.monotonic(), time.time())
        readings = {n: (maybe(n, "temperature"), maybe(n, "voltage")) for n in names}
        with self._lock:
            self._state = state
            self._readings.update(readings)
        self._joints_heard(state.as_dict())  # by arrival: the SDK's frames carry no stamp of the robot's

    def joint_state(self) -> JointState:
        with self._lock:
            state = self._state
        names = self._model.names
        if state is None or len(state.names) != len(names):  # the commanded (or home) pose for what is missing
            known = state.as_dict() if state is not None else {}
            positions = tuple(known.get(n, self._commanded.get(n, self._model.joint(n).home)) for n in names)
            zeros = tuple(0.0 for _ in names)
            now = (time.monotonic(), time.time()) if state is None else (state.stamp_monotonic, state.stamp_wall)
            return JointState(names, positions, zeros, zeros, *now)
        return state

    def set_control_mode(self, parts: Sequence[str], mode: MotorMode) -> None:
        """ON and OFF switch the motors' torque; BRAKE (which v3 has not) keeps them on and ignores commands."""
        mode = MotorMode(mode)
        self._refuse_if_disconnected("motors on/off")
        joints = [n for part in parts for n in self._model.part_joints(part)]
        call = self._sdk_robot.motor.off if mode is MotorMode.OFF else self._sdk_robot.motor.on
        for name in joints:
            self._modes[name] = mode
            self._submit(f"motor {'off' if mode is MotorMode.OFF else 'on'} {name}", call, name)

    def home(self, parts: Sequence[str] | None = None) -> dict[str, ClampReport]:
        """Each motor of the parts goes home through the robot's own motor.home (its home, at its speed)."""
        self._refuse_if_disconnected("home")
        reports = {}
        for part in parts or tuple(self._model.parts):
            joints = self._model.part_joints(part)
            _, report = clamp_command(self._model, {n: self._model.joint(n).home for n in joints})
            ignored = tuple(n for n in joints if self._modes[n] is not MotorMode.ON)
            reports[part] = ClampReport(report.names, report.requested, report.applied, report.clamped, ignored)
            for name in joints:
                if name not in ignored:
                    self._commanded.pop(name, None)
                    self._submit(f"motor home {name}", self._sdk_robot.motor.home, name)
        return reports

    def _on_joints_error(self, frame: Any) -> None:
        """{joint: {overload_limit?, voltage_limit?, temperature_limit?, sensor_failure?}}: a change is an event."""
        value = getattr(frame, "value", None) or {}
        faults = {}
        for name, flags in value.items():
            if isinstance(flags, dict):
                faults[str(name)] = tuple(k for k in FAULT_KEYS if flags.get(k))
        with self._lock:
            changed = {n: f for n, f in faults.items() if self._faults.get(n, ()) != f}
            self._faults.update(changed)
        for name, fault in changed.items():
            if fault:
                log.warning("QTrobot v3 motor %s: %s", name, ", ".join(fault))
                self._event(EventKind.MOTOR_ERROR, EventLevel.DANGER, MotorFault(motor=name, faults=list(fault)))
            else:
                self._event(EventKind.MOTOR_OK, EventLevel.INFO, Motor(motor=name))

    def motor_status(self) -> tuple[MotorStatus, ...]:
        positions = self.joint_state().as_dict()
        with self._lock:
            readings, faults = dict(self._readings), dict(self._faults)
        return tuple(MotorStatus(n, part, positions.get(n, math.nan), *readings.get(n, (None, None)), self._modes[n],
                                 "measured", ",".join(faults.get(n, ())))
                     for part, joints in self._model.parts.items() for n in joints)

    # ---- the SDK's calls ----------------------------------------------------------------------------------------
    def _submit(self, what: str, call: Callable[..., Any], *args: Any, **kwargs: Any) -> concurrent.futures.Future:
        """Runs a blocking SDK call in the pool (bounded by the SDK's default timeout); failures are logged."""
        def run() -> Any:
            try:
                return call(*args, **kwargs)
            except Exception as exc:
                log.warning("QTrobot v3: %s failed: %s", what, exc)
                raise
        return self._pool.submit(run)

    async def _await(self, what: str, call: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        return await asyncio.wrap_future(self._submit(what, call, *args, **kwargs))

    # ---- face, speech, gestures ---------------------------------------------------------------------------------
    def show_emotion(self, name: str) -> None:
        short = name.removeprefix("QT/").removesuffix(".avi")
        offered = {e.removesuffix(".avi").removeprefix("QT/") for e in self._emotions} or set(self._model.emotions)
        if short not in offered:
            raise ValueError(f"unknown emotion {name!r}; this robot offers: {', '.join(sorted(offered))}")
        self._refuse_if_disconnected("emotion")
        self._submit(f"show emotion {short}", self._sdk_robot.face.show_emotion, f"QT/{short}")

    async def say(self, text: str, duration_s: float | None = None) -> SpeechResult:
        """The robot's own voice (tts.say_text), cancellable by stop_speech(); returns when it has finished."""
        self._refuse_if_disconnected("speech")
        self.stop_speech()
        start = time.monotonic()
        handle = self._speech = await asyncio.to_thread(self._sdk_robot.tts.say_text_async, text,
                                                        **self._voice_config)
        try:
            completed, _ = await self._finished(handle)
        finally:
            if self._speech is handle:
                self._speech = None
        return SpeechResult(text, completed, time.monotonic() - start, audible=True)

    async def _finished(self, handle: Any) -> tuple[bool, bool]:
        """Waits (bounded) for an SDK action: (completed: it ended well, stopped: stopped by us or the robot lost)."""
        from luxai.robot.core.actions import ActionError  # noqa: PLC0415

        def wait() -> bool:
            """Until the action ends, the robot is lost or CALL_TIMEOUT_S passes; True if it ended well."""
            deadline = time.monotonic() + CALL_TIMEOUT_S
            while not handle.done():
                if not self.connected or time.monotonic() > deadline:
                    return False
                with contextlib.suppress(TimeoutError):
                    handle.wait(WATCH_PERIOD_S)
            try:
                return handle.result(0) is not False  # say_text, play_file: False when it did not finish
            except ActionError as exc:
                log.debug("QTrobot v3 action ended: %s", exc)
                return False

        ok = await asyncio.to_thread(wait)
        stopped = id(handle) in self._stopped or not self.connected
        self._stopped.discard(id(handle))
        return ok and not stopped, stopped

    def stop_speech(self) -> None:
        handle = self._speech
        if handle is not None and not handle.done():
            self._stopped.add(id(handle))
            self._submit("stop speech", handle.cancel, CALL_TIMEOUT_S)

    async def configure_speech(self, language: str, pitch: int, speed: int) -> None:
        """Speed (percent of normal), pitch and language into the TTS engine's config, and into each say."""
        config: dict[str, Any] = {}
        if language:
            config["lang"] = language
        if pitch:
            config["pitch"] = float(pitch)
        if speed:
            config["rate"] = speed / 100.0
        if not config:
            return
        self._refuse_if_disconnected("speech config")
        self._voice_config.update(config)
        await self._await("speech config", self._sdk_robot.tts.set_config, dict(config))

    def own_gestures(self) -> tuple[str, ...]:
        """The robot's gesture files (gesture.list_files at connect), by the names play_file takes."""
        return self._gesture_files

    async def play_own_gesture(self, name: str, speed: float = 1.0) -> GestureResult:
        """gesture.play_file on the robot, cancellable by stop_gesture()."""
        if name not in self._gesture_files:
            raise ValueError(f"unknown gesture {name!r}; the robot holds: {', '.join(self._gesture_files)}")
        if not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"gesture speed must be a positive number, got {speed!r}")
        self._refuse_if_disconnected("gesture")
        self.stop_gesture()
        handle = self._own_gesture = await asyncio.to_thread(self._sdk_robot.gesture.play_file_async, name, speed)
        try:
            completed, stopped = await self._finished(handle)
        finally:
            if self._own_gesture is handle:
                self._own_gesture = None
        return GestureResult(name, completed, stopped, 0, (), (), None)

    def stop_gesture(self) -> None:
        super().stop_gesture()
        handle = self._own_gesture
        if handle is not None and not handle.done():
            self._stopped.add(id(handle))
            self._submit("stop gesture", handle.cancel, CALL_TIMEOUT_S)

    # ---- camera -------------------------------------------------------------------------------------------------
    def _start_camera(self) -> None:
        if not self.camera_problem:
            self._camera_stop = threading.Event()
            self._camera_thread = threading.Thread(target=self._read_camera, args=(self._camera_stop,),
                                                   name="luxai-camera", daemon=True)
            self._camera_thread.start()

    def _stop_camera(self) -> None:
        self._camera_stop.set()

    def _read_camera(self, stop: threading.Event) -> None:
        """The plugin's color stream (raw BGR) to JPEG, newest frame only, while someone watches."""
        try:
            reader = self._sdk_robot.camera.stream.open_color_reader(queue_size=1)
        except Exception as exc:
            log.warning("QTrobot v3: the camera's color stream cannot be read: %s", exc)
            return
        try:
            while not stop.is_set() and not self._closed.is_set():
                try:
                    frame = reader.read(timeout=0.5)
                except TimeoutError:
                    continue
                if frame is None or not frame.data or not frame.width or not frame.height:
                    continue
                arrived = (time.monotonic(), time.time())
                channels = frame.channels or 3
                pixels = np.frombuffer(frame.data, np.uint8)
                if pixels.size != frame.width * frame.height * channels:
                    log.debug("camera frame of %d bytes is not %dx%dx%d", pixels.size, frame.width, frame.height,
                              channels)
                    continue
                image = pixels.reshape(frame.height, frame.width, channels)
                if (frame.pixel_format or "BGR").upper() == "RGB":
                    image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
                ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
                if ok:
                    self._put_jpeg(jpeg.tobytes(), frame.width, frame.height, arrived=arrived)
        finally:
            with contextlib.suppress(Exception):
                reader.close()

    # ---- microphone ---------------------------------------------------------------------------------------------
    def _start_microphone(self) -> None:
        self._microphone = self._sdk_robot.microphone.stream.on_int_audio_ch0(self._on_microphone)

    def _stop_microphone(self) -> None:
        if self._microphone is not None:
            self._microphone.cancel()
            self._microphone = None

    @property
    def microphone_read(self) -> bool:
        """Whether channel 0 is read (only while someone listens)."""
        return self._microphone is not None

    def _on_microphone(self, frame: Any) -> None:
        pcm = bytes(getattr(frame, "data", b"") or b"")
        self._heard(pcm, int(frame.sample_rate or 16000), int(frame.channels or 1))

    def _on_mic_event(self, frame: Any) -> None:
        """{activity, direction} from the array, for the link's voice activity."""
        value = getattr(frame, "value", None) or {}
        direction = value.get("direction")
        self._heard_voice(bool(value.get("activity")),
                          float(direction) if isinstance(direction, (int, float)) else None)

    # ---- the operator's voice -----------------------------------------------------------------------------------
    def _send_voice(self, chunk: bytes) -> bool:
        frame = self._audio_frame(channels=1, sample_rate=SPEAKER_RATE, bit_depth=16, data=chunk)
        return self._write("_speaker_writer", frame)
