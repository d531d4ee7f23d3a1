"""The Robot interface: the only way anything in the server moves, reads or shows things on the robot.

Units are degrees and the robot's base frame (REP 103: x forward, y left, z up), as LuxAI's standard-mode API
uses them. Joint names, order, parts and limits come from robot_models (the `model` attribute), never from
literals elsewhere.

Rules every backend keeps:
- Commands are always clamped to the joint limits, and every clamp is reported back in a ClampReport.
  A command for a joint whose motor is not ON is not applied, and is reported as ignored.
- Methods without `async` return in well under a millisecond and may be called from the event loop; the
  work they start runs in the backend's own threads. The `async` methods await real completion (speech
  finished, gesture finished) without blocking the loop. close() may block briefly: from asyncio, await aclose().
"""

from __future__ import annotations

import abc
import asyncio
import logging
import math
import threading
from collections.abc import AsyncIterator, Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from client_protocol.events import EventDetail, EventKind, EventLevel
from robot_models import RobotModel
from robot_models.types import CameraFrame, MotorMode

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class JointClamp:
    """One joint whose requested target was outside its limits."""

    name: str
    requested: float
    applied: float


@dataclass(frozen=True)
class ClampReport:
    """What happened to one command: the targets applied (joint order of the command) and what was changed."""

    names: tuple[str, ...]
    requested: tuple[float, ...]
    applied: tuple[float, ...]  # after clamping; for ignored joints, the clamped value that was NOT applied
    clamped: tuple[JointClamp, ...] = ()
    ignored: tuple[str, ...] = ()  # motor OFF or BRAKE, or the robot unreachable: the command did not move them

    @property
    def ok(self) -> bool:
        """True when every joint got exactly what was asked."""
        return not self.clamped and not self.ignored

    def describe(self) -> str:
        """A one-line account for logs and client status messages."""
        parts = [f"{c.name} {c.requested:.1f} -> {c.applied:.1f} deg (limit)" for c in self.clamped]
        if self.ignored:
            parts.append(f"ignored (motor not ON, or the robot disconnected): {', '.join(self.ignored)}")
        return "; ".join(parts) or "applied as requested"


def clamp_command(model: RobotModel, targets: Mapping[str, float]) -> tuple[dict[str, float], ClampReport]:
    """Validate and clamp joint targets against the model; the shared first step of every backend."""
    names, requested, applied, clamped = [], [], [], []
    for name, value in targets.items():
        joint = model.joint(name)  # KeyError naming the valid joints
        try:
            deg = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"joint {name}: target must be a number of degrees, got {value!r}") from None
        if not math.isfinite(deg):
            raise ValueError(f"joint {name}: target must be a finite number of degrees in "
                             f"[{joint.lower}, {joint.upper}], got {value!r}")
        out = model.clamp(name, deg)
        names.append(name)
        requested.append(deg)
        applied.append(out)
        if out != deg:
            clamped.append(JointClamp(name, deg, out))
    report = ClampReport(tuple(names), tuple(requested), tuple(applied), tuple(clamped))
    return dict(zip(names, applied)), report


def part_command(model: RobotModel, part: str, degrees: Sequence[float]) -> dict[str, float]:
    """Map a LuxAI part array ([HeadYaw, HeadPitch], [ShoulderPitch, ShoulderRoll, ElbowRoll]) onto joint names."""
    joints = model.part_joints(part)  # KeyError naming the valid parts
    values = list(degrees)
    if len(values) != len(joints):
        raise ValueError(f"part {part} takes {len(joints)} values ({', '.join(joints)}), got {len(values)}")
    return dict(zip(joints, values))


def pcm_level(pcm: bytes) -> float:
    """How loud a piece of S16LE voice is, 0..1, as a robot shows it: RMS from -50 dBFS (0) to -10 dBFS (1)."""
    samples = np.frombuffer(pcm[:len(pcm) - len(pcm) % 2], "<i2").astype(np.float32) / 32768.0
    rms = float(np.sqrt(np.mean(np.square(samples)))) if samples.size else 0.0
    return min(1.0, max(0.0, (20 * math.log10(max(rms, 1e-9)) + 50.0) / 40.0))


