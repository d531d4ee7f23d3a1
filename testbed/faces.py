"""The stand-in's pupils as the robot's head camera sees them, over a grid of head turns, distances and places in the
frame, each picture with where every face truly is: what bench/faces.py measures the face detectors on and what
tests/test_faces.py holds a floor under.

Rendered in this process with MuJoCo from the classroom scene (sim/scene.py), through a camera of the head camera's
field of view and size, at the head camera's height, placed `distance_m` from the pupil's face on the line between
the pupil and the robot (the robot itself is moved out of the way, so the camera may stand where it stands). The
pictures go through JPEG at the stand-in's quality, as the server's frames do.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import cv2
import mujoco
import numpy as np

from robot_models import load_qtrobot
from robot_models.kinematics import forward_kinematics
from sim.pupils import FIGURES, TABLE_HEIGHT, head_radius, neck_joint
from sim.scene import build_classroom

IN_VIEW_DEG = 45.0  # a head turned at most this far from the camera shows both eyes: its face is in view
MIN_FACE_PX = 30.0  # the recall target counts faces at least this tall


@dataclass(frozen=True)
class Head:
    """A figure's head in a picture: its centre and its height, pixels, and how far it is turned from the camera."""

    name: str
    u: float
    v: float
    height_px: float
    turned_deg: float
    whole: bool  # all of it inside the picture (a head cut by the frame's edge still holds a true face)

    def holds(self, x: float, y: float, margin: float = 1.0) -> bool:
        r = margin * self.height_px / 2
        return abs(x - self.u) <= r and abs(y - self.v) <= r


@dataclass(frozen=True)
class View:
    pupil: str
    distance_m: float
    head_yaw_deg: float  # the pupil's head turned from the camera (its neck; positive to its left)
    pan_deg: float  # the camera turned away from the pupil: the face sits off the frame's centre
    jpeg: bytes
    heads: tuple[Head, ...]  # every figure's head in the picture (whole or cut by its edge), the pupil's first

    @property
    def target(self) -> Head | None:
        return next((h for h in self.heads if h.name == self.pupil), None)

    @property
    def counted(self) -> bool:
        """Whether the recall target counts this picture: the pupil's face in view, whole and tall enough."""
        t = self.target
        return t is not None and t.whole and abs(t.turned_deg) <= IN_VIEW_DEG and t.height_px >= MIN_FACE_PX


def matches(head: Head, box) -> bool:
    """A detector's box (x, y, width, height attributes) is this face: its centre on the head, its size near."""
    cx, cy = box.x + box.width / 2, box.y + box.height / 2
    return head.holds(cx, cy) and 0.4 <= max(box.width, box.height) / head.height_px <= 2.5


class PupilCamera:
    """Renders views of the classroom's pupils (not thread-safe: one renderer, one MjData)."""

    def __init__(self, width: int = 640, height: int = 480, jpeg_quality: int = 80) -> None:
        robot = load_qtrobot()
        self.width, self.height, self.jpeg_quality = width, height, jpeg_quality
        self.scene = build_classroom(robot, antialias=0, offscreen_size=(max(width, 1280), max(height, 720)))
        self.model = m = self.scene.model
        m.vis.global_.fovy = robot.camera.fovy_deg if robot.camera else 65.0
        self.focal = (height / 2) / math.tan(math.radians(m.vis.global_.fovy) / 2)
        self.camera_z = TABLE_HEIGHT + forward_kinematics(robot, robot.home_pose())["camera"][2, 3]
        m.body_pos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "base_link")] = [0.0, 0.0, -20.0]
        self.data = mujoco.MjData(m)
        self.renderer = mujoco.Renderer(m, height, width)
        self.figures = {name: (np.array([x, y, h - head_radius(h)]), head_radius(h)) for name, (x, y), h, *_ in
                        FIGURES}
        self._necks = {name: m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, neck_joint(name))]
                       for name in self.figures}

    def close(self) -> None:
        self.renderer.close()

    def view(self, pupil: str, distance_m: float, head_yaw_deg: float = 0.0, pan_deg: float = 0.0) -> View:
        centre, _ = self.figures[pupil]
        toward_robot = -centre[:2] / np.linalg.norm(centre[:2])
        dz = self.camera_z - centre[2]
        flat = math.sqrt(max(distance_m**2 - dz**2, 0.01))
        eye = np.array([*(centre[:2] + flat * toward_robot), self.camera_z])
        look = centre - eye
        azimuth = math.degrees(math.atan2(look[1], look[0])) + pan_deg
        elevation = math.degrees(math.atan2(look[2], np.linalg.norm(look[:2])))
        forward = np.array([math.cos(math.radians(elevation)) * math.cos(math.radians(azimuth)),
                            math.cos(math.radians(elevation)) * math.sin(math.radians(azimuth)),
                            math.sin(math.radians(elevation))])
        self.data.qpos[:] = 0.0
        self.data.qpos[self._necks[pupil]] = math.radians(head_yaw_deg)
        mujoco.mj_forward(self.model, self.data)
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        cam.lookat[:] = eye + forward
        cam.distance, cam.azimuth, cam.elevation = 1.0, azimuth, elevation
        self.renderer.update_scene(self.data, camera=cam)
        rgb = self.renderer.render()
        ok, jpeg = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
                                [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise RuntimeError("JPEG encoding of a rendered view failed")
        heads = [h for name in sorted(self.figures, key=lambda n: n != pupil)
                 if (h := self._project(name, eye, forward, head_yaw_deg if name == pupil else 0.0)) is not None]
        return View(pupil, distance_m, head_yaw_deg, pan_deg, jpeg.tobytes(), tuple(heads))

    def _project(self, name: str, eye: np.ndarray, forward: np.ndarray, neck_deg: float) -> Head | None:
        centre, radius = self.figures[name]
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        rel = centre - eye
        z = float(rel @ forward)
        if z <= radius:
            return None
        u = self.width / 2 + self.focal * float(rel @ right) / z
        v = self.height / 2 - self.focal * float(rel @ up) / z
        size = 2 * radius * self.focal / z
        r = size / 2
        if not (-r < u < self.width + r and -r < v < self.height + r):
            return None
        whole = r <= u <= self.width - r and r <= v <= self.height - r
        # The figure faces the robot (the world's origin) with its neck at 0; the camera sees it turned by the angle
        # between where its face points and where the camera is.
        facing = math.degrees(math.atan2(-centre[1], -centre[0])) + neck_deg
        to_camera = math.degrees(math.atan2(eye[1] - centre[1], eye[0] - centre[0]))
        turned = (facing - to_camera + 180.0) % 360.0 - 180.0
        return Head(name, u, v, size, turned, whole)

    def views(self, pupils: Iterable[str] | None = None, distances: Iterable[float] = (1.0, 2.0),
              head_yaws: Iterable[float] = (0.0,), pans: Iterable[float] = (0.0,)) -> Iterator[View]:
        for args in itertools.product(pupils or sorted(self.figures), distances, head_yaws, pans):
            yield self.view(*args)
