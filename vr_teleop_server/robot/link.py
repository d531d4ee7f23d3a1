"""The link to a real robot: what the ROS 1 QTrobot's backend (roslibpy) and the QTrobot v3's (LuxAI's SDK) share.

`LinkState` is the rule for lost and back, with no I/O (fed facts and times, it answers with decisions), so that it
is tested on its own. `RobotLink` is the base both real backends derive from: it runs the rule, tells the server,
gates commands, and owns the parts that are the same whatever the wire (voice resampling and chunking, gesture
streaming, the camera's reference counting, the microphone's listeners, voice activity). A backend only translates:
`_connect`/`_disconnect`, `_send_targets`, `_send_voice`, `_start_camera`/`_stop_camera`,
`_start_microphone`/`_stop_microphone`, and feeds `_transport`, `_joints_heard` (the heartbeat), `_put_jpeg`, `_heard`,
`_heard_voice`.

Capture poses: every joint state's head goes into a short history (head_history.py), and each camera frame carries
the head's pose interpolated at the frame's stamp. Stamps are the robot's own (a message's header stamp, wall
clock) when both the frame and the joint states carry one, else the server's arrival times (both clocks are never
mixed: the robot's clock need not agree with the server's).

Lost and back, one rule for every real robot:
- The heartbeat is the robot's joint state stream (a QTrobot publishes it all the time, whether ROS 1's
  /qt_robot/joints/state or the v3's joints state stream). The robot is lost when its transport reports the
  connection down, or when no joint state came for LOST_AFTER_S. It is back when the transport is up and joint
  states flow again, and the backend has re-opened what it writes on (`_resume`); a resume that fails is tried
  again after a backoff that doubles from RETRY_MIN_S to RETRY_MAX_S.
- From lost until back, commands are refused: joint targets are reported ignored (never queued to burst out
  later), the operator's voice is dropped, services raise RobotDisconnected, a streamed gesture stops.
- Reconnecting is the transport's: roslibpy's factory retries with a backoff from RETRY_MIN_S to RETRY_MAX_S (set
  on this connection's factory only), ZeroMQ's sockets retry by themselves, the MQTT client backs off to 5 s.
- The server hears it as events (source `backend`): `disconnected` (danger) and `reconnected` (info), with the
  robot's URL; explicit control then says `robot_lost` / `robot_back`.

Voice activity: `_heard_voice` takes the array's speaking flag and angle as the backend reads them, and tells the
server (a `voice_activity` event with the array's own angle, and a VoiceActivity in the base frame) when a voice
starts, stops, or moves DIRECTION_STEP_DEG while it lasts; the backend's `_to_base` maps the array's angle.
"""

from __future__ import annotations

import abc
import asyncio
import contextlib
import dataclasses
import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import av
import numpy as np

from client_protocol import events
from client_protocol.errors import Refusal
from robot_models import RobotModel

from .head_history import HeadHistory
from .interface import (
    CameraFrame,
    ClampReport,
    FrameMailbox,
    Gesture,
    GestureResult,
    Robot,
    VoiceActivity,
    clamp_command,
    held_level,
    pcm_level,
    stream_waypoints,
)

log = logging.getLogger(__name__)

LOST_AFTER_S = 1.0  # no joint state for this long: the robot is lost
RETRY_MIN_S = 0.5  # the backoff of a resume (and of roslibpy's reconnects), doubling...
RETRY_MAX_S = 5.0  # ...up to this
WATCH_PERIOD_S = 0.1  # how often the rule is checked
SPEAKER_RATE = 16000  # the operator's voice for a robot's speaker: PCM S16LE mono at 16 kHz...
SPEAKER_CHUNK_S = 0.04  # ...in pieces of 40 ms
DIRECTION_STEP_DEG = 20.0  # a voice that moves this far while it lasts is news again


class RobotLinkError(Exception):
    """Any failure of the link to a real robot."""


class RobotUnreachable(RobotLinkError):
    """The robot did not answer at open(): the server cannot run this backend."""


class RobotDisconnected(RobotLinkError, Refusal):
    """A request refused while the robot is lost; the client sees the message as it is."""


def wrap_deg(angle: float) -> float:
    """An angle in degrees into [-180, 180)."""
    return (angle + 180.0) % 360.0 - 180.0


