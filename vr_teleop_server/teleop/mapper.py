"""TeleopMapper: operator poses and buttons in, per-part QTrobot joint targets out. Pure: time is passed in.

Per step and part: raw target (head angles, or arm IK of the body-model hand target) -> limits (so the filter
does not wind up beyond them) -> One Euro filter -> velocity cap (ramped) -> limits again, always last.

Joy layout (Oculus Touch, fixed, per controller on /vr/<side>/joy or similar):
    axes    [thumbstick x, thumbstick y, index trigger, grip]       grip in 0..1 is the arm's dead-man
    buttons [A or X, B or Y, thumbstick click, menu]
Both thumbsticks clicked together is the soft e-stop (configurable).

Rules:
- engage(now) needs a fresh head pose; it captures the head zero and the torso heading, starts from the
  robot's current joints (pass them; otherwise the last command, home at first), restarts the velocity ramp, and leaves both arms not following until
  their grip is pressed anew.
- Head poses silent for the watchdog threshold: everything holds (state "stalled"). The threshold adapts to the
  measured pose jitter between watchdog_timeout_s and watchdog_ceiling_s (teleop/link.py). Fresh head poses
  resume by themselves with the ramp restarted; fresh by their header stamps, so the backlog a link delivers
  after an outage does not resume (and a pose older than the newest is dropped). An arm whose controller is silent for controller_timeout_s holds alone.
- disconnect() and the e-stop hold until a new engage(). release() stops teleop (the robot keeps its pose).
- Parts that hold get no command at all; the robot keeps its last target.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

from client_protocol.vocabulary import Part
from robot_models import ArmSolver, RobotModel, load_qtrobot

from .body import SIDES, BodyModel, calibrate_forward, calibrate_t_pose, hand_point, robot_arms, shoulder_points
from .frames import Pose, check_floats, heading, pose_from_message
from .head import HeadTracker
from .link import PoseLink, stamp_seconds
from .one_euro import OneEuroFilter
from .safety import DeadMan, VelocityRamp, Watchdog, WatchdogState, cap_step, clamp_to_limits, is_fresh
from .settings import TeleopSettings

ARM_IK_TOLERANCE_M = 1e-4  # an arm's IK "reached" its target within this
AXIS_GRIP = 3
BUTTON_STICK = 2
JOY_AXES = 4
JOY_BUTTONS = 4


class TeleopError(RuntimeError):
    """An operation that cannot be done in the current state (e.g. engaging without head poses)."""


@dataclass(frozen=True)
class ArmIK:
    reached: bool
    error_m: float


@dataclass(frozen=True)
class TeleopOutput:
    """One step's result: what to send to the robot and what to report on the teleop state topic."""

    time: float
    dt: float  # seconds the velocity cap used this step (0 when nothing moved)
    state: WatchdogState
    commands: dict[str, tuple[float, ...]]  # part -> joint targets (deg) in the part's order; moving parts only
    targets: dict[str, float]  # the same, by joint name
    clamped: tuple[str, ...]  # joints whose target hit a limit this step
    velocity_limited: tuple[str, ...]  # parts whose step the velocity cap shortened
    head_following: bool
    arms_following: dict[str, bool]
    pose_age_s: dict[str, float | None]  # "head", "left", "right": time since the newest valid pose
    ramp: dict[str, float]  # part -> fraction of its velocity caps in force
    ik: dict[str, ArmIK] = field(default_factory=dict)
    watchdog_timeout_s: float = 0.0  # the adaptive threshold in force at this step

    @property
    def holding(self) -> bool:
        return self.state is not WatchdogState.ACTIVE

    def to_message(self) -> dict[str, Any]:
        """A JSON-ready summary for telemetry (e.g. /vr_teleop/teleop_state)."""
        return {
            "time": self.time, "dt": self.dt, "state": self.state.value, "holding": self.holding,
            "commands": {k: list(v) for k, v in self.commands.items()},
            "clamped": list(self.clamped), "velocity_limited": list(self.velocity_limited),
            "head_following": self.head_following, "arms_following": dict(self.arms_following),
            "pose_age_s": dict(self.pose_age_s), "ramp": dict(self.ramp),
            "ik": {k: {"reached": v.reached, "error_m": v.error_m} for k, v in self.ik.items()},
        }


