"""SimRobot: the Robot interface over the MuJoCo stand-in (sim.StandIn).

The stand-in's threads do the physics and drive its render process (sim/render_process.py: rendering and JPEG
at a lower CPU priority, out of this process's GIL); this class adds the Robot contract on top: clamp
reports, LuxAI part arrays, motor modes, speech timing, gesture streaming and asyncio-friendly camera waits.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

from robot_models import RobotModel, load_qtrobot
from sim import StandIn
from sim.pupils import PUPILS, Pupil

from ..interface import (
    CameraFrame,
    ClampReport,
    FrameMailbox,
    Gesture,
    GestureResult,
    HardwareReport,
    JointState,
    KnownPerson,
    MotorMode,
    MotorStatus,
    NOT_MODELLED,
    Robot,
    SpeechResult,
    VoiceActivity,
    clamp_command,
    motors_report,
    pcm_level,
    stopped_within,
    stream_waypoints,
)

if TYPE_CHECKING:
    from simclock import Clock

    from ...settings import ServerSettings

SETTLE_TOLERANCE_DEG = 1.0  # a gesture counts as finished when every joint is this close to its last waypoint


class SimRobot(Robot):
    """QTrobot played by the MuJoCo stand-in.

    Speech is timed from the text at `words_per_minute` and shown as a talking face; the stand-in makes no
    sound (SpeechResult.audible is False). Construction starts MuJoCo and a GL context and takes a moment:
    from asyncio, use `await SimRobot.create(...)`. Its time is the stand-in's clock (`clock=`, default the wall
    clock; a simulated one must be the running loop's, see simclock).
    """

    backend = "sim"

    def __init__(self, model: RobotModel | None = None, *, standin: StandIn | None = None,
                 words_per_minute: float = 150.0, **standin_options: Any) -> None:
        if not (math.isfinite(words_per_minute) and words_per_minute > 0):
            raise ValueError(f"words_per_minute must be a positive number, got {words_per_minute!r}")
        super().__init__()
        self._model = model or (standin.robot if standin else load_qtrobot())
        self._standin = standin or StandIn(self._model, **standin_options)
        self._owns_standin = standin is None
        self._wpm = float(words_per_minute)
        self._frames = FrameMailbox()
        self._speech_stop: asyncio.Event | None = None
        self._gesture_stop: asyncio.Event | None = None
        self._gesture_joints: tuple[str, ...] = ()
        self._closed = False
        self._listeners: list[Callable[[bytes, int, int], None]] = []
        self._standin.add_frame_listener(self._on_frame)
        self._standin.add_camera_closed_listener(self._frames.close)  # its render process died: no more frames

    @classmethod
    async def create(cls, model: RobotModel | None = None, **options: Any) -> SimRobot:
        """Build one off the event loop (MuJoCo and EGL start-up block for a fraction of a second)."""
        return await asyncio.to_thread(cls, model, **options)

    @classmethod
    def from_settings(cls, settings: ServerSettings, model: RobotModel, clock: Clock | None = None) -> SimRobot:
        """Starts MuJoCo and a GL context: call it off the event loop."""
        return cls(model, camera_width=settings.camera_width, camera_height=settings.camera_height,
                   camera_fps=settings.camera_fps, **({"clock": clock} if clock is not None else {}))

    @staticmethod
    def check_url(_url: str, _robot_id: str | None = None) -> None:
        """Any: the stand-in runs in this process, and a robot URL names nothing to it."""

    @property
    def model(self) -> RobotModel:
        return self._model

    @property
    def standin(self) -> StandIn:
        """The underlying simulation (for tests, tools and the scene's ground truth)."""
        return self._standin

    # ------------------------------------------------------------------------------------------------ motion
    def set_joint_targets(self, targets: Mapping[str, float]) -> ClampReport:
        clamped, report = clamp_command(self._model, targets)
        applied = self._standin.set_targets(clamped)
        ignored = tuple(n for n in clamped if n not in applied)
        if ignored:
            report = ClampReport(report.names, report.requested, report.applied, report.clamped, ignored)
        return report

    def joint_state(self) -> JointState:
        s = self._standin.joint_state()
        return JointState(s.names, s.positions, s.velocities, s.efforts, s.stamp_monotonic, s.stamp_wall)

    def set_control_mode(self, parts: Sequence[str], mode: MotorMode) -> None:
        mode = MotorMode(mode)
        joints = [n for part in parts for n in self._model.part_joints(part)]
        self._standin.set_motor_mode(joints, mode)

    def motor_status(self) -> tuple[MotorStatus, ...]:
        s = self._standin.joint_state()
        temps = self._standin.motor_temperatures()
        return tuple(
            MotorStatus(name=n, part=self._model.joint(n).part, position=p, temperature_c=temps[n], voltage_v=None,
                        mode=MotorMode(int(m)), source="modelled")
            for n, p, m in zip(s.names, s.positions, s.modes)
        )

    def hardware_report(self) -> HardwareReport:
        """The stand-in's simulated hardware: its motors' modelled temperatures (sim/thermal.py); it simulates no
        supply voltage, battery or computer of the robot's, and says so."""
        return motors_report(self.motor_status(), self.connected, NOT_MODELLED)

    # ---------------------------------------------------------------------------------- face, speech, gestures
    def show_emotion(self, name: str) -> None:
        short = name[3:] if name.startswith("QT/") else name
        if short not in self._model.emotions:
            raise ValueError(f"unknown emotion {name!r}; valid emotions: {', '.join(self._model.emotions)} "
                             "(optionally as QT/<name>)")
        self._standin.set_emotion(short)

    def speech_duration(self, text: str) -> float:
        """Seconds the stand-in takes to 'say' text: words at the configured rate, at least 0.3 s if any."""
        words = len(text.split())
        return 0.0 if words == 0 else max(0.3, 60.0 * words / self._wpm)

    async def say(self, text: str, duration_s: float | None = None) -> SpeechResult:
        self.stop_speech()
        duration = self.speech_duration(text) if duration_s is None else max(0.0, float(duration_s))
        stop = self._speech_stop = asyncio.Event()
        self._standin.speak(duration)
        t0 = self._standin.clock.monotonic()
        completed = False
        try:
            await asyncio.wait_for(stop.wait(), duration)
        except TimeoutError:
            completed = True
        finally:
            if self._speech_stop is stop:  # not superseded by a newer say(), whose face must keep talking
                self._speech_stop = None
                if not completed:  # stopped or cancelled
                    self._standin.speak(0.0)
        return SpeechResult(text, completed, self._standin.clock.monotonic() - t0, audible=False)

    def stop_speech(self) -> None:
        if self._speech_stop is not None:
            self._speech_stop.set()
            self._standin.speak(0.0)

    async def play_gesture(self, gesture: Gesture, speed: float = 1.0) -> GestureResult:
        gesture.validate(self._model)
        if not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"gesture speed must be a positive number, got {speed!r}")
        self.stop_gesture()
        stop = self._gesture_stop = asyncio.Event()
        joints = tuple(dict.fromkeys(n for wp in gesture.waypoints for n in wp.targets))
        self._gesture_joints = joints
        try:
            streamed = await stream_waypoints(self.set_joint_targets, gesture, speed, stop)
            final_error = None
            if not stop.is_set() and streamed.sent == len(gesture.waypoints):
                final_error = await self._settle(streamed.last, stop)
        finally:
            if self._gesture_stop is stop:
                self._gesture_stop = None
                self._gesture_joints = ()
        stopped = stop.is_set()
        completed = (not stopped and streamed.sent == len(gesture.waypoints) and not streamed.ignored
                     and final_error is not None and final_error <= SETTLE_TOLERANCE_DEG)
        return GestureResult(gesture.name, completed, stopped, streamed.sent, streamed.clamps, streamed.ignored,
                             final_error)

    async def _settle(self, targets: Mapping[str, float], stop: asyncio.Event) -> float | None:
        """Wait until the joints reach the last waypoint (or could have, at their caps); the largest error.

        The time the joints are given is the physics' own (simulated) time: on a loaded machine the physics trails
        the wall clock, and a wall-clock deadline ended the wait before the servos had moved (a gesture judged
        incomplete at 20 deg off after 1.2 s of wall time and no simulated time). The wall-clock limit is only a
        backstop for physics that has stopped."""
        state = self._standin.joint_state()
        here = dict(zip(state.names, state.positions))
        slowest = max(abs(here[n] - v) / self._model.joint(n).max_velocity for n, v in targets.items())
        clock = self._standin.clock
        deadline = state.sim_time + slowest + 1.0
        backstop = clock.monotonic() + 10 * (slowest + 1.0)
        while True:
            state = self._standin.joint_state()
            here = dict(zip(state.names, state.positions))
            error = max(abs(here[n] - v) for n, v in targets.items())
            if error <= SETTLE_TOLERANCE_DEG or state.sim_time >= deadline or clock.monotonic() >= backstop:
                return error
            if await stopped_within(stop, 0.02):
                return None

    def stop_gesture(self) -> None:
        if self._gesture_stop is not None:
            self._gesture_stop.set()
            here = self._standin.joint_positions()
            self._standin.set_targets({n: here[n] for n in self._gesture_joints})

    # ------------------------------------------------------------------------------------------------ voice
    def play_voice(self, pcm: bytes, sample_rate: int, channels: int) -> None:
        """The stand-in has no speaker: its mouth opens with the voice's level (RMS, -50..-10 dBFS to 0..1)."""
        self._standin.set_voice_level(pcm_level(pcm))

    @property
    def voice_level(self) -> float:
        return self._standin.voice_level

    # ------------------------------------------------------------------------------------------------ microphone
    def listen(self, listener: Callable[[bytes, int, int], None]) -> Callable[[], None]:
        """What the classroom's simulated pupils say (`hear`), as a real robot's microphone would give it."""
        self._listeners.append(listener)
        return lambda: listener in self._listeners and self._listeners.remove(listener)

    # ------------------------------------------------------------------------- the simulated world (SimulatedWorld)
    @property
    def pupils(self) -> tuple[Pupil, ...]:
        return PUPILS

    def hear(self, pcm: bytes, sample_rate: int, channels: int) -> None:
        """On the loop: a piece of a simulated pupil's voice reaches the microphone (sim/pupils.py)."""
        for listener in tuple(self._listeners):
            listener(pcm, sample_rate, channels)

    def report_voice(self, activity: VoiceActivity) -> None:
        self._voice_activity(activity)

    def pupil_looks(self, name: str, at_robot: bool) -> None:
        self._standin.pupil_looks(name, at_robot)

    def known_people(self) -> tuple[KnownPerson, ...]:
        """The classroom's simulated pupils, by name (sim/pupils.py)."""
        return tuple(KnownPerson(p.name, p.yaw_deg) for p in PUPILS)

    # ------------------------------------------------------------------------------------------------ camera
    def add_camera_subscriber(self) -> None:
        self._standin.start_camera()

    def remove_camera_subscriber(self) -> None:
        self._standin.stop_camera()

    def add_raw_camera_subscriber(self) -> None:
        self._standin.start_camera(jpeg=False)

    def remove_raw_camera_subscriber(self) -> None:
        self._standin.stop_camera(jpeg=False)

    def latest_frame(self) -> CameraFrame | None:
        return self._standin.latest_frame()

    async def next_frame(self, after_seq: int = 0, timeout: float | None = None) -> CameraFrame | None:
        return await self._frames.next(after_seq, timeout)

    def camera_closed(self) -> bool:
        return self._frames.closed

    def _on_frame(self, frame: CameraFrame) -> None:
        """Render thread: hand the frame to the asyncio waiters."""
        self._frames.put(frame)

    # ------------------------------------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._standin.remove_frame_listener(self._on_frame)
        self._frames.close()
        if self._owns_standin:
            self._standin.close()