VOICE_HOLD_S = 0.25  # a voice level reads 0 this long after its last piece (as the stand-in's mouth closes)


def held_level(level_at: tuple[float, float], now: float) -> float:
    """A voice level (level, monotonic time it was taken) as it reads at `now`: 0 once VOICE_HOLD_S has passed."""
    level, at = level_at
    return level if now - at < VOICE_HOLD_S else 0.0


@dataclass(frozen=True)
class JointState:
    """Joint state in the model's canonical order (degrees, deg/s, N m)."""

    names: tuple[str, ...]
    positions: tuple[float, ...]
    velocities: tuple[float, ...]
    efforts: tuple[float, ...]
    stamp_monotonic: float  # for intervals
    stamp_wall: float  # for message headers

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.names, self.positions))

    def reordered(self, names: Sequence[str]) -> JointState:
        """The same state in another order, e.g. model.alphabetical_names for /qt_robot/joints/state."""
        idx = [self.names.index(n) for n in names]
        return JointState(tuple(names), tuple(self.positions[i] for i in idx), tuple(self.velocities[i] for i in idx),
                          tuple(self.efforts[i] for i in idx), self.stamp_monotonic, self.stamp_wall)


@dataclass(frozen=True)
class MotorStatus:
    name: str
    part: str
    position: float  # degrees
    temperature_c: float | None  # None: this backend cannot tell
    voltage_v: float | None
    mode: MotorMode
    source: str  # "measured" (a real robot) or "modelled" (the stand-in's thermal model)
    fault: str = ""  # what the motor reports wrong (comma-separated), "" when nothing (or the backend cannot tell)


# Why a HardwareReport has no figure for something (its `missing` values)
NO_INTERFACE = "interface"       # the robot's interface gives no way to read it
NO_READING = "no_reading"        # it can be read, but nothing has come yet (or the robot was lost before)
NOT_MODELLED = "not_modelled"    # the stand-in does not simulate it


@dataclass(frozen=True)
class HardwareReport:
    """The robot's own hardware as its backend reads it (/vr_teleop/status/robot_hardware). A figure is None where
    the backend cannot give it, and `missing` names each such figure with why (NO_INTERFACE, NO_READING,
    NOT_MODELLED), so that a panel says so rather than showing a zero."""

    source: str  # "measured" (a real robot) or "modelled" (the stand-in)
    connected: bool
    motors: int  # motors that report a temperature
    hottest_motor: str  # "" when none reports one
    motor_temperature_c: float | None  # the hottest motor's
    motor_voltage_min_v: float | None  # the lowest supply voltage a motor reports
    motor_faults: int  # motors that report a fault now
    battery_percent: float | None = None
    cpu_percent: float | None = None  # the robot's own computer
    memory_percent: float | None = None
    temperature_c: float | None = None
    missing: Mapping[str, str] = field(default_factory=dict)  # figure -> why it is None


def motors_report(motors: Sequence[MotorStatus], connected: bool, unread: str) -> HardwareReport:
    """A report from the motors' own readings; the robot's battery and computer, which `unread` says why this
    backend cannot read, are missing. A motor figure no motor gives is missing: never read (NO_READING) on a
    measured robot, not simulated (NOT_MODELLED) on the stand-in."""
    modelled = any(m.source == "modelled" for m in motors)
    no_motor = NOT_MODELLED if modelled else NO_READING
    hot = [m for m in motors if m.temperature_c is not None]
    hottest = max(hot, key=lambda m: m.temperature_c or 0.0) if hot else None
    volts = [m.voltage_v for m in motors if m.voltage_v is not None]
    missing = {figure: unread for figure in ("battery", "cpu", "memory", "temperature")}
    if hottest is None:
        missing["motor_temperature"] = no_motor
    if not volts:
        missing["motor_voltage"] = no_motor
    return HardwareReport(source="modelled" if modelled else "measured", connected=connected, motors=len(hot),
                          hottest_motor=hottest.name if hottest else "",
                          motor_temperature_c=hottest.temperature_c if hottest else None,
                          motor_voltage_min_v=min(volts) if volts else None,
                          motor_faults=sum(1 for m in motors if m.fault), missing=missing)


