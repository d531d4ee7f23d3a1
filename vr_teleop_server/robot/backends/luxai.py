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

Lost and back: the joints state stream is the robot's heartbeat. When it stops for LOST_AFTER_S (or the broker
connection drops), `connected` turns False and `connection_changed` listeners hear it on the event loop; commands are
then reported ignored and RPCs refused, never queued (the stream writers are closed, dropping whatever their sockets
still held, and opened afresh once the robot is back). The transports reconnect by themselves: ZeroMQ's sockets
retry every RECONNECT interval, the MQTT client with a back-off from 1 to MQTT_MAX_BACKOFF_S seconds.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

import av
import cv2
import numpy as np

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

DEFAULT_HUB_PORT = 50500  # LuxAI's service hub
DEFAULT_CAMERA_PORT = 50655  # LuxAI's realsense-driver plugin
CAMERA_NODE_ID = "qtrobot-realsense-driver"  # the plugin's node id, its namespace through the MQTT gateway
CALL_TIMEOUT_S = 30.0  # the longest any SDK call may take (a gesture file or a sentence included)
LOST_AFTER_S = 1.0  # no joint state for this long: the robot is lost
WATCH_PERIOD_S = 0.1
MQTT_MAX_BACKOFF_S = 5
SPEAKER_RATE = 16000  # the media foreground audio stream: PCM S16LE, 16 kHz mono
SPEAKER_CHUNK_S = 0.04
JPEG_QUALITY = 80
DIRECTION_STEP_DEG = 20.0  # a voice that moves this far while it lasts is news again
FAULT_KEYS = ("overload_limit", "voltage_limit", "temperature_limit", "sensor_failure")


def _angle(a: float, b: float) -> float:
    """The smaller angle between two directions in degrees."""
    return abs((a - b + 180.0) % 360.0 - 180.0)


class RobotUnreachable(RuntimeError):
    """The robot did not answer at start-up: the server cannot run this backend."""


class RobotDisconnected(Refusal):
    """A request refused while the robot is away; the client sees the message as it is."""


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