class LinkState:
    """The rule for lost and back (module docstring), without I/O: fed the transport's state, heartbeats and the
    monotonic time; `tick` decides. Facts may come from any thread; tick from one."""

    def __init__(self, lost_after_s: float = LOST_AFTER_S) -> None:
        self.lost_after_s = lost_after_s
        self.connected = False
        self.reason = "not opened"
        self._transport_up = False
        self._last_beat = -math.inf
        self._retry_at = -math.inf
        self._retry_s = RETRY_MIN_S

    def opened(self, now: float) -> None:
        """The robot answered at start-up: connected, with LOST_AFTER_S for its first heartbeat."""
        self.connected, self.reason = True, ""
        self._transport_up, self._last_beat = True, now

    def transport(self, up: bool) -> None:
        self._transport_up = up

    def heartbeat(self, now: float) -> None:
        self._last_beat = now

    def tick(self, now: float) -> str | None:
        """"lost" (now disconnected: stop everything), "resume" (the robot answers again: re-open, then call
        resumed()), or None."""
        alive = self._transport_up and now - self._last_beat < self.lost_after_s
        if self.connected and not alive:
            self.connected = False
            self.reason = ("the connection closed" if not self._transport_up else
                           f"no joint state for {self.lost_after_s:g} s")
            self._retry_at, self._retry_s = -math.inf, RETRY_MIN_S
            self._last_beat = -math.inf  # back only with a joint state that came after the loss
            return "lost"
        if not self.connected and alive and now >= self._retry_at:
            return "resume"
        return None

    def resumed(self, ok: bool, now: float) -> bool:
        """The outcome of a resume; True when the robot is back. A failed one is retried after the backoff."""
        if ok:
            self.connected, self.reason = True, ""
            return True
        self._retry_at = now + self._retry_s
        self._retry_s = min(2 * self._retry_s, RETRY_MAX_S)
        return False


class VoiceNews:
    """Which of the array's reports are news: a voice starting or stopping, or moving DIRECTION_STEP_DEG while it
    lasts (the array's estimate wanders a little at its own rate). Fed from one thread."""

    def __init__(self) -> None:
        self.speaking = False
        self.direction: float | None = None
        self._told: tuple[bool, float | None] | None = None

    def update(self, speaking: bool | None, direction: float | None) -> bool:
        """A report (None: that part unchanged); True when it is news."""
        if speaking is not None:
            self.speaking = speaking
        if direction is not None:
            self.direction = direction
        told = self._told
        news = told is None or told[0] != self.speaking or (
            self.speaking and self.direction is not None
            and (told[1] is None or abs(wrap_deg(self.direction - told[1])) >= DIRECTION_STEP_DEG))
        if news:
            self._told = (self.speaking, self.direction)
        return news


