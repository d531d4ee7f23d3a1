"""Recording a gesture from the robot's joint states."""

from __future__ import annotations

import math
from collections.abc import Sequence

from robot_models import RobotModel

from ..interface import Gesture, JointState, Waypoint

RECORD_RATE_HZ = 20.0  # LuxAI records gestures at about 20 waypoints a second


class GestureRecorder:
    """Turns a stream of joint states into a Gesture, keeping about `rate_hz` samples a second.

    Pure: it never reads the robot or the clock itself. The caller passes each JointState (e.g. from an asyncio
    task polling robot.joint_state()); times come from its stamp_monotonic, or from `t` when given, and the
    gesture starts at 0. A sample is kept when it comes at least 3/4 of a period after the last one kept, so a
    caller polling at the rate keeps every sample despite a quarter period of jitter, and one polling faster
    (e.g. at the 30 or 60 Hz of a joint-state stream) is thinned to about the rate. The newest state at stop()
    is always kept, so the gesture ends where the robot did.
    """

    MIN_SPACING = 0.75  # of a period, between kept samples

    def __init__(self, model: RobotModel, rate_hz: float = RECORD_RATE_HZ) -> None:
        if not (math.isfinite(rate_hz) and 0 < rate_hz <= 1000):
            raise ValueError(f"rate_hz must be in (0, 1000], got {rate_hz!r}")
        self.model = model
        self.period_s = 1.0 / rate_hz
        self._joints: tuple[str, ...] | None = None
        self._parts: tuple[str, ...] = ()
        self._name = "recording"
        self._t0 = 0.0
        self._last_kept_t = -math.inf
        self._kept: list[Waypoint] = []
        self._pending: Waypoint | None = None  # newest state not kept (yet)
        self._last_t = -math.inf

    @property
    def recording(self) -> bool:
        return self._joints is not None

    @property
    def parts(self) -> tuple[str, ...]:
        """The parts of the current (or last) recording; pass them to GestureLibrary.save()."""
        return self._parts

    @property
    def sample_count(self) -> int:
        return len(self._kept) + (self._pending is not None)

    def start(self, parts: Sequence[str], name: str = "recording") -> None:
        if self.recording:
            raise RuntimeError("already recording; stop() or cancel() the current recording first")
        parts = tuple(dict.fromkeys(parts))
        if not parts:
            raise ValueError(f"record at least one part; valid parts: {', '.join(self.model.parts)}")
        self._joints = tuple(n for p in parts for n in self.model.part_joints(p))  # KeyError naming valid parts
        self._parts, self._name = parts, name
        self._kept, self._pending, self._last_kept_t, self._last_t = [], None, -math.inf, -math.inf

    def sample(self, state: JointState, t: float | None = None) -> bool:
        """Offer one joint state; True if it was kept as a waypoint. Repeated stamps are ignored."""
        if self._joints is None:
            raise RuntimeError("sample() called while not recording; call start(parts) first")
        now = state.stamp_monotonic if t is None else float(t)
        if not math.isfinite(now):
            raise ValueError(f"sample time must be finite, got {now!r}")
        if now == self._last_t:
            return False
        if now < self._last_t:
            raise ValueError(f"sample time {now} is earlier than the previous {self._last_t}; pass times from one "
                             "monotonic clock (time.monotonic())")
        positions = state.as_dict()
        missing = [n for n in self._joints if n not in positions]
        if missing:
            raise ValueError(f"joint state lacks {', '.join(missing)}; it must cover parts {', '.join(self._parts)}")
        if self._last_t == -math.inf:
            self._t0 = now
        self._last_t = now
        wp = Waypoint(now - self._t0, {n: float(positions[n]) for n in self._joints})
        if now - self._last_kept_t >= self.MIN_SPACING * self.period_s:
            self._kept.append(wp)
            self._pending = None
            self._last_kept_t = now
            return True
        self._pending = wp
        return False

    def stop(self, name: str | None = None) -> Gesture:
        """End the recording and return it; ValueError if it has fewer than 2 samples (nothing to play)."""
        if self._joints is None:
            raise RuntimeError("stop() called while not recording; call start(parts) first")
        kept = self._kept + ([self._pending] if self._pending is not None else [])
        self._joints, self._kept, self._pending = None, [], None
        if len(kept) < 2:
            raise ValueError(f"the recording has {len(kept)} sample(s); a gesture needs at least 2. Call sample() "
                             f"with the joint state while recording, for at least {self.period_s:.2f} s")
        return Gesture(name or self._name, tuple(kept))

    def cancel(self) -> None:
        """Drop the current recording, if any."""
        self._joints, self._kept, self._pending = None, [], None