class LuxaiRobot(Robot):
    """QTrobot v3 through `luxai-robot`. Construction connects and blocks: from asyncio, use `await create(...)`."""

    def __init__(self, url: str, model: RobotModel | None = None, *, robot_id: str | None = None,
                 camera_url: str | None = None, connect_timeout: float = 10.0, mqtt_ca_file: Path | None = None,
                 mqtt_username: str | None = None, mqtt_password: str | None = None) -> None:
        self.transport, self.url = parse_robot_url(url, robot_id)
        self.robot_id = robot_id
        self._mqtt_login = (mqtt_ca_file, mqtt_username, mqtt_password)
        self._lock = threading.Lock()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._pool = concurrent.futures.ThreadPoolExecutor(max_workers=6, thread_name_prefix="luxai-sdk")
        self._closed = threading.Event()
        self.connection_changed: list[Callable[[bool], None]] = []  # called on the event loop with the new state
        self.events: list[Callable[[str, str, dict[str, Any]], None]] = []  # (kind, level, detail), on the loop
        _, self._command_frame, self._audio_frame = _sdk()
        self._sdk_robot = self._connect(connect_timeout)
        try:
            base = model or load_qtrobot()
            self.robot_limits = self._read_limits(base)
            try:
                self._model = base.narrowed(self.robot_limits)
            except ValueError as exc:
                raise RobotUnreachable(f"the QTrobot v3 at {self.url} cannot be driven safely: {exc}") from None
            self._emotions = self._list("face.list_emotions", self._sdk_robot.face.list_emotions)
            self._gesture_files = tuple(f.removesuffix(".xml") for f in
                                        self._list("gesture.list_files", self._sdk_robot.gesture.list_files))
            self.camera_problem = self._enable_camera(camera_url)
            narrowed = [f"{j.name} {j.lower:g}..{j.upper:g}" for j in self._model.joints
                        if (j.lower, j.upper) != (base.joint(j.name).lower, base.joint(j.name).upper)]
            log.info("QTrobot v3 %s (%s) at %s; %s; camera: %s", self._sdk_robot.robot_id or robot_id,
                     self._sdk_robot.robot_type, self.url,
                     f"its limits narrow {', '.join(narrowed)} deg" if narrowed else "the model's limits hold",
                     self.camera_problem or "realsense-driver")
            self._state: JointState | None = None
            self._readings: dict[str, tuple[float | None, float | None]] = {}
            self._faults: dict[str, tuple[str, ...]] = {}
            self._last_state = time.monotonic()
            self._connected = True
            self._modes = {n: MotorMode.ON for n in self._model.names}
            self._commanded: dict[str, float] = {}
            self._writers_lock = threading.Lock()
            self._speech: Any = None  # the ActionHandle of the sentence being said
            self._gesture: Any = None  # the ActionHandle of the gesture file playing, or an asyncio.Event
            self._stopped: set[int] = set()  # id() of the handles stop_speech()/stop_gesture() cancelled
            self._voice_config: dict[str, Any] = {}
            self._frames = FrameMailbox()
            self._frame_seq = 0
            self._camera_count = 0
            self._camera_thread: threading.Thread | None = None
            self._camera_stop = threading.Event()
            self._listeners: list[Callable[[bytes, int, int], None]] = []
            self._microphone: Any = None
            self._speaker_format = (0, 0)
            self._speaker_resampler: av.AudioResampler | None = None
            self._speaker_pending = bytearray()
            self._voice = (0.0, 0.0)
            self._mic_activity: tuple[bool, float | None] | None = None  # the last (activity, direction) told
            self._command_writer: Any = None
            self._speaker_writer: Any = None
            self._open_writers()
            self._subscriptions = [self._sdk_robot.motor.stream.on_joints_state(self._on_joint_state, queue_size=1),
                                   *self._optional_stream("the motors' error stream", "motor", "on_joints_error",
                                                          self._on_joints_error),
                                   *self._optional_stream("the microphone's events", "microphone", "on_int_event",
                                                          self._on_mic_event)]
            self._watcher = threading.Thread(target=self._watch, name="luxai-watch", daemon=True)
            self._watcher.start()
        except BaseException:
            self._closed.set()
            with contextlib.suppress(Exception):
                self._sdk_robot.close()
            self._pool.shutdown(wait=False)
            raise

    @classmethod
    async def create(cls, url: str, model: RobotModel | None = None, **options: Any) -> LuxaiRobot:
        robot = await asyncio.to_thread(lambda: cls(url, model, **options))
        robot._loop = asyncio.get_running_loop()
        return robot

    # ---- connection ---------------------------------------------------------------------------------------------
    def _connect(self, timeout: float) -> Any:
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
    def connected(self) -> bool:
        return self._connected

    @property
    def info(self) -> dict[str, Any]:
        return {"backend": "luxai", "robot_url": self.url, "robot_id": self._sdk_robot.robot_id or self.robot_id,
                "robot_type": self._sdk_robot.robot_type, "connected": self._connected,
                "camera": {"available": not self.camera_problem, "source": self.camera_source,
                           "problem": self.camera_problem},
                "robot_limits": self.robot_limits}

    def _watch(self) -> None:
        """The heartbeat: lost when joint states stop (or the broker is gone), back when they flow again."""
        while not self._closed.wait(WATCH_PERIOD_S):
            alive = time.monotonic() - self._last_state < LOST_AFTER_S
            if alive == self._connected:
                continue
            if alive:
                try:
                    self._open_writers()  # fresh sockets: nothing from before the loss goes out
                except Exception as exc:  # the SDK could not open them yet: still lost, try again
                    log.warning("QTrobot v3 at %s answers again but its streams cannot be opened: %s", self.url, exc)
                    continue
                log.info("QTrobot v3 at %s is back", self.url)
            else:
                log.warning("QTrobot v3 at %s is lost (no joint state for %.1f s); waiting for it", self.url,
                            LOST_AFTER_S)
                self._close_writers()
                self._stop_actions()
            self._connected = alive
            self._call_soon(self._notify, alive)

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

    def _stop_actions(self) -> None:
        """The robot is gone: whatever waited on it ends now rather than at its timeout."""
        gesture = self._gesture
        if isinstance(gesture, asyncio.Event):
            self._call_soon(gesture.set)

    def _call_soon(self, fn: Callable[..., None], *args: Any) -> None:
        loop = self._loop
        if loop is None:
            return
        with contextlib.suppress(RuntimeError):  # the loop has closed: nobody to tell
            loop.call_soon_threadsafe(fn, *args)

    def _notify(self, connected: bool) -> None:
        for listener in list(self.connection_changed):
            try:
                listener(connected)
            except Exception:
                log.exception("robot connection listener failed")

    def _event(self, kind: str, level: str, detail: dict[str, Any]) -> None:
        """Any thread: an event for the listeners on the loop."""
        def deliver() -> None:
            for listener in list(self.events):
                try:
                    listener(kind, level, detail)
                except Exception:
                    log.exception("robot event listener failed")
        self._call_soon(deliver)

    @property
    def model(self) -> RobotModel:
        return self._model

    # ---- motion -------------------------------------------------------------------------------------------------
    def set_joint_targets(self, targets: Mapping[str, float]) -> ClampReport:
        clamped, report = clamp_command(self._model, targets)
        writer = self._command_writer
        ignored = tuple(n for n in clamped if writer is None or not self._connected
                        or self._modes[n] is not MotorMode.ON)
        if ignored:
            report = ClampReport(report.names, report.requested, report.applied, report.clamped, ignored)
        moving = {n: v for n, v in clamped.items() if n not in ignored}
        if moving:
            frame = self._command_frame()
            for name, value in moving.items():
                frame.set_joint(name, position=value, velocity=self._model.joint(name).max_velocity)
            self._commanded.update(moving)
            self._write("_command_writer", frame)
        return report

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
        self._last_state = state.stamp_monotonic

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
                self._event("motor_error", "danger", {"motor": name, "faults": list(fault)})
            else:
                self._event("motor_ok", "info", {"motor": name})

    def motor_faults(self) -> dict[str, tuple[str, ...]]:
        with self._lock:
            return {n: f for n, f in self._faults.items() if f}

    def motor_status(self) -> tuple[MotorStatus, ...]:
        positions = self.joint_state().as_dict()
        with self._lock:
            readings, faults = dict(self._readings), dict(self._faults)
        return tuple(MotorStatus(n, part, positions.get(n, math.nan), *readings.get(n, (None, None)), self._modes[n],
                                 "measured", ",".join(faults.get(n, ())))
                     for part, joints in self._model.parts.items() for n in joints)

    # ---- the SDK's calls ----------------------------------------------------------------------------------------
    def _refuse_if_disconnected(self, what: str) -> None:
        if not self._connected:
            raise RobotDisconnected(f"{what}: the QTrobot v3 at {self.url} is disconnected (waiting for it to come "
                                    "back); try again once it is back")

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
                if not self._connected or time.monotonic() > deadline:
                    return False
                with contextlib.suppress(TimeoutError):
                    handle.wait(WATCH_PERIOD_S)
            try:
                return handle.result(0) is not False  # say_text, play_file: False when it did not finish
            except ActionError as exc:
                log.debug("QTrobot v3 action ended: %s", exc)
                return False

        ok = await asyncio.to_thread(wait)
        stopped = id(handle) in self._stopped or not self._connected
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
        handle = self._gesture = await asyncio.to_thread(self._sdk_robot.gesture.play_file_async, name, speed)
        try:
            completed, stopped = await self._finished(handle)
        finally:
            if self._gesture is handle:
                self._gesture = None
        return GestureResult(name, completed, stopped, 0, (), (), None)

    async def play_gesture(self, gesture: Gesture, speed: float = 1.0) -> GestureResult:
        """The server's gestures (its files, recordings) are streamed as joint commands, waypoint by waypoint."""
        gesture.validate(self._model)
        if not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"gesture speed must be a positive number, got {speed!r}")
        self._refuse_if_disconnected("gesture")
        self.stop_gesture()
        stop = self._gesture = asyncio.Event()
        streamed = await stream_waypoints(self.set_joint_targets, gesture, speed, stop)
        if self._gesture is stop:
            self._gesture = None
        stopped = stop.is_set()
        completed = not stopped and streamed.sent == len(gesture.waypoints) and not streamed.ignored
        return GestureResult(gesture.name, completed, stopped, streamed.sent, streamed.clamps, streamed.ignored, None)

    def stop_gesture(self) -> None:
        gesture = self._gesture
        if isinstance(gesture, asyncio.Event):
            gesture.set()
        elif gesture is not None and not gesture.done():
            self._stopped.add(id(gesture))
            self._submit("stop gesture", gesture.cancel, CALL_TIMEOUT_S)

    # ---- camera -------------------------------------------------------------------------------------------------
    def add_camera_subscriber(self) -> None:
        self._camera_count += 1
        if self._camera_count == 1 and not self.camera_problem:
            self._camera_stop = threading.Event()
            self._camera_thread = threading.Thread(target=self._read_camera, args=(self._camera_stop,),
                                                   name="luxai-camera", daemon=True)
            self._camera_thread.start()

    def remove_camera_subscriber(self) -> None:
        self._camera_count = max(0, self._camera_count - 1)
        if self._camera_count == 0:
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
                    self._frame_seq += 1  # only this thread counts
                    self._frames.put(CameraFrame(jpeg.tobytes(), frame.width, frame.height, self._frame_seq,
                                                 time.monotonic(), time.time()))
        finally:
            with contextlib.suppress(Exception):
                reader.close()

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
            self._microphone = self._sdk_robot.microphone.stream.on_int_audio_ch0(self._on_microphone)

        def stop() -> None:
            if listener in self._listeners:
                self._listeners.remove(listener)
            if not self._listeners and self._microphone is not None:
                self._microphone.cancel()
                self._microphone = None

        return stop

    def _on_microphone(self, frame: Any) -> None:
        pcm = bytes(getattr(frame, "data", b"") or b"")
        if pcm:
            rate, channels = int(frame.sample_rate or 16000), int(frame.channels or 1)
            self._call_soon(self._hear, pcm, rate, channels)

    def _hear(self, pcm: bytes, rate: int, channels: int) -> None:
        for listener in list(self._listeners):
            try:
                listener(pcm, rate, channels)
            except Exception:
                log.exception("a microphone listener failed")

    def _on_mic_event(self, frame: Any) -> None:
        """{activity, direction}: an event when a voice starts or stops, or, while it lasts, moves by
        DIRECTION_STEP_DEG or more (the array's estimate wanders a little at its own rate)."""
        value = getattr(frame, "value", None) or {}
        activity = bool(value.get("activity"))
        direction = value.get("direction")
        direction = float(direction) if isinstance(direction, (int, float)) else None
        last = self._mic_activity
        if last is not None and activity == last[0] and not (
                activity and direction is not None and (last[1] is None or _angle(direction, last[1])
                                                        >= DIRECTION_STEP_DEG)):
            return
        self._mic_activity = (activity, direction)
        self._event("voice_activity", "info", {"activity": activity, "direction_deg": direction})

    # ---- the operator's voice -----------------------------------------------------------------------------------
    def play_voice(self, pcm: bytes, sample_rate: int, channels: int) -> None:
        self._voice = (pcm_level(pcm), time.monotonic())
        writer = self._speaker_writer
        if writer is None or not self._connected:
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
            frame = self._audio_frame(channels=1, sample_rate=SPEAKER_RATE, bit_depth=16, data=chunk)
            if not self._write("_speaker_writer", frame):
                return

    @property
    def voice_level(self) -> float:
        return held_level(self._voice, time.monotonic())

    # ---- lifecycle ----------------------------------------------------------------------------------------------
    def close(self) -> None:
        if self._closed.is_set():
            return
        self._closed.set()
        self._loop = None  # our own closing is no news for the listeners
        self._frames.close()
        self._camera_stop.set()
        for subscription in [*self._subscriptions, self._microphone]:
            if subscription is not None:
                subscription.cancel()
        self._watcher.join(timeout=2)
        self._close_writers()
        self._pool.shutdown(wait=False, cancel_futures=True)
        with contextlib.suppress(Exception):
            self._sdk_robot.close()
