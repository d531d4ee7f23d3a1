"""LuxAI's QTrobot API on the bus: the topics and services a real QTrobot's rosbridge exposes, served by a Robot.

An existing QTrobot script (roslibpy, roslibjs) written against `/qt_robot/*` works against the stand-in
unchanged. Every command goes through the Robot interface, which clamps; a clamp or an ignored joint is published
on `/vr_teleop/clamps` and reported to the sender as a status warning, never hidden.

A client that commands a part here (head, arms, a gesture's parts, the face by an emotion, the voice by speech) owns
it in the arbiter (core/ownership.py) while the command runs and the arbiter's client grace after: the robot's autonomy keeps off it.
The server's own features (autonomy's proposals, the menus when autonomy selects) claim nothing this way.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import itertools
import logging
import time
from collections.abc import Callable
from typing import Any

from client_protocol import names
from client_protocol.errors import Refusal
from client_protocol.events import EventKind, GestureRecording
from client_protocol.vocabulary import Owner, Part
from simclock import WALL, Clock

from ..core.bus import SERVER_NODE, Bus, BusError, Published
from ..core.events import declare_event_topic, publish_event
from ..core.ownership import Ownership
from ..core.tasks import cancel_and_wait, every
from ..robot.gestures import GestureLibrary, GestureRecorder, check_save_name
from ..robot.interface import ClampReport, Gesture, MotorMode, Robot
from .speech import Speaker

log = logging.getLogger(__name__)

class LuxaiApi:
    def __init__(self, bus: Bus, robot: Robot, gestures: GestureLibrary, speaker: Speaker,
                 joint_state_hz: float = 30.0, clock: Clock = WALL, owners: Ownership | None = None) -> None:
        self.bus = bus
        self.owners = owners or Ownership(robot.model.parts)  # a playing gesture owns the parts it moves
        self._plays = itertools.count(1)
        self.clock = clock  # times the gesture recorder's samples
        self.robot = robot
        self.gestures = gestures
        self.speaker = speaker
        self.recorder = GestureRecorder(robot.model)
        self._record_task: asyncio.Task[None] | None = None
        self._recorded: tuple[Gesture, tuple[str, ...]] | None = None  # stopped, not yet saved
        self.gestures_changed: list[Callable[[], None]] = []  # e.g. the menus' play list
        self.joint_state_period = 1.0 / joint_state_hz
        self._tasks: set[asyncio.Task[Any]] = set()
        self._joint_task: asyncio.Task[None] | None = None
        self._camera_task: asyncio.Task[None] | None = None

    # ---- lifetime -----------------------------------------------------------------------------------------------
    def start(self) -> None:
        bus = self.bus
        for topic, part in names.COMMAND_TOPIC_PARTS.items():
            bus.declare_topic(topic, "std_msgs/Float64MultiArray", persistent=True)
            bus.subscribe(SERVER_NODE, topic, None, lambda p, part=part: self._on_part_command(part, p))
        bus.declare_topic(names.JOINT_STATE_TOPIC, "sensor_msgs/JointState", persistent=True)
        bus.declare_topic(names.CLAMP_TOPIC, "vr_teleop_msgs/Clamp", persistent=True)
        camera = bus.declare_topic(names.CAMERA_TOPIC, "sensor_msgs/CompressedImage", persistent=True, queue_bound=1)
        camera.on_subscriber_count = self._on_camera_watchers
        bus.declare_topic(names.CAPTURE_POSE_TOPIC, "vr_teleop_msgs/CapturePose", persistent=True, queue_bound=4)
        declare_event_topic(bus)  # gesture recording starts and stops (the operator's HUD shows it)

        for name, handler in ((names.EMOTION_SHOW_SERVICE, self._on_emotion_topic),
                              (names.SPEECH_SAY_SERVICE, self._on_speech_topic),
                              (names.GESTURE_PLAY_SERVICE, self._on_gesture_topic)):
            bus.declare_topic(name, "std_msgs/String", persistent=True)
            bus.subscribe(SERVER_NODE, name, None, handler)

        bus.provide(names.EMOTION_SHOW_SERVICE, "qt_robot_interface/emotion_show", self._emotion_show)
        bus.provide(names.SPEECH_SAY_SERVICE, "qt_robot_interface/speech_say", self._speech_say)
        bus.provide(names.SPEECH_STOP_SERVICE, "qt_robot_interface/speech_stop", self._speech_stop)
        bus.provide(names.SPEECH_CONFIG_SERVICE, "qt_robot_interface/speech_config", self._speech_config)
        bus.provide(names.GESTURE_RECORD_SERVICE, "qt_gesture_controller/gesture_record", self._gesture_record)
        bus.provide(names.GESTURE_SAVE_SERVICE, "qt_gesture_controller/gesture_save", self._gesture_save)
        bus.provide(names.GESTURE_PLAY_SERVICE, "qt_gesture_controller/gesture_play", self._gesture_play)
        bus.provide(names.GESTURE_LIST_SERVICE, "qt_gesture_controller/gesture_list", self._gesture_list)
        bus.provide(names.GESTURE_STOP_SERVICE, "qt_gesture_controller/gesture_stop", self._gesture_stop)
        bus.provide(names.MOTORS_HOME_SERVICE, "qt_motors_controller/home", self._home)
        bus.provide(names.MOTORS_CONTROL_MODE_SERVICE, "qt_motors_controller/set_control_mode", self._control_mode)
        self._joint_task = asyncio.ensure_future(self._publish_joint_states())

    async def stop(self) -> None:
        self.recorder.cancel()
        self.owners.close()
        await cancel_and_wait(self._joint_task, self._camera_task, self._record_task, *self._tasks)

    def _spawn(self, coro: Any) -> None:
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    # ---- joint commands -----------------------------------------------------------------------------------------
    def _on_part_command(self, part: str, published: Published) -> None:
        with self.owners.commanding(published.sender, (part,)):
            self._command_part(part, published)

    def _command_part(self, part: str, published: Published) -> None:
        try:
            # a plain dict when validated from a client or a feature: no model built for the one field read
            data = published.data["data"]
            report = self.robot.set_part_targets(part, data)
        except (ValueError, KeyError) as exc:
            self.bus.report(published.sender, "error", f"{published.topic}: {exc}")
            return
        self.publish_clamp(published.topic, report, published.sender)

    def publish_clamp(self, source: str, report: ClampReport, sender: str | None = None) -> None:
        """Makes a clamped or ignored command visible: on /vr_teleop/clamps, and to the sender as a warning."""
        if report.ok:
            return
        self.bus.publish(names.CLAMP_TOPIC, {
            "header": {"stamp": self.bus.registry.now()}, "source": source,
            "joints": [c.name for c in report.clamped], "requested": [c.requested for c in report.clamped],
            "applied": [c.applied for c in report.clamped], "ignored": list(report.ignored)})
        if sender is not None:
            self.bus.report(sender, "warning", f"{source}: {report.describe()}")

    async def _home(self, request: Any) -> dict[str, Any]:
        parts = self._parts(request.parts)
        with self.owners.commanding(Bus.caller(), tuple(parts)):
            for part, report in self.robot.home(parts).items():
                self.publish_clamp(f"/qt_robot/motors/home {part}", report)
        return {"status": True}

    async def _control_mode(self, request: Any) -> dict[str, Any]:
        try:
            mode = MotorMode(request.mode)
        except ValueError:
            raise BusError(f"mode {request.mode} is not one of M_ON=0, M_OFF=1, M_BREAK=2") from None
        self.robot.set_control_mode(self._parts(request.parts), mode)
        return {"status": True}

    def _parts(self, parts: list[str]) -> list[str]:
        known = tuple(self.robot.model.parts)
        unknown = [p for p in parts if p not in known]
        if unknown:
            raise BusError(f"unknown part(s) {', '.join(unknown)}; parts are {', '.join(known)}")
        return list(parts) or list(known)

    # ---- joint states -------------------------------------------------------------------------------------------
    async def _publish_joint_states(self) -> None:
        order = self.robot.model.alphabetical_names

        def publish() -> None:
            state = self.robot.joint_state().reordered(order)
            secs = int(state.stamp_wall)
            self.bus.publish(names.JOINT_STATE_TOPIC, {
                "header": {"stamp": {"secs": secs, "nsecs": int((state.stamp_wall - secs) * 1e9)}},
                "name": list(state.names), "position": list(state.positions), "velocity": list(state.velocities),
                "effort": list(state.efforts)})

        await every(self.joint_state_period, publish, "joint states: publishing")

    # ---- camera -------------------------------------------------------------------------------------------------
    def _on_camera_watchers(self, count: int) -> None:
        """Frames are rendered only while someone watches."""
        if count > 0 and self._camera_task is None:
            self._camera_task = asyncio.ensure_future(self._pump_camera())
        elif count == 0 and self._camera_task is not None:
            self._camera_task.cancel()  # its live_frames() gives the camera back
            self._camera_task = None

    async def _pump_camera(self) -> None:
        async with contextlib.aclosing(self.robot.live_frames()) as frames:
            async for frame in frames:
                if self._camera_task is not asyncio.current_task():
                    break  # cancelled: Python 3.11's wait_for can swallow a cancel that meets a frame's arrival
                secs = int(frame.stamp_wall)
                header = {"seq": frame.seq % 2**32, "frame_id": names.CAMERA_FRAME_ID,
                          "stamp": {"secs": secs, "nsecs": int((frame.stamp_wall - secs) * 1e9)}}
                if frame.pose is not None:  # first: a client has the pose when the frame comes
                    self.bus.publish(names.CAPTURE_POSE_TOPIC, {
                        "header": header, "head_yaw": frame.pose.yaw, "head_pitch": frame.pose.pitch,
                        "stamp_gap": frame.pose.gap_s, "source": frame.pose.source})
                self.bus.publish(names.CAMERA_TOPIC, {"header": header, "format": "jpeg", "data": frame.jpeg})

    # ---- face, speech, gestures ---------------------------------------------------------------------------------
    def _show(self, name: str) -> None:
        try:
            self.robot.show_emotion(name)
        except ValueError as exc:
            raise BusError(str(exc)) from None

    def _on_emotion_topic(self, published: Published) -> None:
        try:
            with self.owners.commanding(published.sender, (Part.FACE,)):
                self._show(published.data["data"])
        except Refusal as exc:  # the bus's or the robot's
            self.bus.report(published.sender, "error", f"{published.topic}: {exc}")

    async def _emotion_show(self, request: Any) -> dict[str, Any]:
        with self.owners.commanding(Bus.caller(), (Part.FACE,)):
            self._show(request.name)
        return {"status": True}

    def _on_speech_topic(self, published: Published) -> None:
        self._spawn(self._say_reporting(published))

    async def _say_reporting(self, published: Published) -> None:
        try:
            with self.owners.commanding(published.sender, (Part.VOICE,)):
                await self.speaker.say(published.data["data"])
        except Refusal as exc:  # the bus's or the robot's
            self.bus.report(published.sender, "error", f"{published.topic}: {exc}")

    async def _speech_say(self, request: Any) -> dict[str, Any]:
        with self.owners.commanding(Bus.caller(), (Part.VOICE,)):
            result = await self.speaker.say(request.message)
        return {"status": result.completed}

    async def _speech_stop(self, _request: Any) -> dict[str, Any]:
        self.speaker.stop_speaking()
        return {"status": True}

    async def _speech_config(self, request: Any) -> dict[str, Any]:
        if request.pitch < 0 or request.speed < 0:
            raise BusError("pitch and speed must be 0 (keep) or positive")
        await self.speaker.configure(request.language, request.pitch, request.speed)
        return {"status": True}

    def _gesture(self, name: str) -> Gesture:
        try:
            return self.gestures.get(name)
        except KeyError as exc:
            raise BusError(str(exc.args[0]) if exc.args else f"unknown gesture {name!r}") from None

    def gesture_names(self) -> list[str]:
        """The library's gestures, then those the robot holds itself (a QTrobot v3's files) that the library does not
        (the library's "wave" is also "QT/wave": a robot's gesture of that name is shadowed)."""
        return self.gestures.names() + [n for n in self.robot.own_gestures() if n not in self.gestures]

    def _on_gesture_topic(self, published: Published) -> None:
        name = published.data["data"]
        if name not in self.gestures and name in self.robot.own_gestures():
            self._spawn(self._play_own(name, 1.0, published.sender, published.sender))
            return
        try:
            gesture = self._gesture(name)
        except Refusal as exc:  # the bus's or the robot's
            self.bus.report(published.sender, "error", f"{published.topic}: {exc}")
            return
        self._spawn(self._play(gesture, 1.0, published.sender, published.sender))

    @contextlib.contextmanager
    def _owning(self, name: str, parts: tuple[str, ...]) -> Any:
        """The gesture owns its parts while it plays (autonomy keeps off them); a newer gesture's claim is not
        ended by an older one's end."""
        who = f"{name}#{next(self._plays)}"
        self.owners.claim(Owner.GESTURE, parts, who)
        try:
            yield
        finally:
            self.owners.release(Owner.GESTURE, parts, who)

    async def _play_own(self, name: str, speed: float, sender: str | None, by: str) -> bool:
        parts = tuple(self.robot.model.parts)  # the robot's own file: its parts unknown here
        try:
            with self.owners.commanding(by, parts), self._owning(name, parts):
                return (await self.robot.play_own_gesture(name, speed)).completed
        except Refusal as exc:
            if sender is None:
                raise
            self.bus.report(sender, "error", f"{names.GESTURE_PLAY_SERVICE} {name}: {exc}")
            return False

    async def _play(self, gesture: Gesture, speed: float, sender: str | None, by: str) -> bool:
        model = self.robot.model
        parts = tuple(dict.fromkeys(model.joint(n).part for wp in gesture.waypoints for n in wp.targets))
        with self.owners.commanding(by, parts), self._owning(gesture.name, parts):
            result = await self.robot.play_gesture(gesture, speed)
        if result.clamps or result.ignored:
            self.publish_clamp(
                f"/qt_robot/gesture/play {gesture.name}",
                ClampReport(tuple(c.name for c in result.clamps), tuple(c.requested for c in result.clamps),
                            tuple(c.applied for c in result.clamps), result.clamps, result.ignored), sender)
        return result.completed

    async def _gesture_play(self, request: Any) -> dict[str, Any]:
        speed = request.speed or 1.0  # LuxAI scripts often leave speed out (0)
        if not 0.1 <= speed <= 10:
            raise BusError(f"speed {request.speed:g} is outside 0.1..10 (1 plays as recorded)")
        by = Bus.caller()
        if request.name not in self.gestures and request.name in self.robot.own_gestures():
            return {"status": await self._play_own(request.name, speed, None, by)}
        return {"status": await self._play(self._gesture(request.name), speed, None, by)}

    async def _gesture_list(self, _request: Any) -> dict[str, Any]:
        return {"gestures": self.gesture_names()}

    async def _gesture_stop(self, _request: Any) -> dict[str, Any]:
        """Stops a recording if one runs (as LuxAI's controller does), else the playing gesture."""
        if self.recorder.recording:
            self.stop_recording()
        else:
            self.robot.stop_gesture()
        return {"status": True}

    # ---- recording ----------------------------------------------------------------------------------------------
    async def _gesture_record(self, request: Any) -> dict[str, Any]:
        # idleParts is accepted but not applied: here the operator moves the robot by explicit control, so the
        # recorded parts must stay powered.
        self.start_recording(self._parts(request.parts), wait_s=request.wait, timeout_s=request.timeout)
        return {"status": True}

    def start_recording(self, parts: list[str], wait_s: float = 0, timeout_s: float = 0) -> None:
        if self.recorder.recording:
            raise BusError("already recording; stop it (/qt_robot/gesture/stop) or save it first")
        self.recorder.start(parts)
        self._recorded = None
        self._record_task = asyncio.ensure_future(self._sample(wait_s, timeout_s))
        self._recording_changed()

    async def _sample(self, wait_s: float, timeout_s: float) -> None:
        await asyncio.sleep(wait_s)
        clock = self.clock
        end = clock.monotonic() + timeout_s if timeout_s else None
        while self.recorder.recording and (end is None or clock.monotonic() < end):
            self.recorder.sample(self.robot.joint_state(), clock.monotonic())
            await asyncio.sleep(self.recorder.period_s)
        if self.recorder.recording:  # the timeout ended it
            self.stop_recording()

    def stop_recording(self) -> None:
        """Ends the recording and keeps it for /qt_robot/gesture/save."""
        if not self.recorder.recording:
            raise BusError("not recording; start with /qt_robot/gesture/record")
        parts = self.recorder.parts
        self.recorder.sample(self.robot.joint_state(), self.clock.monotonic())
        try:
            self._recorded = (self.recorder.stop(), parts)
        except ValueError as exc:
            raise BusError(str(exc)) from None
        finally:
            if self._record_task is not None and self._record_task is not asyncio.current_task():
                self._record_task.cancel()
            self._record_task = None
            self._recording_changed()

    def _recording_changed(self) -> None:
        publish_event(self.bus, "gestures", EventKind.GESTURE_RECORDING, "info",
                      GestureRecording(recording=self.recorder.recording,
                                       parts=list(self.recorder.parts) if self.recorder.recording else []))

    @property
    def recording(self) -> bool:
        return self.recorder.recording

    async def _gesture_save(self, request: Any) -> dict[str, Any]:
        if request.path:
            raise BusError("path is not supported: recordings are saved in the server's gesture directory "
                           "(serve --gesture-dir)")
        self.save_recording(request.name)
        return {"status": True}

    def save_recording(self, name: str) -> str:
        """Saves the last recording (stopping it if it still runs) as LuxAI gesture XML; returns its name."""
        if self.recorder.recording:
            self.stop_recording()
        if self._recorded is None:
            raise BusError("nothing recorded to save; record with /qt_robot/gesture/record first")
        gesture, parts = self._recorded
        name = name or time.strftime("recording_%Y%m%d_%H%M%S", time.localtime(self.clock.time()))
        try:
            check_save_name(name)
            path = self.gestures.save(dataclasses.replace(gesture, name=name), parts)
        except (ValueError, FileExistsError) as exc:
            raise BusError(str(exc)) from None
        self._recorded = None
        log.info("recorded gesture %s saved to %s", name, path)
        for listener in list(self.gestures_changed):
            listener()
        return name
