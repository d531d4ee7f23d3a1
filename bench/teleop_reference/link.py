"""How fresh a pose stream is across a real network, and how long a silence means a stall. Pure: time passed in.

Two facts come with every head pose: when it arrived (the server's monotonic clock) and when the headset made it
(its header stamp, the client's wall clock). The clocks differ by an unknown offset, but the smallest
`arrival - stamp` seen lately is that offset plus the path's least delay, so for each pose
    late = (arrival - stamp) - min over the last `offset_window_s` of (arrival - stamp)
is how much later than the best case it came: a pose held up behind a TCP retransmission, or sent into a link
that was down, is late by that long. A silence holds the robot (the watchdog times arrivals); to resume, the
watchdog ages the newest pose from when it would have arrived on time (`effective time = arrival - late`), so a
backlog that arrives in a burst after an outage is already old and does not resume control: only poses made
recently do. (Holding on arrivals, not on stamps, keeps the server's own event-loop hiccups from holding the
robot: a pose the server was slow to read is late by its stamp, but nothing was silent.)

Stale poses: a pose whose stamp is older than the newest one taken is dropped (never replayed: unordered
transports can deliver it late). A stamp more than `clock_reset_s` behind the newest is the headset's clock
starting over (a restarted app), not a late pose: it is taken and the estimates start again.
Poses without a stamp (zero), or repeating the newest stamp, count as made on arrival.

The adaptive threshold: every accepted pose gives one sample, the silence before it (the time since the pose
before arrived); a burst after a stall gives one long sample and many short ones. The threshold is `margin` times the `quantile` of the last
`window` samples, never below the floor (the configured watchdog timeout, also the value until there are
`min_samples` samples) and never above the ceiling. Samples above the ceiling are outages, not jitter, and are
left out, so an outage never teaches the watchdog to wait longer.
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any


def stamp_seconds(msg: Mapping[str, Any] | Any) -> float | None:
    """header.stamp of a stamped message (dict or model; ROS 1 {secs, nsecs} or ROS 2 {sec, nanosec}) in seconds,
    or None when it has none (absent, or zero)."""
    if hasattr(msg, "model_dump"):
        msg = msg.model_dump()
    if not isinstance(msg, Mapping):
        return None
    header = msg.get("header")
    stamp = header.get("stamp") if isinstance(header, Mapping) else None
    if not isinstance(stamp, Mapping):
        return None
    secs = stamp.get("secs", stamp.get("sec", 0))
    nsecs = stamp.get("nsecs", stamp.get("nanosec", 0))
    if not isinstance(secs, (int, float)) or not isinstance(nsecs, (int, float)):
        return None
    value = float(secs) + float(nsecs) / 1e9
    return value if value > 0 and math.isfinite(value) else None


@dataclass(frozen=True)
class Arrival:
    accepted: bool
    effective_time: float  # when the pose would have arrived without network lateness (monotonic)
    late_s: float


class PoseLink:
    """One pose stream's network view: stale-pose filter, lateness, adaptive watchdog threshold."""

    def __init__(self, floor_s: float = 0.2, ceiling_s: float = 0.5, *, margin: float = 1.5, quantile: float = 0.99,
                 window: int = 512, min_samples: int = 30, offset_window_s: float = 10.0,
                 clock_reset_s: float = 2.0) -> None:
        if not 0 < floor_s:
            raise ValueError(f"watchdog floor must be above 0 s, got {floor_s!r}")
        self.floor_s = floor_s
        self.ceiling_s = max(ceiling_s, floor_s)  # a floor above the ceiling wins: the configured timeout is kept
        self.margin = margin
        self.quantile = quantile
        self.min_samples = min_samples
        self.offset_window_s = offset_window_s
        self.clock_reset_s = clock_reset_s
        self._samples: deque[float] = deque(maxlen=window)
        self._threshold = floor_s
        self._dirty = 0
        self.stale_dropped = 0
        self.reset()

    def reset(self) -> None:
        """Forget the clock offset and the newest stamp (a new engage, a new client). Jitter samples stay: the
        network is the same."""
        self._transits: deque[tuple[float, float]] = deque()  # (arrival, transit), transit increasing
        self._newest_stamp: float | None = None
        self._last_effective: float | None = None
        self._last_arrival: float | None = None

    @property
    def threshold_s(self) -> float:
        if self._dirty:
            self._recompute()
        return self._threshold

    def _recompute(self) -> None:
        self._dirty = 0
        n = len(self._samples)
        if n < self.min_samples:
            self._threshold = self.floor_s
            return
        k = max(1, math.ceil((1.0 - self.quantile) * n))
        high = heapq.nlargest(k, self._samples)[-1]
        self._threshold = min(max(self.margin * high, self.floor_s), self.ceiling_s)

    def arrive(self, stamp: float | None, now: float) -> Arrival:
        """A pose stamped `stamp` (seconds, or None) arriving at `now` (monotonic seconds)."""
        late = 0.0
        if stamp is not None and self._newest_stamp is not None and stamp != self._newest_stamp:
            behind = self._newest_stamp - stamp
            if 0 < behind <= self.clock_reset_s:
                self.stale_dropped += 1
                return Arrival(False, now, 0.0)
            if behind > self.clock_reset_s:
                self.reset()  # the headset's clock started over
        if stamp is not None and stamp != self._newest_stamp:
            late = self._lateness(now - stamp, now)
            self._newest_stamp = stamp
        effective = now - late
        if self._last_effective is not None:
            effective = max(effective, self._last_effective)
        if self._last_arrival is not None and now - self._last_arrival <= self.ceiling_s:
            self._samples.append(max(0.0, now - self._last_arrival))
            self._dirty += 1
        self._last_effective = effective
        self._last_arrival = now
        return Arrival(True, effective, now - effective)

    def _lateness(self, transit: float, now: float) -> float:
        """The transit minus the least transit of the last offset_window_s (a sliding-window minimum)."""
        q = self._transits
        while q and q[-1][1] >= transit:
            q.pop()
        q.append((now, transit))
        while q[0][0] < now - self.offset_window_s:
            q.popleft()
        return transit - q[0][1]
