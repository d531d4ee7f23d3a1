"""Static poses from the study file: the tracking system of preplanned setups (perception B)."""

from __future__ import annotations

import numpy as np

from simclock import WALL, Clock

from ..studyfile import ObjectSpec


class StaticTracker:
    name = "static"

    def __init__(self, objects: dict[str, ObjectSpec], clock: Clock = WALL) -> None:
        self.clock = clock
        self._poses = {n: o.static_pose.matrix() for n, o in objects.items() if o.static_pose is not None}

    def object_pose(self, obj: str) -> tuple[np.ndarray, float] | None:
        pose = self._poses.get(obj)
        return None if pose is None else (pose, self.clock.monotonic())  # never stale

    async def start(self) -> None:
        pass

    async def stop(self) -> None:
        pass
