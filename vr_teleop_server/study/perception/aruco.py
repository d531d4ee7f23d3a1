"""ArUco markers on the robot's head-camera frames (OpenCV's cv2.aruco): object poses in the base frame.

Each frame is read (raw pixels from the stand-in's frame ring, or a camera's JPEG decoded) and searched in a
worker thread; the marker's pose in the camera comes from solvePnP (IPPE_SQUARE) with the robot model's
intrinsics scaled to the frame size, and the camera's pose in the base frame from forward kinematics at the joint state read with the frame. Frames taken while the head turns faster
than `max_head_speed` deg/s are skipped: the joint state and the image would not belong together.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from dataclasses import dataclass

import cv2
import numpy as np

from robot_models import RobotModel
from robot_models.kinematics import forward_kinematics
from robot_models.types import CameraFrame

from ...core.tasks import cancel_and_wait
from ...robot.interface import Robot
from ..studyfile import ObjectSpec

log = logging.getLogger(__name__)
DICTIONARY = cv2.aruco.DICT_4X4_50


@dataclass(frozen=True)
class MarkerSighting:
    id: int
    camera_from_marker: np.ndarray  # 4x4


def camera_matrix(model: RobotModel, width: int, height: int) -> np.ndarray:
    cam = model.camera
    if cam is None:
        raise ValueError("the robot model has no camera intrinsics")
    sx, sy = width / cam.width, height / cam.height
    return np.array([[cam.fx * sx, 0, cam.cx * sx], [0, cam.fy * sy, cam.cy * sy], [0, 0, 1]], float)


def gray_image(frame: CameraFrame) -> np.ndarray | None:
    """The frame in grayscale: from its raw pixels when it has them (the stand-in's frame ring: no JPEG made
    or decoded for perception), else from its JPEG; None when its ring slot was overwritten first."""
    if not frame.jpeg and frame.ring is not None:
        return frame.ring.read(frame.seq, lambda rgb: cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))
    return cv2.imdecode(np.frombuffer(frame.jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)


def detect_markers(gray: np.ndarray, k: np.ndarray, sizes: dict[int, float]) -> list[MarkerSighting]:
    """Markers of known size in a grayscale image, with their poses in the camera's optical frame."""
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX  # sub-pixel corners: depth error halves
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(DICTIONARY), params)
    corners, ids, _ = detector.detectMarkers(gray)
    out = []
    if ids is None:
        return out
    for c, marker_id in zip(corners, ids.ravel()):
        size = sizes.get(int(marker_id))
        if size is None:
            continue
        half = size / 2
        obj = np.array([[-half, half, 0], [half, half, 0], [half, -half, 0], [-half, -half, 0]], float)
        ok, rvec, tvec = cv2.solvePnP(obj, c.reshape(4, 2), k, None, flags=cv2.SOLVEPNP_IPPE_SQUARE)
        if not ok:
            continue
        t = np.eye(4)
        t[:3, :3] = cv2.Rodrigues(rvec)[0]
        t[:3, 3] = tvec.ravel()
        out.append(MarkerSighting(int(marker_id), t))
    return out


class ArucoTracker:
    name = "aruco"

    def __init__(self, robot: Robot, objects: dict[str, ObjectSpec], *, rate_hz: float = 5.0,
                 max_head_speed: float = 2.0) -> None:
        self.robot = robot
        self.model = robot.model
        self._by_marker = {o.marker.id: (n, o.marker.object_in_marker.matrix())
                           for n, o in objects.items() if o.marker is not None}
        self._sizes = {o.marker.id: o.marker.size_m for o in objects.values() if o.marker is not None}
        self._period = 1.0 / rate_hz
        self._max_head_speed = max_head_speed
        self._poses: dict[str, tuple[np.ndarray, float]] = {}
        self._task: asyncio.Task[None] | None = None
        self._last: tuple[np.ndarray, list[MarkerSighting]] = (np.empty(0, np.uint8), [])  # image searched, found
        self.frames_searched = 0

    def object_pose(self, obj: str) -> tuple[np.ndarray, float] | None:
        return self._poses.get(obj)

    async def start(self) -> None:
        self._task = asyncio.ensure_future(self._loop())

    async def stop(self) -> None:
        task, self._task = self._task, None
        await cancel_and_wait(task)

    async def _loop(self) -> None:
        async with contextlib.aclosing(self.robot.live_frames(jpeg=False)) as frames:  # raw pixels if there are
            async for frame in frames:
                state = self.robot.joint_state()
                head = [state.velocities[state.names.index(n)] for n in self.model.part_joints("head")]
                if max(abs(v) for v in head) <= self._max_head_speed:
                    try:
                        found = await asyncio.to_thread(self._search, frame, state.as_dict())
                    except Exception:  # a bad frame must not end tracking
                        log.exception("ArUco search failed")
                        found = {}
                    for name, pose in found.items():
                        self._poses[name] = (pose, frame.stamp_monotonic)
                age = asyncio.get_running_loop().time() - frame.stamp_monotonic  # stamps are on the loop's clock
                await asyncio.sleep(max(0.0, self._period - age))

    def _search(self, frame: CameraFrame, angles: dict[str, float]) -> dict[str, np.ndarray]:
        """Markers seen in the frame, placed with the joint state read with it. The same image as the last one
        (a still camera on a still scene) shows the same markers: they are not searched for again."""
        gray = gray_image(frame)
        if gray is None:  # overwritten in the ring before it was read, or not an image
            return {}
        if not np.array_equal(gray, self._last[0]):
            self.frames_searched += 1
            k = camera_matrix(self.model, gray.shape[1], gray.shape[0])
            self._last = (gray, detect_markers(gray, k, self._sizes))
        base_from_camera = forward_kinematics(self.model, {**self.model.home_pose(), **angles})["camera"]
        out = {}
        for s in self._last[1]:
            name, object_in_marker = self._by_marker[s.id]
            out[name] = base_from_camera @ s.camera_from_marker @ object_in_marker
        return out
