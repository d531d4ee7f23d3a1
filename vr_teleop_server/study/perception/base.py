"""The perception interface: trackers give object poses; Perception adds query points and the service."""

from __future__ import annotations

import contextlib
from typing import Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from client_protocol import names
from simclock import WALL, Clock

from ...core.bus import SERVER_NODE, Bus, BusError

from ..studyfile import ObjectSpec

BASE_FRAME = "base_link"


class Tracker(Protocol):
    """A tracking system. Poses are 4x4 in the robot's base frame (metres)."""

    name: str

    def object_pose(self, obj: str) -> tuple[np.ndarray, float] | None:
        """The newest pose of `obj` and the monotonic time it was seen at; None if never seen."""

    async def start(self) -> None: ...

    async def stop(self) -> None: ...


class Perception:
    """Trackers by name, the trial's default one, and each object's query points (poses in the object frame)."""

    def __init__(self, bus: Bus, objects: dict[str, ObjectSpec], trackers: dict[str, Tracker], default: str,
                 clock: Clock = WALL) -> None:
        self.clock = clock  # the trackers' stamps' clock
        if default not in trackers:
            raise ValueError(f"default tracker {default!r} is not among {sorted(trackers)}")
        self.bus = bus
        self.objects = objects
        self.trackers = trackers
        self.default = default

    async def start(self) -> None:
        for tracker in self.trackers.values():
            await tracker.start()
        self.bus.provide(names.PERCEPTION_QUERY_SERVICE, "vr_teleop_msgs/PerceptionQuery", self._query_service)

    async def stop(self) -> None:
        with contextlib.suppress(BusError):
            self.bus.unadvertise_service(SERVER_NODE, names.PERCEPTION_QUERY_SERVICE)
        for tracker in self.trackers.values():
            await tracker.stop()

    def query(self, obj: str, query_point: str = "", tracker: str = "") -> tuple[np.ndarray, float]:
        """(pose of the query point in the base frame, age in seconds). BusError names what is missing.

        Objects without a marker (places such as a hand-over spot) take their static pose under the trial's
        tracker; naming a tracker explicitly asks that one only."""
        spec = self.objects.get(obj)
        if spec is None:
            raise BusError(f"unknown object {obj!r}; objects: {', '.join(self.objects)}")
        name = tracker or self.default
        source = self.trackers.get(name)
        if source is None:
            raise BusError(f"unknown tracking system {name!r}; this trial has {', '.join(self.trackers)}")
        seen = source.object_pose(obj)
        if seen is None and not tracker and spec.marker is None and "static" in self.trackers:
            seen = self.trackers["static"].object_pose(obj)  # a place (a hand-over spot) carries no marker
        if seen is None:
            raise BusError(f"{name} has not seen {obj!r} yet (no marker in view, or no static pose in the study file)")
        pose, stamp = seen
        if query_point:
            point = spec.query_points.get(query_point)
            if point is None:
                raise BusError(f"object {obj!r} has no query point {query_point!r}; it has "
                               f"{', '.join(spec.query_points) or 'none'}")
            pose = pose @ point.matrix()
        return pose, max(0.0, self.clock.monotonic() - stamp)

    async def _query_service(self, req: object) -> dict[str, object]:
        pose, age = self.query(req.object, req.query_point, req.tracker)  # type: ignore[attr-defined]
        x, y, z, w = Rotation.from_matrix(pose[:3, :3]).as_quat()
        p = pose[:3, 3]
        return {"success": True, "message": "", "age": age,
                "pose": {"header": {"frame_id": BASE_FRAME},
                         "pose": {"position": {"x": p[0], "y": p[1], "z": p[2]},
                                  "orientation": {"x": x, "y": y, "z": z, "w": w}}}}
