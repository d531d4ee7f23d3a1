"""Explicit control on the bus: the operator's headset and controller streams drive QTrobot through TeleopMapper.

One mechanism end to end: poses and Joy arrive as ordinary topic messages, the mapper turns them into joint
targets, and the targets leave as ordinary messages on LuxAI's command topics (`/qt_robot/*_position/command`),
where the robot API clamps and reports them like anyone's. Nothing reaches the robot by a back door, and a
recording of the bus shows every command teleop made.

Rules the client can rely on (README "Explicit control"):
- One holder. `/vr_teleop/control/engage` (std_srvs/SetBool, data true) makes the caller the holder; it needs a
  fresh head pose from the caller (the current head orientation becomes the robot's head zero). Engaging again while
  holding changes nothing (a rig's "take control" pressed twice must not swing the head back to the centre);
  `/vr_teleop/control/recenter` (std_srvs/Trigger, the holder only) re-zeroes the head on purpose. Another client's
  poses and Joy are refused with a status error (at most one a second per client) until the holder releases
  (engage false), is e-stopped, or disconnects.
- The mapper steps on each of the holder's head poses, so a pose turns into commands at once. A 30 Hz tick
  publishes `/vr_teleop/teleop_state` and lets the watchdog see a silent stream.
- Stalled head poses: the robot holds; fresh poses resume by themselves (ramped). A dropped holder, an e-stop
  or a lost robot backend: the robot holds until a fresh engage.
"""

from __future__ import annotations

import asyncio
import json
import logging
from collections import deque
from collections.abc import Callable
from typing import Any, Literal

from client_protocol import names
from client_protocol.events import (Calibration, EStop, EventDetail, EventKind, EventLevel, Holder, HolderBy,
                                    PartSwitch, Refused, Watchdog)
from client_protocol.vocabulary import ARMS, Owner, Part
from simclock import WALL, Clock

from ..core.bus import SERVER_NODE, Bus, BusError, Published
from ..core.events import declare_event_topic, publish_event
from ..core.ownership import Ownership
from ..core.tasks import cancel_and_wait
from ..media.link_quality import ControlLink
from ..robot.interface import Robot
from ..teleop import TeleopError, TeleopMapper, TeleopOutput, TeleopSettings, WatchdogState

log = logging.getLogger(__name__)

STATE_RATE_HZ = 30.0
REFUSAL_INTERVAL_S = 1.0  # a refused client hears about it at most this often, not 90 times a second
HOLDS_WINDOW_S = 60.0  # link_view counts the watchdog's holds over this long
WATCHDOG_KINDS = {WatchdogState.RELEASED: EventKind.WATCHDOG_RELEASED, WatchdogState.ACTIVE: EventKind.WATCHDOG_ACTIVE,
                  WatchdogState.STALLED: EventKind.WATCHDOG_STALLED,
                  WatchdogState.DISCONNECTED: EventKind.WATCHDOG_DISCONNECTED,
                  WatchdogState.ESTOPPED: EventKind.WATCHDOG_ESTOPPED}


