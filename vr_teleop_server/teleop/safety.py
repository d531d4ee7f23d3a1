"""What stands between a filtered target and the motors: velocity cap, ramp, joint limits, dead-man, watchdog.

Order per part and step: filter -> velocity cap (ramped) -> joint limits. Limits come last so nothing can
push a command outside them; since the previous command is always within limits, clamping can only shorten
a step, so the velocity bound survives it.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass

from robot_models import RobotModel


def cap_step(
    previous: Sequence[float], target: Sequence[float], caps_deg_s: Sequence[float], dt: float
) -> tuple[list[float], bool]:
    """Move from `previous` toward `target`, scaling the whole step so no joint exceeds cap*dt.

    The step keeps its direction (the part moves along a straight line in joint space, as Unitree's teleop
    does) and is only ever shrunk: a ratio below 1 leaves it untouched. Returns (new values, whether it was
    scaled). dt <= 0 means no time has passed: stay.
    """
    if dt <= 0.0:
        return list(previous), any(t != p for t, p in zip(target, previous))
    ratio = 0.0
    for p, t, cap in zip(previous, target, caps_deg_s):
        ratio = max(ratio, abs(t - p) / (cap * dt))
    if ratio <= 1.0:
        return list(target), False
    return [p + (t - p) / ratio for p, t in zip(previous, target)], True


def clamp_joints(model: RobotModel, names: Sequence[str], values: Sequence[float]) -> tuple[list[float], list[str]]:
    """Joint limits from the robot model; returns (clamped values, names of the joints that were clamped)."""
    joints = [model.joint(n) for n in names]
    return clamp_to_limits(names, values, [j.lower for j in joints], [j.upper for j in joints])


def clamp_to_limits(names: Sequence[str], values: Sequence[float], lower: Sequence[float], upper: Sequence[float]
                    ) -> tuple[list[float], list[str]]:
    """clamp_joints with the limits given (the control loop reads them once); a NaN is refused naming the joint."""
    out, clamped = [], []
    for name, value, lo, hi in zip(names, values, lower, upper):
        if value != value:
            raise ValueError(f"joint {name}: target is NaN; send a number of degrees in [{lo}, {hi}]")
        c = lo if value < lo else hi if value > hi else float(value)
        if c != value:
            clamped.append(name)
        out.append(c)
    return out, clamped


class VelocityRamp:
    """Caps scale linearly from `start_fraction` to 1 over `duration_s` after each (re)start."""

    __slots__ = ("duration_s", "start_fraction", "_t0")

    def __init__(self, duration_s: float = 2.0, start_fraction: float = 0.1) -> None:
        self.duration_s = duration_s
        self.start_fraction = start_fraction
        self._t0: float | None = None

    def restart(self, now: float) -> None:
        self._t0 = now

    def factor(self, now: float) -> float:
        if self._t0 is None or self.duration_s <= 0.0:
            return 1.0
        progress = min(max((now - self._t0) / self.duration_s, 0.0), 1.0)
        return self.start_fraction + (1.0 - self.start_fraction) * progress


class DeadManMode(enum.StrEnum):
    HOLD = "hold"  # the arm follows only while the grip is held; on release it stays where it is
    TOGGLE = "toggle"  # each press of the grip starts or stops following


class DeadMan:
    """One arm's clutch on its analog grip, with hysteresis so a half-pressed grip does not flicker.

    After `reset` (at engage) the arm is not following, and in hold mode a grip already held does not count:
    the operator must press anew, so engaging never makes an arm leap to wherever the hand happens to be.
    """

    __slots__ = ("mode", "press", "release", "_pressed", "_armed", "_following")

    def __init__(self, mode: DeadManMode = DeadManMode.HOLD, press: float = 0.6, release: float = 0.4) -> None:
        self.mode = DeadManMode(mode)
        self.press = press
        self.release = release
        self._pressed = False
        self._armed = True  # no grip held since reset (a grip held at reset must be let go first)
        self._following = False

    @property
    def following(self) -> bool:
        return self._following

    @property
    def pressed(self) -> bool:
        return self._pressed

    def reset(self) -> None:
        self._armed = not self._pressed
        self._following = False

    def drop(self) -> None:
        """Stop following (lost stream, e-stop); the next press starts again."""
        self.reset()

    def update(self, grip: float) -> bool:
        """Feed the grip axis (0..1); returns whether the arm follows now."""
        was = self._pressed
        if was:
            self._pressed = grip > self.release
        else:
            self._pressed = grip >= self.press
        rising = self._pressed and not was
        if not self._pressed:
            self._armed = True
        if self.mode is DeadManMode.HOLD:
            self._following = self._pressed and self._armed
        elif rising and self._armed:
            self._following = not self._following
        return self._following


class WatchdogState(enum.StrEnum):
    RELEASED = "released"  # not engaged: teleop sends nothing
    ACTIVE = "active"  # engaged and head poses are fresh
    STALLED = "stalled"  # engaged, but head poses stopped for longer than the timeout: holding
    DISCONNECTED = "disconnected"  # the operator's client went away: holding until a fresh engage
    ESTOPPED = "estopped"  # soft e-stop (both thumbsticks clicked): holding until a fresh engage


@dataclass
class Watchdog:
    """Engaged/stalled/disconnected bookkeeping for the head pose stream.

    Resume rule: after a stall, fresh head poses resume teleoperation by themselves, and the caller restarts
    the velocity ramp so the robot eases back instead of jumping. A disconnect or an e-stop needs a new engage.
    """

    timeout_s: float = 0.2
    state: WatchdogState = WatchdogState.RELEASED

    def engage(self) -> None:
        self.state = WatchdogState.ACTIVE

    def release(self, reason: WatchdogState = WatchdogState.RELEASED) -> None:
        self.state = reason

    @property
    def engaged(self) -> bool:
        return self.state in (WatchdogState.ACTIVE, WatchdogState.STALLED)

    def check(self, last_pose_time: float | None, now: float,
              last_made_time: float | None = None) -> tuple[WatchdogState, bool]:
        """Update from the age of the newest head pose; returns (state, resumed_just_now).

        A silence (no pose arrived for timeout_s) holds. Resuming also needs the newest pose to be recent by
        `last_made_time` (when it would have arrived without network lateness, teleop/link.py): a backlog
        delivered in a burst after an outage does not resume, the poses made after it do."""
        if not self.engaged:
            return self.state, False
        fresh = last_pose_time is not None and now - last_pose_time <= self.timeout_s
        if self.state is WatchdogState.ACTIVE and not fresh:
            self.state = WatchdogState.STALLED
        elif self.state is WatchdogState.STALLED and fresh and (
                last_made_time is None or now - last_made_time <= self.timeout_s):
            self.state = WatchdogState.ACTIVE
            return self.state, True
        return self.state, False


def is_fresh(last_time: float | None, now: float, timeout_s: float) -> bool:
    return last_time is not None and now - last_time <= timeout_s and math.isfinite(last_time)
