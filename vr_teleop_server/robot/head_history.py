"""Where a real robot's head was when a camera frame was taken: a short history of its joint states' head poses,
interpolated at the frame's stamp. Sans I/O (fed stamps and angles, asked at a stamp), shared by the real
backends through robot/link.py.

A real camera's frames and joint states come on different streams at different delays, so the frame's stamp
usually falls between two joint states: the head's pose there is interpolated linearly between them (a head at
60 deg/s moves 2 degrees between two joint states at 30 Hz). Past the newest joint state (the next one has not
come yet) it is the newest, never extrapolated; before the oldest kept, the oldest. Either way `gap_s` says how far
the frame's stamp lies from the nearest joint state used.
"""

from __future__ import annotations

import bisect
import math
import threading
from collections import deque

from robot_models.types import CapturePose

KEEP = 128  # joint states kept: about 4 s at LuxAI's 30 Hz, longer than any frame waits


class HeadHistory:
    """Thread-safe: joint states added from one thread, poses asked from another (the camera's)."""

    def __init__(self, keep: int = KEEP) -> None:
        self._lock = threading.Lock()
        self._stamps: deque[float] = deque(maxlen=keep)
        self._poses: deque[tuple[float, float]] = deque(maxlen=keep)

    def __len__(self) -> int:
        return len(self._stamps)

    def add(self, stamp: float, yaw: float, pitch: float) -> None:
        """A joint state's head (degrees) at `stamp` (seconds, any clock the frames' stamps share). One stamped
        at or before the newest kept is out of order (or a repeat) and is ignored; a non-finite value too."""
        if not (math.isfinite(stamp) and math.isfinite(yaw) and math.isfinite(pitch)):
            return
        with self._lock:
            if self._stamps and stamp <= self._stamps[-1]:
                return
            self._stamps.append(stamp)
            self._poses.append((yaw, pitch))

    def clear(self) -> None:
        with self._lock:
            self._stamps.clear()
            self._poses.clear()

    def at(self, stamp: float) -> CapturePose | None:
        """The head at `stamp`, or None before any joint state."""
        with self._lock:
            stamps, poses = list(self._stamps), list(self._poses)
        if not stamps or not math.isfinite(stamp):
            return None
        i = bisect.bisect_left(stamps, stamp)
        if i == 0:
            return CapturePose(*poses[0], gap_s=stamps[0] - stamp, source="joint_states")
        if i == len(stamps):
            return CapturePose(*poses[-1], gap_s=stamp - stamps[-1], source="joint_states")
        t0, t1 = stamps[i - 1], stamps[i]
        (y0, p0), (y1, p1) = poses[i - 1], poses[i]
        f = (stamp - t0) / (t1 - t0)
        return CapturePose(y0 + f * (y1 - y0), p0 + f * (p1 - p0), gap_s=min(stamp - t0, t1 - stamp),
                           source="joint_states")