class ExplicitControl:
    def __init__(self, bus: Bus, robot: Robot, settings: TeleopSettings | None = None,
                 clock: Clock = WALL,
                 may_override: Callable[[str], bool] = lambda caller: False,
                 operator_of: Callable[[str], str] = lambda owner: owner,
                 operator_online: Callable[[str, str], bool] = lambda operator, gone: False,
                 owners: Ownership | None = None) -> None:
        self.bus = bus
        self.robot = robot
        self.mapper = TeleopMapper(robot.model, settings)
        self.clock = clock
        self.holder: str | None = None
        self._ever_engaged = False
        self._head_sender: str | None = None  # who sent the newest head pose the mapper holds
        self._last_output: TeleopOutput | None = None
        self._last_summary: tuple[Any, ...] | None = None
        self._last_refusal: dict[str, float] = {}
        self._robot_connected = True
        self._tick_task: asyncio.Task[None] | None = None
        self._holds: deque[float] = deque()  # when the watchdog held (stalled), for link_view
        self.may_override = may_override  # whether a caller may take control from its holder
        # Control is held by an operator, which may use several connections (one per ROS# component):
        # operator_of(owner) names it; operator_online(operator, gone) says whether it keeps another connection.
        self.operator_of = operator_of
        self.operator_online = operator_online
        # who moves each part (core/ownership.py): the holder owns the parts they follow, from engage to release
        self.owners = owners or Ownership(robot.model.parts)
        self._parts_on = {part: True for part in robot.model.parts}

    # ---- lifetime -----------------------------------------------------------------------------------------------
    def start(self) -> None:
        bus = self.bus
        declare_event_topic(bus)
        bus.declare_topic(names.TELEOP_STATE_TOPIC, "vr_teleop_msgs/TeleopState", persistent=True)
        bus.declare_topic(names.HEAD_POSE_TOPIC, "geometry_msgs/PoseStamped", persistent=True)
        bus.subscribe(SERVER_NODE, names.HEAD_POSE_TOPIC, None, self._on_head_pose)
        for side in ("left", "right"):
            bus.declare_topic(names.CONTROLLER_POSE_TOPICS[side], "geometry_msgs/PoseStamped", persistent=True)
            bus.subscribe(SERVER_NODE, names.CONTROLLER_POSE_TOPICS[side], None,
                          lambda p, side=side: self._on_controller_pose(side, p))
            bus.declare_topic(names.JOY_TOPICS[side], "sensor_msgs/Joy", persistent=True)
            bus.subscribe(SERVER_NODE, names.JOY_TOPICS[side], None, lambda p, side=side: self._on_joy(side, p))
        bus.provide(names.ENGAGE_SERVICE, "std_srvs/SetBool", self._engage_service)
        bus.provide(names.CALIBRATE_SERVICE, "std_srvs/Trigger", self._calibrate_service)
        bus.provide(names.RECENTER_SERVICE, "std_srvs/Trigger", self._recenter_service)
        bus.provide(names.HEAD_SERVICE, "std_srvs/SetBool", lambda r: self._part_service("head", (Part.HEAD,), r))
        bus.provide(names.ARMS_SERVICE, "std_srvs/SetBool", lambda r: self._part_service("arms", ARMS, r))
        bus.provide(names.ESTOP_SERVICE, "std_srvs/Trigger", self._estop_service)
        bus.owner_dropped.append(self._on_owner_dropped)
        self._tick_task = asyncio.ensure_future(self._tick())

    async def stop(self) -> None:
        if self._on_owner_dropped in self.bus.owner_dropped:
            self.bus.owner_dropped.remove(self._on_owner_dropped)
        task, self._tick_task = self._tick_task, None
        await cancel_and_wait(task)

    # ---- inputs -------------------------------------------------------------------------------------------------
    def _admit(self, published: Published) -> bool:
        """Only the holder's streams count while someone holds control; others hear why, now and then."""
        sender = published.sender
        if self.holder is None or self.operator_of(sender) == self.holder:
            return True
        now = self.clock.monotonic()
        if now - self._last_refusal.get(sender, -1e9) >= REFUSAL_INTERVAL_S:
            self._last_refusal[sender] = now
            self.bus.report(sender, "error", f"{published.topic}: refused: control is held by another client "
                            f"({self.holder}); it must release control or disconnect first")
            self._event(EventKind.REFUSED, EventLevel.WARNING,
                        Refused(client=sender, topic=published.topic, holder=self.holder))
        return False

    def _on_head_pose(self, published: Published) -> None:
        if not self._admit(published):
            return
        now = self.clock.monotonic()
        try:
            if not self.mapper.on_head_pose(published.data, now):
                return  # stamped before the newest pose taken: never replayed
        except ValueError as exc:
            self.bus.report(published.sender, "error", f"{published.topic}: rejected: {exc}")
            return
        self._head_sender = self.operator_of(published.sender)
        if self.holder is not None and self._robot_connected:
            self._step(now)

    def _on_controller_pose(self, side: str, published: Published) -> None:
        if not self._admit(published):
            return
        try:
            self.mapper.on_controller_pose(side, published.data, self.clock.monotonic())
        except ValueError as exc:
            self.bus.report(published.sender, "error", f"{published.topic}: rejected: {exc}")

    def _on_joy(self, side: str, published: Published) -> None:
        if not self._admit(published):
            return
        was = self.mapper.state
        msg = published.data
        axes, buttons = msg["axes"], msg["buttons"]
        try:
            self.mapper.on_joy(side, axes, buttons, self.clock.monotonic())
        except ValueError as exc:
            self.bus.report(published.sender, "error", f"{published.topic}: rejected: {exc}")
            return
        if was is not WatchdogState.ESTOPPED and self.mapper.state is WatchdogState.ESTOPPED:
            self._event(EventKind.ESTOP, EventLevel.WARNING, EStop(by=published.sender, how="both thumbsticks"))
            self._publish_state()

    # ---- the control step ---------------------------------------------------------------------------------------
    def _step(self, now: float) -> None:
        before = self.mapper.state
        out = self.mapper.step(now)
        self._last_output = out
        for part, values in out.commands.items():
            self.bus.publish(names.PART_COMMAND_TOPICS[part], {"data": list(values)})
        if out.state is not before:
            level = EventLevel.INFO if out.state is WatchdogState.ACTIVE else EventLevel.WARNING
            if out.state is WatchdogState.STALLED:
                self._holds.append(now)
            age, made = self.mapper.head_pose_age(now), self.mapper.head_pose_made_age(now)
            self._event(WATCHDOG_KINDS[out.state], level, Watchdog(
                holder=self.holder, threshold_s=round(out.watchdog_timeout_s, 4),
                pose_age_s=None if age is None else round(age, 4),
                pose_made_age_s=None if made is None else round(made, 4)))
        self._publish_state_if_changed()

    async def _tick(self) -> None:
        period = 1.0 / STATE_RATE_HZ
        while True:
            await asyncio.sleep(period)
            try:
                self._check_robot()
                now = self.clock.monotonic()
                age = self.mapper.head_pose_age(now)
                if self.mapper.state is WatchdogState.ACTIVE and (
                        age is None or age > self.mapper.watchdog_timeout_s):
                    self._step(now)  # between head poses only the watchdog acts: a silent stream becomes a hold
                self._publish_state()
            except Exception:  # the tick must survive anything one step does
                log.exception("teleop tick failed")

    def _check_robot(self) -> None:
        connected = self.robot.connected
        if connected == self._robot_connected:
            return
        self._robot_connected = connected
        if not connected:
            self._event(EventKind.ROBOT_LOST, EventLevel.DANGER, Holder(holder=self.holder))
            if self.holder is not None:
                self.mapper.release()
                self.bus.report(self.holder, "error", "the robot backend is disconnected: the robot holds; "
                                "engage again once it is back")
        else:
            self._event(EventKind.ROBOT_BACK, EventLevel.INFO, Holder(holder=self.holder))
        self._publish_state()

    # ---- services -----------------------------------------------------------------------------------------------
    async def _engage_service(self, request: Any) -> dict[str, Any]:
        caller = self.bus.caller()
        if request.data:
            return self.engage(caller)
        return self.release(caller)

    def engage(self, caller: str) -> dict[str, Any]:
        caller = self.operator_of(caller)
        if self.holder is not None and self.holder != caller:
            raise BusError(f"control is held by another client ({self.holder}); it must release control or "
                           "disconnect first")
        if self.holder == caller and self.mapper.engaged:
            return {"success": True, "message": "control is already held by this operator; nothing changed (call "
                                                f"{names.RECENTER_SERVICE} to make your current head orientation "
                                                "straight ahead)"}
        if not self._robot_connected:
            raise BusError("the robot backend is disconnected; engage once it is back")
        if self._head_sender != caller:
            raise BusError("cannot engage: no head pose from this operator yet; stream /vr/head/pose (from any "
                           "connection of this operator), then engage")
        now = self.clock.monotonic()
        try:
            self.mapper.engage(now, self.robot.joint_state().as_dict())
        except TeleopError as exc:
            raise BusError(str(exc)) from None
        self.holder = caller
        self.owners.release(Owner.ESTOP)  # engaging again resumes after an emergency stop
        self._claim_parts()  # before the answer: no autonomous command reaches the head after it
        self._holds.clear()  # link_view counts this engagement's holds
        self._ever_engaged = True
        self._event(EventKind.ENGAGE, EventLevel.INFO, Holder(holder=caller))
        self._publish_state()
        return {"success": True, "message": "engaged: your head orientation is the robot's head zero; hold a "
                                            "grip to move that arm"}

    def release(self, caller: str = SERVER_NODE) -> dict[str, Any]:
        """Ends control; the robot keeps its pose. Only the holder (or the server itself) may release."""
        if self.holder is None:
            return {"success": True, "message": "nobody held control"}
        caller = self.operator_of(caller) if caller != SERVER_NODE else caller
        if caller not in (self.holder, SERVER_NODE) and not self.may_override(caller):
            raise BusError(f"control is held by another client ({self.holder}); only it (or a supervisor) can "
                           "release control")
        holder, self.holder = self.holder, None
        self.mapper.release()
        self._claim_parts()
        self._event(EventKind.RELEASE, EventLevel.INFO, HolderBy(holder=holder, by=caller))
        self._publish_state()
        return {"success": True, "message": "released: the robot holds its pose"}

    def estop(self, caller: str = SERVER_NODE) -> dict[str, Any]:
        """Holds the robot and takes control away from whoever holds it; anyone may stop the robot."""
        holder, self.holder = self.holder, None
        self.mapper.estop()
        self.owners.claim(Owner.ESTOP, self.owners.parts, caller)  # autonomy stops too, until engage or a level
        self._claim_parts()
        state = self.robot.joint_state().as_dict()
        for part, joints in self.robot.model.parts.items():
            # where the joints are, within the limits: the physical joints may sit a hair beyond them
            self.bus.publish(names.PART_COMMAND_TOPICS[part],
                             {"data": [self.robot.model.clamp(n, state[n]) for n in joints]})
        self._event(EventKind.ESTOP, EventLevel.DANGER, EStop(holder=holder, by=caller))
        self._publish_state()
        return {"success": True, "message": "stopped: the robot holds where it is and control is released"}

    async def _estop_service(self, _request: Any) -> dict[str, Any]:
        return self.estop(self.bus.caller())

    async def _recenter_service(self, _request: Any) -> dict[str, Any]:
        return self.recenter(self.bus.caller())

    def recenter(self, caller: str) -> dict[str, Any]:
        """The holder's current head orientation becomes straight ahead; teleop resumes from the robot's pose with
        the engage ramp, so the head eases to its new centre."""
        operator = self.operator_of(caller) if caller != SERVER_NODE else self.holder
        if not self._robot_connected:
            raise BusError("the robot backend is disconnected; engage once it is back")
        if self.holder is None or not self.mapper.engaged:
            raise BusError("cannot recenter: nobody is controlling the robot; engage first")
        if operator != self.holder:
            raise BusError(f"control is held by another client ({self.holder}); only it can recenter")
        if self._head_sender != self.holder:
            raise BusError("cannot recenter: no head pose from the operator holding control")
        try:
            self.mapper.engage(self.clock.monotonic(), self.robot.joint_state().as_dict())
        except TeleopError as exc:
            raise BusError(str(exc)) from None
        self._event(EventKind.RECENTER, EventLevel.INFO, HolderBy(holder=self.holder, by=caller))
        self._publish_state()
        return {"success": True, "message": "recentered: your current head orientation is straight ahead"}

    async def _calibrate_service(self, _request: Any) -> dict[str, Any]:
        caller = self.bus.caller()
        if self.holder is not None and caller != SERVER_NODE and self.operator_of(caller) != self.holder:
            raise BusError(f"control is held by another client ({self.holder}); only it can calibrate")
        try:
            body = self.mapper.calibrate(self.clock.monotonic())
        except TeleopError as exc:
            raise BusError(str(exc)) from None
        detail = {"shoulder_half_width_m": round(body.shoulder_half_width_m, 3),
                  "arm_length_m": round(body.arm_length_m, 3),
                  "eye_to_shoulder_drop_m": round(body.eye_to_shoulder_drop_m, 3)}
        self._event(EventKind.CALIBRATE, EventLevel.INFO, Calibration(by=caller, **detail))
        return {"success": True, "message": json.dumps(detail, sort_keys=True)}

    async def _part_service(self, what: Literal["head", "arms"], parts: tuple[Part, ...],
                            request: Any) -> dict[str, Any]:
        for part in parts:
            self.mapper.set_part_enabled(part, request.data)
            self._parts_on[part] = bool(request.data)
        self._claim_parts()
        kinds = {("head", True): EventKind.HEAD_ON, ("head", False): EventKind.HEAD_OFF,
                 ("arms", True): EventKind.ARMS_ON, ("arms", False): EventKind.ARMS_OFF}
        self._event(kinds[what, bool(request.data)], EventLevel.INFO,
                    PartSwitch(by=self.bus.caller(), part=what, enabled=bool(request.data)))
        self._publish_state()
        return {"success": True, "message": f"{what} {'follow' if request.data else 'hold'}"}

    def _on_owner_dropped(self, owner: str) -> None:
        self._last_refusal.pop(owner, None)
        operator = self.operator_of(owner)
        if self.operator_online(operator, owner):
            return  # the operator keeps another connection: nothing changes
        if self._head_sender == operator:
            self._head_sender = None
        if operator != self.holder:
            return
        self.holder = None
        self.mapper.disconnect()
        self._claim_parts()
        self._event(EventKind.WATCHDOG_DISCONNECTED, EventLevel.WARNING, Watchdog(holder=owner))
        self._publish_state()

    def _claim_parts(self) -> None:
        """The holder owns the parts they follow (a part switched off is not followed); nobody holding, none."""
        if self.holder is None:
            self.owners.release(Owner.OPERATOR)
            return
        on = [part for part, enabled in self._parts_on.items() if enabled]
        self.owners.release(Owner.OPERATOR, [part for part in self._parts_on if part not in on])
        self.owners.claim(Owner.OPERATOR, on, self.holder)

    # ---- telemetry ----------------------------------------------------------------------------------------------
    def holds(self, connection: str) -> bool:
        """Whether the connection's operator holds control (one of its connections engaged)."""
        return self.holder is not None and self.operator_of(connection) == self.holder

    def link_view(self, connection: str) -> ControlLink | None:
        """The watchdog as the connection's operator meets it, while that operator holds control (its holds since
        it engaged, over the last minute); else None."""
        if not self.holds(connection):
            return None
        now = self.clock.monotonic()
        while self._holds and now - self._holds[0] > HOLDS_WINDOW_S:
            self._holds.popleft()
        settings = self.mapper.settings
        return ControlLink(state=self.state_name(), threshold_s=self.mapper.watchdog_timeout_s,
                           floor_s=settings.watchdog_timeout_s, ceiling_s=settings.watchdog_ceiling_s,
                           holds_last_minute=len(self._holds))

    def _event(self, kind: EventKind, level: EventLevel, detail: EventDetail) -> None:
        log.info("teleop %s %s", kind, detail)
        publish_event(self.bus, "teleop", kind, level, detail)

    def state_name(self) -> str:
        if not self._robot_connected:
            return "robot_lost"
        if not self._ever_engaged and self.mapper.state is WatchdogState.RELEASED:
            return "idle"
        return self.mapper.state.value

    def _following(self) -> tuple[bool, bool, bool, tuple[str, ...], tuple[str, ...]]:
        """(head, left arm, right arm following, joints clamped, parts velocity-limited) as the state topic
        reports them: all false and empty unless the holder's teleop is active."""
        out = self._last_output
        if out is None or out.state is not WatchdogState.ACTIVE or self.holder is None:
            return False, False, False, (), ()
        return (out.head_following, out.arms_following["left"], out.arms_following["right"], out.clamped,
                out.velocity_limited)

    def _summary(self) -> tuple[Any, ...]:
        """What a client must hear about when it changes (not the pose ages, which change every time)."""
        return (self.mapper.engaged and self.holder is not None, self.state_name(), self.holder or "",
                *self._following()[:4], self._robot_connected)

    def _state_message(self) -> dict[str, Any]:
        now = self.clock.monotonic()
        head, left, right, clamped, limited = self._following()

        def age(key: str) -> float:
            value = self.mapper.pose_age(key, now)
            return -1.0 if value is None else value

        return {
            "header": {"stamp": self.bus.registry.now()},
            "engaged": self.mapper.engaged and self.holder is not None, "state": self.state_name(),
            "holder": self.holder or "",
            "head_following": head, "left_arm_following": left, "right_arm_following": right,
            "clamped": list(clamped), "velocity_limited": list(limited),
            "pose_age": age("head"), "left_pose_age": age("left"), "right_pose_age": age("right"),
            "robot_connected": self._robot_connected,
        }

    def _publish_state(self) -> None:
        self._last_summary = self._summary()
        self.bus.publish(names.TELEOP_STATE_TOPIC, self._state_message())

    def _publish_state_if_changed(self) -> None:
        """Called on every head pose: the summary is compared before any message is built."""
        if self._summary() != self._last_summary:
            self._publish_state()