@dataclass
class _Stamped:
    pose: Pose
    time: float  # arrival
    made: float | None = None  # when it would have arrived without network lateness (head poses: teleop/link.py)


@dataclass
class _Joy:
    axes: tuple[float, ...]
    buttons: tuple[int, ...]
    time: float


def _check_side(side: str) -> str:
    if side not in SIDES:
        raise ValueError(f"controller side must be 'left' or 'right', got {side!r}")
    return side


class TeleopMapper:
    """The explicit-control core. Feed it poses and Joy, call step(now) at the control rate."""

    def __init__(self, model: RobotModel | None = None, settings: TeleopSettings | None = None) -> None:
        self.settings = s = settings or TeleopSettings()
        base = model or load_qtrobot()
        try:
            self.model = base.with_velocity_caps(s.velocity_caps_deg_s) if s.velocity_caps_deg_s else base
        except KeyError as exc:
            raise ValueError(f"velocity_caps_deg_s: {exc.args[0]}") from None
        self.parts = self.model.parts
        self._arms = robot_arms(self.model)
        self._reach = s.robot_reach_m or self._arms.reach_m
        # Per-frame constants as plain floats: the step is scalar arithmetic (bench/teleop.py).
        self._solvers = {side: ArmSolver(self.model, side) for side in SIDES}
        self._robot_shoulder = {side: tuple(float(v) for v in self._arms.shoulder[side]) for side in SIDES}
        self._body: BodyModel = s.body.body_model()
        self._head = HeadTracker(s.head_yaw_scale, s.head_pitch_scale, s.yaw_wrap_hysteresis_deg, s.gimbal_margin_deg)
        self._watchdog = Watchdog(s.watchdog_timeout_s)
        self._link = PoseLink(s.watchdog_timeout_s, s.watchdog_ceiling_s, margin=s.watchdog_margin,
                              quantile=s.watchdog_quantile)
        self._deadman = {side: DeadMan(s.deadman_mode, s.grip_press_threshold, s.grip_release_threshold)
                         for side in SIDES}
        self._ramps = {part: VelocityRamp(s.ramp_duration_s, s.ramp_start_fraction) for part in self.parts}
        self._filters = {}
        for part, names in self.parts.items():
            f = s.head_filter if part == Part.HEAD else s.arm_filter
            for n in names:
                self._filters[n] = OneEuroFilter(f.min_cutoff_hz, f.beta, f.d_cutoff_hz)
        self._caps = {n: self.model.joint(n).max_velocity * s.velocity_scale for n in self.model.names}
        self._limits = {part: ([self.model.joint(n).lower for n in names], [self.model.joint(n).upper for n in names])
                        for part, names in self.parts.items()}
        self._command = self.model.home_pose()
        self._enabled = {part: True for part in self.parts}
        self._moving = {part: False for part in self.parts}  # was the part commanded on the last step
        self._head_pose: _Stamped | None = None
        self._controllers: dict[str, _Stamped | None] = {side: None for side in SIDES}
        self._joy: dict[str, _Joy | None] = {side: None for side in SIDES}
        self._ik_cache: dict[str, tuple[tuple[float, float, float], tuple[tuple[float, ...], float]]] = {}
        self._torso0 = 0.0  # torso heading at engage
        self._head0 = 0.0  # head heading at engage
        self._last_step: float | None = None

    # ----- inputs -------------------------------------------------------------------------------------------
    def parse_pose(self, msg: Mapping[str, Any] | Pose) -> Pose:
        if isinstance(msg, Pose):
            return msg
        return pose_from_message(msg, quaternion_tolerance=self.settings.quaternion_norm_tolerance)

    def on_head_pose(self, pose: Mapping[str, Any] | Pose, now: float) -> bool:
        """A headset pose (PoseStamped dict or Pose). Invalid poses raise ValueError and are not used; a pose
        stamped before the newest one taken is dropped (returns False)."""
        parsed = self.parse_pose(pose)
        arrival = self._link.arrive(None if isinstance(pose, Pose) else stamp_seconds(pose), now)
        if not arrival.accepted:
            return False
        self._head_pose = _Stamped(parsed, now, arrival.effective_time)
        return True

    @property
    def watchdog_timeout_s(self) -> float:
        """The head-pose silence after which the robot holds now (adaptive, see teleop/link.py)."""
        return self._link.threshold_s

    @property
    def stale_poses_dropped(self) -> int:
        return self._link.stale_dropped

    def on_controller_pose(self, side: str, pose: Mapping[str, Any] | Pose, now: float) -> None:
        self._controllers[_check_side(side)] = _Stamped(self.parse_pose(pose), now)

    def on_joy(self, side: str, axes: Sequence[float], buttons: Sequence[int], now: float) -> None:
        """A sensor_msgs/Joy of one Touch controller (layout in the module docstring)."""
        _check_side(side)
        ax = check_floats(axes, f"{side} joy axes")
        if len(ax) < JOY_AXES:
            raise ValueError(f"{side} joy axes: expected at least {JOY_AXES} (stick x, stick y, trigger, grip), "
                             f"got {len(ax)}")
        if len(buttons) < JOY_BUTTONS:
            raise ValueError(f"{side} joy buttons: expected at least {JOY_BUTTONS} (A/X, B/Y, stick click, menu), "
                             f"got {len(buttons)}")
        try:
            btn = tuple(int(b) for b in buttons)
        except (TypeError, ValueError):
            raise ValueError(f"{side} joy buttons: expected integers, got {list(buttons)!r}") from None
        self._joy[side] = _Joy(tuple(ax), btn, now)
        self._deadman[side].update(ax[AXIS_GRIP])
        if self.settings.estop_both_sticks and self._watchdog.engaged and self._both_sticks(now):
            self._stop(WatchdogState.ESTOPPED)

    def _both_sticks(self, now: float) -> bool:
        window = self.settings.joy_timeout_s or 1.0
        return all(
            (j := self._joy[side]) is not None and j.buttons[BUTTON_STICK] and now - j.time <= window
            for side in SIDES
        )

    # ----- modes --------------------------------------------------------------------------------------------
    @property
    def state(self) -> WatchdogState:
        return self._watchdog.state

    @property
    def engaged(self) -> bool:
        return self._watchdog.engaged

    @property
    def body(self) -> BodyModel:
        return self._body

    def pose_age(self, stream: str, now: float) -> float | None:
        """Seconds since the newest valid pose of "head", "left" or "right"; None before any."""
        stamped = self._head_pose if stream == "head" else self._controllers[_check_side(stream)]
        return self._age(stamped, now)

    def head_pose_age(self, now: float) -> float | None:
        return self.pose_age("head", now)

    def head_pose_made_age(self, now: float) -> float | None:
        """Age of the newest head pose counted from when it would have arrived without network lateness."""
        h = self._head_pose
        return None if h is None else now - (h.made if h.made is not None else h.time)

    @property
    def last_command(self) -> dict[str, float]:
        return dict(self._command)

    def engage(self, now: float, current_joints: Mapping[str, float] | None = None) -> None:
        """Start explicit control from `current_joints` (degrees, the robot's measured pose; joints not given
        start from the last command, which is the home pose before the first engage)."""
        if not is_fresh(self._head_pose and self._head_pose.time, now, self.settings.watchdog_timeout_s):
            raise TeleopError(
                f"cannot engage: no head pose in the last {self.settings.watchdog_timeout_s:g} s; the headset must "
                "stream its pose before engaging"
            )
        start = dict(self._command)
        for name, value in (current_joints or {}).items():
            self.model.joint(name)
            if not math.isfinite(value):
                raise ValueError(f"current joint {name}: {value!r} is not a number of degrees")
            start[name] = self.model.clamp(name, value)
        self._command = start
        rot = self._head_pose.pose.rotation
        self._head.set_zero(rot)
        self._head0 = self._torso0 = heading(rot)
        for dm in self._deadman.values():
            dm.reset()
        self._ik_cache.clear()
        self._moving = {part: False for part in self.parts}
        self._watchdog.engage()
        self._link.reset()
        self._last_step = now

    def release(self) -> None:
        """Stop explicit control; the robot keeps its last target."""
        self._stop(WatchdogState.RELEASED)

    def estop(self) -> None:
        """Emergency stop from outside (dashboard, service): hold until a new engage()."""
        self._stop(WatchdogState.ESTOPPED)

    def disconnect(self) -> None:
        """The operator's client went away: hold, and forget its streams; a new engage is needed."""
        self._stop(WatchdogState.DISCONNECTED)
        self._link.reset()
        self._head_pose = None
        self._controllers = {side: None for side in SIDES}
        self._joy = {side: None for side in SIDES}

    def _stop(self, reason: WatchdogState) -> None:
        self._watchdog.release(reason)
        self._head.clear()
        for dm in self._deadman.values():
            dm.drop()

    def set_part_enabled(self, part: str, enabled: bool) -> None:
        """Menu switches (head control, arm control): a disabled part holds."""
        self.model.part_joints(part)
        self._enabled[part] = bool(enabled)

    def calibrate(self, now: float, posture: Literal["t_pose", "forward"] = "t_pose") -> BodyModel:
        """Measure the operator's body from the newest head and controller poses held in `posture`."""
        timeout = max(self.settings.controller_timeout_s, self.settings.watchdog_timeout_s)
        poses = {"head": self._head_pose, **self._controllers}
        stale = [k for k, v in poses.items() if not is_fresh(v and v.time, now, timeout)]
        if stale:
            raise TeleopError(f"cannot calibrate: no recent pose from {', '.join(stale)}; track the headset and both "
                              "controllers, then calibrate")
        fn = {"t_pose": calibrate_t_pose, "forward": calibrate_forward}.get(posture)
        if fn is None:
            raise ValueError(f"calibration posture must be 't_pose' or 'forward', got {posture!r}")
        body, torso = fn(poses["head"].pose, poses["left"].pose, poses["right"].pose, self._body)
        self._body = body
        if self.engaged:
            self._torso0, self._head0 = torso, heading(poses["head"].pose.rotation)
        return body

    # ----- the control step ---------------------------------------------------------------------------------
    def _age(self, stamped: _Stamped | _Joy | None, now: float) -> float | None:
        return None if stamped is None else now - stamped.time

    def _arm_follows(self, side: str, now: float) -> bool:
        s = self.settings
        c = self._controllers[side]
        if not (self._enabled[f"{side}_arm"] and self._deadman[side].following):
            return False
        if not is_fresh(c and c.time, now, s.controller_timeout_s):
            return False
        if s.joy_timeout_s is not None and not is_fresh(self._joy[side] and self._joy[side].time, now, s.joy_timeout_s):
            self._deadman[side].drop()
            return False
        return True

    def _arm_target(self, side: str, shoulder: tuple[float, float, float], cos_torso: float, sin_torso: float,
                    scale: float) -> tuple[list[float], ArmIK] | None:
        target = hand_point(self._controllers[side].pose.xyz, shoulder, cos_torso, sin_torso, scale,
                            self._robot_shoulder[side])
        if not all(map(math.isfinite, target)):
            return None
        cached = self._ik_cache.get(side)
        if cached is not None and math.dist(cached[0], target) <= self.settings.ik_reuse_tolerance_m:
            angles, error = cached[1]
        else:
            solver = self._solvers[side]
            angles, error = solver.solve(*target, [self._command[n] for n in solver.names])
            self._ik_cache[side] = (target, (angles, error))
        return list(angles), ArmIK(error <= ARM_IK_TOLERANCE_M, error)

    def _output(self, now: float, dt: float, commands=None, clamped=(), limited=(), ik=None) -> TeleopOutput:
        commands = commands or {}
        return TeleopOutput(
            time=now, dt=dt, state=self._watchdog.state, commands=commands,
            targets={n: v for part, vals in commands.items() for n, v in zip(self.parts[part], vals)},
            clamped=tuple(clamped), velocity_limited=tuple(limited),
            head_following=Part.HEAD in commands,
            arms_following={side: f"{side}_arm" in commands for side in SIDES},
            pose_age_s={"head": self._age(self._head_pose, now),
                        **{side: self._age(self._controllers[side], now) for side in SIDES}},
            ramp={part: r.factor(now) for part, r in self._ramps.items()},
            ik=ik or {}, watchdog_timeout_s=self._watchdog.timeout_s,
        )

    def step(self, now: float) -> TeleopOutput:
        """Advance to `now` (monotonic seconds) and return the targets of the parts that move."""
        self._watchdog.timeout_s = self._link.threshold_s
        state, resumed = self._watchdog.check(self._head_pose and self._head_pose.time, now,
                                              self._head_pose and self._head_pose.made)
        if not self._watchdog.engaged:
            self._moving = {part: False for part in self.parts}
            return self._output(now, 0.0)
        if self._last_step is not None and now <= self._last_step:
            return self._output(now, 0.0)  # duplicate or out-of-order time: nothing moves
        dt = min(now - self._last_step, self.settings.max_step_dt_s) if self._last_step is not None else 0.0
        self._last_step = now
        if resumed:
            self._moving = {part: False for part in self.parts}  # restarts ramps and filters below
        if state is WatchdogState.STALLED:
            self._moving = {part: False for part in self.parts}
            return self._output(now, dt)

        head = self._head_pose.pose
        forward = head.forward
        raw: dict[str, list[float]] = {}
        ik: dict[str, ArmIK] = {}
        if self._enabled[Part.HEAD]:
            raw[Part.HEAD] = list(self._head.update_forward(*forward))
        following = [side for side in SIDES if self._arm_follows(side, now)]
        if following:  # an arm whose grip is not held needs no body model and no IK
            head_heading = math.atan2(forward[1], forward[0])
            torso = self._torso0 + self._body_follow(head_heading)
            cos_t, sin_t = math.cos(torso), math.sin(torso)
            scale = self._reach / self._body.arm_length_m
            shoulders = dict(zip(SIDES, shoulder_points(self._body, head.xyz, head_heading, torso)))
            for side in following:
                solved = self._arm_target(side, shoulders[side], cos_t, sin_t, scale)
                if solved is not None:
                    raw[f"{side}_arm"], ik[side] = solved

        commands: dict[str, tuple[float, ...]] = {}
        clamped: list[str] = []
        limited: list[str] = []
        for part, target in raw.items():
            names = self.parts[part]
            previous = [self._command[n] for n in names]
            if not self._moving[part]:  # (re)starting: ease in from where the robot is
                self._ramps[part].restart(now)
                for n, p in zip(names, previous):
                    self._filters[n].reset(p, now - dt)
            lower, upper = self._limits[part]
            target, hit = clamp_to_limits(names, target, lower, upper)
            filtered = [self._filters[n](v, now) for n, v in zip(names, target)]
            ramp = self._ramps[part].factor(now)
            capped, was_capped = cap_step(previous, filtered, [self._caps[n] * ramp for n in names], dt)
            final, hit2 = clamp_to_limits(names, capped, lower, upper)
            clamped.extend(n for n in names if n in hit or n in hit2)
            if was_capped:
                limited.append(part)
            for n, v in zip(names, final):
                self._command[n] = v
            commands[part] = tuple(final)
        self._moving = {part: part in commands for part in self.parts}
        return self._output(now, dt, commands, clamped, limited, ik)

    def _body_follow(self, head_heading: float) -> float:
        follow = self.settings.body.torso_yaw_follow
        if follow == 0.0:
            return 0.0
        return follow * math.remainder(head_heading - self._head0, 2 * math.pi)