class RobotLink(Robot):
    """A real robot behind a link that can be lost. Construction does no I/O; open() (or connect(), blocking)
    reaches the robot, close() lets it go."""

    def __init__(self, url: str, model: RobotModel) -> None:
        super().__init__()
        self.url = url
        self._model = model
        self._link = LinkState()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._closed = threading.Event()
        self._watcher: threading.Thread | None = None
        self._frames = FrameMailbox()
        self._frame_seq = 0  # only the thread that puts frames counts
        self._head_arrived = HeadHistory()  # the head by the joint states' arrival (server wall clock)
        self._head_stamped = HeadHistory()  # ... by their own stamps (the robot's clock), when they carry one
        self._camera_count = 0
        self._microphone_listeners: list[Callable[[bytes, int, int], None]] = []
        self._speaker_format = (0, 0)
        self._speaker_resampler: av.AudioResampler | None = None
        self._speaker_pending = bytearray()
        self._voice = (0.0, 0.0)  # (level, monotonic time) of the newest piece of voice
        self._voice_news = VoiceNews()
        self._gesture_stop: asyncio.Event | None = None

    @classmethod
    async def create(cls, *args: Any, **kwargs: Any) -> RobotLink:
        robot = cls(*args, **kwargs)
        try:
            await robot.open()
        except BaseException:
            await robot.aclose()
            raise
        return robot

    # ---- what a backend translates ---------------------------------------------------------------------------
    @abc.abstractmethod
    def _connect(self) -> None:
        """Blocking: reach the robot and start reading it; RobotUnreachable when it does not answer."""

    @abc.abstractmethod
    def _disconnect(self) -> None:
        """Blocking, briefly: stop reading and let the robot go (also after a _connect that failed half-way)."""

    def _resume(self) -> None:
        """The robot answers again: re-open what is written on (raise to be tried again later)."""

    def _on_lost(self) -> None:
        """The robot was just lost (the watcher's thread): drop what is written on."""

    @abc.abstractmethod
    def _send_targets(self, targets: dict[str, float]) -> tuple[str, ...]:
        """Send clamped joint targets to a connected robot; the joints that did not take them."""

    @abc.abstractmethod
    def _send_voice(self, chunk: bytes) -> bool:
        """One SPEAKER_CHUNK_S piece of voice (S16LE mono, SPEAKER_RATE) to the speaker; False: dropped."""

    @abc.abstractmethod
    def _start_camera(self) -> None: ...

    @abc.abstractmethod
    def _stop_camera(self) -> None: ...

    @abc.abstractmethod
    def _start_microphone(self) -> None: ...

    @abc.abstractmethod
    def _stop_microphone(self) -> None: ...

    def _to_base(self, array_deg: float) -> float:
        """The microphone array's angle in the robot's base frame (degrees, positive left)."""
        return wrap_deg(array_deg)

    # ---- lifecycle ---------------------------------------------------------------------------------------------
    async def open(self) -> None:
        self._loop = asyncio.get_running_loop()
        await asyncio.to_thread(self.connect)

    def connect(self) -> None:
        """Blocking open() (for tools without a loop)."""
        try:
            self._connect()
        except BaseException:
            self._closed.set()
            self._disconnect()
            raise
        self._link.opened(time.monotonic())
        self._watcher = threading.Thread(target=self._watch, name=f"{self.backend}-link", daemon=True)
        self._watcher.start()

    def close(self) -> None:
        if self._closed.is_set() and self._watcher is None:
            return
        self._closed.set()
        self._loop = None  # our own closing is no news for the listeners
        self._frames.close()
        if self._watcher is not None:
            self._watcher.join(timeout=2)
            self._watcher = None
        self._disconnect()

    # ---- lost and back -----------------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self._link.connected

    @property
    def model(self) -> RobotModel:
        return self._model

    @property
    def info(self) -> dict[str, Any]:
        return {"backend": self.backend, "robot_url": self.url, "connected": self.connected}

    def _transport(self, up: bool) -> None:
        """Any thread: the transport's connection went up or down."""
        self._link.transport(up)

    def _heartbeat(self) -> None:
        """Any thread: a joint state arrived."""
        self._link.heartbeat(time.monotonic())

    def _joints_heard(self, positions: Mapping[str, float], stamp: float | None = None) -> None:
        """Any thread: a joint state arrived (the heartbeat); its head (degrees) is kept for the camera's frames, at
        `stamp` (its own, the robot's wall clock; None or 0: it has none) and at its arrival."""
        yaw, pitch = (positions.get(n) for n in self._model.part_joints("head"))
        if yaw is not None and pitch is not None:
            self._head_arrived.add(time.time(), float(yaw), float(pitch))
            if stamp:
                self._head_stamped.add(stamp, float(yaw), float(pitch))
        self._heartbeat()

    def _watch(self) -> None:
        while not self._closed.wait(WATCH_PERIOD_S):
            decision = self._link.tick(time.monotonic())
            if decision == "lost":
                log.warning("%s robot at %s is lost (%s); waiting for it", self.backend, self.url, self._link.reason)
                self._on_lost()
                self._call_soon(self._lost)
            elif decision == "resume":
                try:
                    self._resume()
                    ok = True
                except Exception as exc:  # still lost: tried again after the backoff
                    log.warning("%s robot at %s answers again but cannot be resumed yet: %s", self.backend,
                                self.url, exc)
                    ok = False
                if self._link.resumed(ok, time.monotonic()):
                    log.info("%s robot at %s is back", self.backend, self.url)
                    self._call_soon(self._tell_connection, True)

    def _lost(self) -> None:
        """On the loop: whatever waited on the robot ends now, rather than at its timeout."""
        self._speaker_pending.clear()
        if self._gesture_stop is not None:
            self._gesture_stop.set()
        self._tell_connection(False)

    def _tell_connection(self, up: bool) -> None:
        self._event_listeners(events.EventKind.RECONNECTED if up else events.EventKind.DISCONNECTED,
                              events.EventLevel.INFO if up else events.EventLevel.DANGER,
                              events.BackendLink(robot_url=self.url))
        self._connection_listeners(up)

    def _call_soon(self, fn: Callable[..., None], *args: Any) -> None:
        """Any thread: fn(*args) on the loop (nothing before open() or after close())."""
        loop = self._loop
        if loop is None:
            return
        with contextlib.suppress(RuntimeError):  # the loop has closed: nobody to tell
            loop.call_soon_threadsafe(fn, *args)

    def _event(self, kind: events.EventKind, level: events.EventLevel, detail: events.EventDetail) -> None:
        """Any thread: an event for the listeners on the loop."""
        self._call_soon(self._event_listeners, kind, level, detail)

    def _refuse_if_disconnected(self, what: str) -> None:
        if not self.connected:
            raise RobotDisconnected(f"{what}: the robot at {self.url} is disconnected (waiting for it to come "
                                    "back); try again once it is back")

    # ---- motion ------------------------------------------------------------------------------------------------
    def set_joint_targets(self, targets: Mapping[str, float]) -> ClampReport:
        clamped, report = clamp_command(self._model, targets)
        ignored = tuple(clamped) if not self.connected else self._send_targets(clamped)
        return dataclasses.replace(report, ignored=ignored) if ignored else report

    async def play_gesture(self, gesture: Gesture, speed: float = 1.0) -> GestureResult:
        """The server's gestures (its files, recordings) are streamed as joint commands, waypoint by waypoint, so
        that recordings the robot does not hold play too; losing the robot stops it."""
        gesture.validate(self._model)
        if not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"gesture speed must be a positive number, got {speed!r}")
        self._refuse_if_disconnected("gesture")
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

    # ---- camera ------------------------------------------------------------------------------------------------
    def add_camera_subscriber(self) -> None:
        self._camera_count += 1
        if self._camera_count == 1:
            self._start_camera()

    def remove_camera_subscriber(self) -> None:
        if self._camera_count == 0:
            return
        self._camera_count -= 1
        if self._camera_count == 0:
            self._stop_camera()

    def _put_jpeg(self, jpeg: bytes, width: int, height: int, stamp: float | None = None,
                  arrived: tuple[float, float] | None = None) -> None:
        """The camera's thread: a new frame for the waiters, with the head's pose when it was taken. `stamp`: the
        frame's own (the robot's wall clock; None or 0: it has none); `arrived`: (monotonic, wall) when it came,
        if earlier than now (before a conversion)."""
        mono, wall = arrived or (time.monotonic(), time.time())
        pose = self._head_stamped.at(stamp) if stamp and len(self._head_stamped) else None
        if pose is None:
            pose = self._head_arrived.at(wall)
        self._frame_seq += 1
        self._frames.put(CameraFrame(jpeg, width, height, self._frame_seq, mono, wall, pose=pose))

    def latest_frame(self) -> CameraFrame | None:
        return self._frames.newest

    async def next_frame(self, after_seq: int = 0, timeout: float | None = None) -> CameraFrame | None:
        return await self._frames.next(after_seq, timeout)

    def camera_closed(self) -> bool:
        return self._frames.closed

    # ---- microphone --------------------------------------------------------------------------------------------
    def listen(self, listener: Callable[[bytes, int, int], None]) -> Callable[[], None]:
        """The microphone is read only while someone listens."""
        listeners = self._microphone_listeners
        listeners.append(listener)
        if len(listeners) == 1:
            self._start_microphone()

        def stop() -> None:
            if listener in listeners:
                listeners.remove(listener)
                if not listeners:
                    self._stop_microphone()

        return stop

    def _heard(self, pcm: bytes, rate: int, channels: int) -> None:
        """Any thread: a piece of what the microphone hears, for the listeners on the loop."""
        if pcm:
            self._call_soon(self._hear, pcm, rate, channels)

    def _hear(self, pcm: bytes, rate: int, channels: int) -> None:
        for listener in tuple(self._microphone_listeners):
            try:
                listener(pcm, rate, channels)
            except Exception:
                log.exception("a microphone listener failed")

    def _heard_voice(self, speaking: bool | None, array_deg: float | None) -> None:
        """The array's thread: its speaking flag and/or angle (None: unchanged); news goes to the server."""
        news = self._voice_news
        if not news.update(speaking, array_deg):
            return
        direction = None if news.direction is None else self._to_base(news.direction)
        activity = VoiceActivity(news.speaking, direction, time.monotonic())
        self._event(events.EventKind.VOICE_ACTIVITY, events.EventLevel.INFO,
                    events.VoiceActivity(activity=news.speaking, direction_deg=news.direction))
        self._call_soon(self._voice_activity, activity)

    # ---- the operator's voice ----------------------------------------------------------------------------------
    def play_voice(self, pcm: bytes, sample_rate: int, channels: int) -> None:
        """Resampled to SPEAKER_RATE mono and sent in SPEAKER_CHUNK_S pieces; dropped while the robot is lost."""
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
            if not self._send_voice(chunk):
                self._speaker_pending.clear()
                return

    @property
    def voice_level(self) -> float:
        return held_level(self._voice, time.monotonic())