class FrameMailbox:
    """Hands camera frames from a backend's thread to asyncio waiters on any loop, keeping only the newest."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._newest: CameraFrame | None = None
        self._waiters: list[tuple[asyncio.AbstractEventLoop, asyncio.Future, int]] = []
        self.closed = False

    @property
    def newest(self) -> CameraFrame | None:
        with self._lock:
            return self._newest

    def put(self, frame: CameraFrame) -> None:
        """Any thread: keep `frame` and wake the waiters it is new to."""
        with self._lock:
            self._newest = frame
            ready = [(loop, fut) for loop, fut, after in self._waiters if frame.seq > after]
        for loop, fut in ready:
            self._resolve(loop, fut, frame)

    async def next(self, after_seq: int = 0, timeout: float | None = None) -> CameraFrame | None:
        """A frame newer than after_seq, or None on timeout or after close()."""
        loop = asyncio.get_running_loop()
        fut: asyncio.Future = loop.create_future()
        entry = (loop, fut, after_seq)
        with self._lock:
            if self._newest is not None and self._newest.seq > after_seq:
                return self._newest
            if self.closed:
                return None
            self._waiters.append(entry)
        try:
            return await asyncio.wait_for(fut, timeout)
        except asyncio.TimeoutError:
            return None
        finally:
            with self._lock:
                if entry in self._waiters:
                    self._waiters.remove(entry)

    def close(self) -> None:
        with self._lock:
            self.closed = True
            waiters, self._waiters = self._waiters, []
        for loop, fut, _ in waiters:
            self._resolve(loop, fut, None)

    @staticmethod
    def _resolve(loop: asyncio.AbstractEventLoop, fut: asyncio.Future, value: CameraFrame | None) -> None:
        try:
            loop.call_soon_threadsafe(lambda: fut.done() or fut.set_result(value))
        except RuntimeError:  # that loop is closed; its waiter is gone
            pass


@dataclass(frozen=True)
class Waypoint:
    time_s: float  # from the gesture's start, at speed 1
    targets: Mapping[str, float]  # joint name -> degrees


@dataclass(frozen=True)
class Gesture:
    """A timed joint trajectory (LuxAI's gesture files hold about 20 waypoints a second)."""

    name: str
    waypoints: tuple[Waypoint, ...]

    def validate(self, model: RobotModel) -> None:
        if not self.waypoints:
            raise ValueError(f"gesture {self.name!r} has no waypoints")
        last = -math.inf
        for i, wp in enumerate(self.waypoints):
            if not (math.isfinite(wp.time_s) and wp.time_s >= 0):
                raise ValueError(f"gesture {self.name!r} waypoint {i}: time must be a finite number of seconds >= 0")
            if wp.time_s < last:
                raise ValueError(f"gesture {self.name!r} waypoint {i}: times must not go backwards "
                                 f"({wp.time_s} after {last})")
            last = wp.time_s
            for name in wp.targets:
                model.joint(name)

    @property
    def duration_s(self) -> float:
        return self.waypoints[-1].time_s if self.waypoints else 0.0


@dataclass(frozen=True)
class GestureResult:
    name: str
    completed: bool  # every waypoint was sent and the robot settled on the last one
    stopped: bool  # stop_gesture() or a newer gesture cut it short
    waypoints_sent: int
    clamps: tuple[JointClamp, ...]  # every clamp along the way
    ignored: tuple[str, ...]  # joints that could not follow (motor not ON)
    final_error_deg: float | None  # largest |position - last waypoint| at the end; None if not reached there


@dataclass(frozen=True)
class StreamedWaypoints:
    """What stream_waypoints sent: how many waypoints, the clamps and ignored joints met, the last targets applied."""

    sent: int
    clamps: tuple[JointClamp, ...]
    ignored: tuple[str, ...]
    last: dict[str, float]


async def stopped_within(stop: asyncio.Event, seconds: float) -> bool:
    """True if `stop` is set within `seconds`, False when the time passes first."""
    try:
        await asyncio.wait_for(stop.wait(), seconds)
        return True
    except TimeoutError:
        return stop.is_set()


async def stream_waypoints(set_targets: Callable[[Mapping[str, float]], ClampReport], gesture: Gesture,
                           speed: float, stop: asyncio.Event) -> StreamedWaypoints:
    """Send each waypoint as joint targets at its time (divided by `speed`) on the running loop's clock, until `stop`.

    The one way a backend plays a gesture it does not hold itself (the server's files and recordings), so every
    waypoint goes through the backend's clamping and is reported like any command.
    """
    loop = asyncio.get_running_loop()
    start, sent, clamps, ignored, last = loop.time(), 0, [], {}, {}
    for wp in gesture.waypoints:
        wait = start + wp.time_s / speed - loop.time()
        if (wait > 0 and await stopped_within(stop, wait)) or stop.is_set():
            break
        report = set_targets(wp.targets)
        clamps.extend(report.clamped)
        ignored.update(dict.fromkeys(report.ignored))
        last.update(zip(report.names, report.applied))
        sent += 1
    return StreamedWaypoints(sent, tuple(clamps), tuple(ignored), last)


@dataclass(frozen=True)
class SpeechResult:
    text: str
    completed: bool  # False when stopped early
    duration_s: float
    audible: bool  # False: this backend only animates the face (no sound is produced)


@dataclass(frozen=True)
class VoiceActivity:
    """What the robot's microphone array tells of a voice: whether someone speaks, and from where.

    direction_deg: the voice's azimuth in the robot's base frame (degrees, positive to the left, 0 straight ahead),
    or None when the array gives no direction. Each backend maps its array's own angle at one boundary (the ROS 1
    robot's ReSpeaker, the v3's microphone events). who: the speaker when the backend knows it (the stand-in's
    simulated pupils), else "". stamp: the server clock's monotonic time it was heard.
    """

    speaking: bool
    direction_deg: float | None
    stamp: float
    who: str = ""


@dataclass(frozen=True)
class KnownPerson:
    """Someone a backend knows by name, and their direction from the robot's base (degrees, positive to the left)."""

    name: str
    yaw_deg: float


class Listeners:
    """Callbacks on the event loop; one that fails is logged and the others still hear."""

    def __init__(self, what: str) -> None:
        self._what = what
        self._listeners: list[Callable[..., None]] = []

    def add(self, listener: Callable[..., None]) -> Callable[[], None]:
        """Add one; the returned function removes it."""
        self._listeners.append(listener)
        return lambda: listener in self._listeners and self._listeners.remove(listener)

    def __bool__(self) -> bool:
        return bool(self._listeners)

    def __call__(self, *args: Any) -> None:
        for listener in tuple(self._listeners):
            try:
                listener(*args)
            except Exception:  # one faulty listener must not silence the others
                log.exception("a robot %s listener failed", self._what)


class Robot(abc.ABC):
    """What the server needs from a robot (the stand-in or the real QTrobot).

    Lifecycle: construction does no I/O (a real robot's backend only checks its URL); `await open()` reaches the
    robot (RobotUnreachable, robot/link.py, when it cannot); `close()` lets it go. Listeners added between the two
    hear what open() finds (an event such as camera_unavailable).
    """

    backend: str = ""  # its name in robot.backends.BACKENDS

    def __init__(self) -> None:
        self._voice_listeners = Listeners("voice activity")
        self._connection_listeners = Listeners("connection")
        self._event_listeners = Listeners("event")

    async def open(self) -> None:
        """Reach the robot. The default has nothing to reach."""

    # ------------------------------------------------------------------------------------------------ the link
    @property
    def connected(self) -> bool:
        """Whether the robot answers now; while False, commands are ignored and services refused."""
        return True

    @property
    def info(self) -> dict[str, Any]:
        """What the backend knows of the robot for /vr_teleop/robot_description's `backend` entry ({}: none)."""
        return {}

    def on_connection_changed(self, listener: Callable[[bool], None]) -> Callable[[], None]:
        """listener(connected) on the event loop when the robot is lost or back, until the returned function is
        called."""
        return self._connection_listeners.add(listener)

    def on_event(self, listener: Callable[[EventKind, EventLevel, EventDetail], None]) -> Callable[[], None]:
        """listener(kind, level, detail) on the event loop for what the backend reports (the kinds of source
        `backend` in client_protocol.events.KINDS: disconnected, reconnected, motor_error, voice_activity,
        camera_unavailable...; the detail is the kind's model), until the returned function is called."""
        return self._event_listeners.add(listener)

    @property
    @abc.abstractmethod
    def model(self) -> RobotModel:
        """Joint names, order, parts, limits and velocity caps of this robot."""

    # ------------------------------------------------------------------------------------------------ motion
    @abc.abstractmethod
    def set_joint_targets(self, targets: Mapping[str, float]) -> ClampReport:
        """Command joints by name (degrees). Clamped to limits; the report says what was clamped or ignored."""

    def set_part_targets(self, part: str, degrees: Sequence[float]) -> ClampReport:
        """Command one part with LuxAI's array layout ("head": [yaw, pitch]; arms: [pitch, roll, elbow])."""
        return self.set_joint_targets(part_command(self.model, part, degrees))

    @abc.abstractmethod
    def joint_state(self) -> JointState:
        """The newest joint state (canonical order)."""

    @abc.abstractmethod
    def set_control_mode(self, parts: Sequence[str], mode: MotorMode) -> None:
        """Switch the motors of whole parts ON, OFF or BRAKE. Going ON holds the current position."""

    def home(self, parts: Sequence[str] | None = None) -> dict[str, ClampReport]:
        """Send parts (default: all) to the home pose at their velocity caps."""
        model = self.model
        reports = {}
        for part in parts or tuple(model.parts):
            joints = model.part_joints(part)
            reports[part] = self.set_joint_targets({n: model.joint(n).home for n in joints})
        return reports

    @abc.abstractmethod
    def motor_status(self) -> tuple[MotorStatus, ...]:
        """Per motor position, temperature, voltage and mode (canonical order)."""

    def hardware_report(self) -> HardwareReport:
        """The robot's own hardware: what its motors report (motor_status), and, named missing, its battery and
        computer. Neither LuxAI interface gives those (the ROS 1 API has no such topic or service; the v3 SDK's
        describes the robot's type but not its state), so NO_INTERFACE is the default; a backend that reads them
        fills them."""
        return motors_report(self.motor_status(), self.connected, NO_INTERFACE)

    # ---------------------------------------------------------------------------------- face, speech, gestures
    @abc.abstractmethod
    def show_emotion(self, name: str) -> None:
        """Show an emotion ("happy" or "QT/happy"); ValueError names the valid ones."""

    @abc.abstractmethod
    async def say(self, text: str, duration_s: float | None = None) -> SpeechResult:
        """Speak `text`; returns when speaking has finished (as LuxAI's speech/say service does). `duration_s`:
        the length of audio the server rendered for it, which a backend that only animates should follow."""

    @abc.abstractmethod
    def stop_speech(self) -> None:
        """Cut the current speech short; its say() returns completed=False. A say() that follows is never cut by
        this stop (a backend whose stop travels must let it arrive first)."""

    async def configure_speech(self, language: str, pitch: int, speed: int) -> None:
        """Set the robot's own voice as LuxAI's /qt_robot/speech/config does (empty or 0: keep). The default does
        nothing: a backend whose speech is the server's rendered voice (the stand-in) has no voice of its own."""

    @abc.abstractmethod
    async def play_gesture(self, gesture: Gesture, speed: float = 1.0) -> GestureResult:
        """Play a timed trajectory; returns when it has finished or was stopped. A new gesture stops the old."""

    @abc.abstractmethod
    def stop_gesture(self) -> None:
        """Stop the playing gesture (or the robot's own) where it is."""

    def own_gestures(self) -> tuple[str, ...]:
        """Gestures the robot itself holds and plays by name (a QTrobot v3's gesture files); the default: none."""
        return ()

    async def play_own_gesture(self, name: str, speed: float = 1.0) -> GestureResult:
        """Play one of own_gestures() on the robot; returns when it has finished or was stopped."""
        raise ValueError(f"unknown gesture {name!r}: this robot holds no gestures of its own")

    # ------------------------------------------------------------------------------------------------ camera
    @abc.abstractmethod
    def add_camera_subscriber(self) -> None:
        """Count one more viewer; frames are produced only while the count is above zero."""

    @abc.abstractmethod
    def remove_camera_subscriber(self) -> None:
        """Undo one add_camera_subscriber()."""

    def add_raw_camera_subscriber(self) -> None:
        """Count one more viewer that reads frames' raw pixels (`CameraFrame.ring`) and needs no JPEG. A backend
        whose frames come as JPEG anyway (a real camera's topic) counts it as any viewer."""
        self.add_camera_subscriber()

    def remove_raw_camera_subscriber(self) -> None:
        self.remove_camera_subscriber()

    @abc.abstractmethod
    def latest_frame(self) -> CameraFrame | None:
        """The newest frame, or None if none was produced yet (check its stamps for age)."""

    def camera_closed(self) -> bool:
        """Whether the camera has closed for good (the backend closed): no frame will come any more."""
        return False

    @abc.abstractmethod
    async def next_frame(self, after_seq: int = 0, timeout: float | None = None) -> CameraFrame | None:
        """Wait (without blocking the loop) for a frame newer than after_seq; None on timeout or once closed."""

    async def live_frames(self, jpeg: bool = True) -> AsyncIterator[CameraFrame]:
        """Each new frame, watching the camera for as long as the iteration lasts; with `jpeg` False, frames may
        come without their JPEG (when the backend has their raw pixels: `CameraFrame.ring`), which saves the
        compression when no one else wants it.

        The newest kept frame is skipped: it may be from when the camera last ran, not what the robot sees now.
        Iterate inside contextlib.aclosing() so that the camera is given back as soon as the loop ends.
        """
        latest = self.latest_frame()
        seq = latest.seq if latest is not None else 0
        add, remove = ((self.add_camera_subscriber, self.remove_camera_subscriber) if jpeg else
                       (self.add_raw_camera_subscriber, self.remove_raw_camera_subscriber))
        add()
        try:
            while True:
                frame = await self.next_frame(seq, timeout=1.0)
                if frame is not None:
                    seq = frame.seq
                    if frame.jpeg or not jpeg:  # one drawn before this iteration asked for JPEG is skipped
                        yield frame
                elif self.camera_closed():  # no frame will ever come: end, rather than poll a closed camera
                    return
        finally:
            remove()

    # ------------------------------------------------------------------------------------------------ microphone
    def listen(self, listener: Callable[[bytes, int, int], None]) -> Callable[[], None]:
        """Hear what the robot's microphone hears: listener(pcm S16LE, sample rate, channels) is called on the event
        loop with each piece, from now until the returned function is called (the microphone may be read only while
        someone listens). The default hears nothing: a backend without a microphone stream (the stand-in's
        classroom is synthesised by the media mixer instead)."""
        return lambda: None

    # ------------------------------------------------------------------------------------------------ hearing
    def on_voice_activity(self, listener: Callable[[VoiceActivity], None]) -> Callable[[], None]:
        """Call listener(activity) on the event loop whenever the robot's microphone array reports a voice starting,
        stopping or moving, until the returned function is called. The default hears no voices."""
        return self._voice_listeners.add(listener)

    def _voice_activity(self, activity: VoiceActivity) -> None:
        """For backends, on the event loop: hand a voice report to every listener."""
        self._voice_listeners(activity)

    def known_people(self) -> tuple[KnownPerson, ...]:
        """The people this backend can tell apart by where they are: the stand-in's simulated pupils (their names
        are their faces' track ids, and what its microphone array names as `VoiceActivity.who`). A real robot
        knows nobody: its faces are tracks, named by number until someone renames them."""
        return ()

    # ------------------------------------------------------------------------------------------------ voice
    def play_voice(self, pcm: bytes, sample_rate: int, channels: int) -> None:
        """Play a piece of the operator's voice (PCM S16LE) through the robot. Called on the loop: must return at
        once. The default plays nothing (a backend without an audio path); the stand-in moves its mouth; the real
        robot gets it on its speaker topic."""

    @property
    def voice_level(self) -> float:
        """How loud the voice the robot plays is right now, 0..1, as the robot shows it (0: silent, or no
        audio path)."""
        return 0.0

    # ------------------------------------------------------------------------------------------------ lifecycle
    @abc.abstractmethod
    def close(self) -> None:
        """Stop the backend's threads and connections. May block briefly."""

    async def aclose(self) -> None:
        await asyncio.to_thread(self.close)
