"""Modelled perception (`--perception modelled`, a study file's `perception: modelled`): the stand-in's pupils' face
boxes computed from the scene instead of drawn by llvmpipe and searched by CenterFace (about 0.4 CPU s a frame).

Each pupil's head is projected through the head camera's model (MuJoCo's, its intrinsics as the render process
draws them) at the head's pose; it is seen if its centre is in the frame, in front of the camera, and the line from the camera to it
meets that head first (not another head, nor the robot's own parts). A seen face is then found with the recall the
real detector has at that distance, turn from the camera and skin tone: the table `bench/faces.py --calibrate`
measured on rendered frames (data/face_recall.json, which says when and how), interpolated between its grid
points, drawn from a seeded generator. Its box is the head's projected box scaled and shifted as the calibration
found CenterFace's boxes to be. The modelled detector finds no false positives (the calibration measures how many
the real one finds: see the file).
"""

from __future__ import annotations

import asyncio
import json
import math
import random
from collections.abc import AsyncIterator
from dataclasses import dataclass
from importlib import resources
from typing import Any

import mujoco
import numpy as np

from robot_models.mjcf import HEAD_CAMERA
from simclock import Clock
from sim.pupils import FIGURES, head_radius, skin_tone

from .faces import FaceBox, Found, Perception

TABLE = "face_recall.json"


@dataclass(frozen=True)
class RecallTable:
    """The real detector's recall by skin tone, distance (m) and turn from the camera (degrees, absolute), with its
    boxes' geometry relative to the projected head; read from the calibration's file."""

    distances: tuple[float, ...]
    turns: tuple[float, ...]
    recall: dict[str, np.ndarray]  # tone -> [distance, turn]
    confidence: dict[str, np.ndarray]  # tone -> [distance, turn]: the found boxes' mean confidence
    box_scale: tuple[float, float]  # box width, height / the head's projected diameter
    box_shift: tuple[float, float]  # box centre - head centre, in head diameters (x right, y down)
    box_iou: dict[str, float]  # such a box against the detector's on the calibration's pictures: min, p05, median
    measured: dict[str, Any]

    @classmethod
    def load(cls, path: Any = None) -> RecallTable:
        raw = json.loads((path or resources.files("vr_teleop_server.features") / "data" / TABLE).read_text())
        return cls(tuple(raw["distances_m"]), tuple(raw["turns_deg"]),
                   {t: np.array(v, float) for t, v in raw["recall"].items()},
                   {t: np.array(v, float) for t, v in raw["confidence"].items()},
                   tuple(raw["box"]["scale"]), tuple(raw["box"]["shift"]), raw["box"]["iou_with_detector"],
                   raw["measured"])

    def _at(self, grid: np.ndarray, distance: float, turn: float) -> float:
        """Bilinear in distance and turn, held at the grid's edges (nearer or farther than measured: the edge)."""
        d = float(np.clip(distance, self.distances[0], self.distances[-1]))
        a = float(np.clip(abs(turn), self.turns[0], self.turns[-1]))
        i = min(int(np.searchsorted(self.distances, d, side="right")) - 1, len(self.distances) - 2)
        j = min(int(np.searchsorted(self.turns, a, side="right")) - 1, len(self.turns) - 2)
        fd = (d - self.distances[i]) / (self.distances[i + 1] - self.distances[i])
        fa = (a - self.turns[j]) / (self.turns[j + 1] - self.turns[j])
        g = grid[i:i + 2, j:j + 2]
        return float((1 - fd) * ((1 - fa) * g[0, 0] + fa * g[0, 1]) + fd * ((1 - fa) * g[1, 0] + fa * g[1, 1]))

    def recall_at(self, tone: str, distance: float, turn: float) -> float:
        return self._at(self.recall[tone], distance, turn)

    def confidence_at(self, tone: str, distance: float, turn: float) -> float:
        return self._at(self.confidence[tone], distance, turn)


@dataclass(frozen=True)
class HeadView:
    """A pupil's head as the head camera sees it: where, how far, turned how far, and whether it is seen."""

    name: str
    u: float  # centre, pixels
    v: float
    diameter_px: float
    distance_m: float
    turned_deg: float  # from facing the camera (0) to showing it the back of the head (180)
    seen: str  # "visible", "behind the camera", "out of the frame" or "occluded by <geom's body>"
    recall: float  # the real detector's, at this distance, turn and skin tone (0 unless visible)


class SceneFaces:
    """The pupils' heads in the head camera at a scene state (qpos), in a width x height picture. Not thread-safe
    (one MjData); cheap: a kinematics pass and a ray per pupil."""

    def __init__(self, model: mujoco.MjModel, width: int, height: int, table: RecallTable | None = None) -> None:
        self.model, self.width, self.height = model, width, height
        self.table = table or RecallTable.load()
        self.data = mujoco.MjData(model)
        self.camera = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, HEAD_CAMERA)
        sensor, intr = model.cam_sensorsize[self.camera], model.cam_intrinsic[self.camera]
        if sensor[0] > 0 and intr[0] > 0 and intr[1] > 0:  # intrinsics (the QTrobot's camera): they win over fovy
            self.fx, self.fy = intr[0] / sensor[0] * width, intr[1] / sensor[1] * height
            self.cx, self.cy = width / 2 - intr[2] / sensor[0] * width, height / 2 - intr[3] / sensor[1] * height
        else:
            self.fx = self.fy = (height / 2) / math.tan(math.radians(float(model.cam_fovy[self.camera])) / 2)
            self.cx, self.cy = width / 2, height / 2
        self.camera_body = int(model.cam_bodyid[self.camera])
        self.heads = {name: (mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"{name}_head"), head_radius(h))
                      for name, _, h, *_ in FIGURES}

    def look(self, qpos: np.ndarray) -> list[HeadView]:
        m, d = self.model, self.data
        d.qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        mujoco.mj_camlight(m, d)
        eye, rot = d.cam_xpos[self.camera].copy(), d.cam_xmat[self.camera].reshape(3, 3)  # x right, y up, -z ahead
        views = []
        for name, (body, radius) in self.heads.items():
            centre = d.xpos[body]
            local = (centre - eye) @ rot
            depth = -float(local[2])
            distance = float(np.linalg.norm(centre - eye))
            facing = d.xmat[body].reshape(3, 3)[:, 0]  # the head's +x: where its face points
            to_camera = eye - centre
            turned = abs((math.degrees(math.atan2(facing[1], facing[0]) - math.atan2(to_camera[1], to_camera[0]))
                          + 180.0) % 360.0 - 180.0)
            if depth <= radius:
                views.append(HeadView(name, math.nan, math.nan, 0.0, distance, turned, "behind the camera", 0.0))
                continue
            u = self.cx + self.fx * float(local[0]) / depth
            v = self.cy - self.fy * float(local[1]) / depth
            size = 2 * radius * self.fy / depth
            seen = "visible"
            if not (0 <= u <= self.width and 0 <= v <= self.height):
                seen = "out of the frame"
            else:
                hit = self._first_hit(eye, centre)
                if hit != body:
                    seen = f"occluded by {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, hit)}"
            recall = self.table.recall_at(skin_tone(name), distance, turned) if seen == "visible" else 0.0
            views.append(HeadView(name, u, v, size, distance, turned, seen, recall))
        return views

    def _first_hit(self, eye: np.ndarray, centre: np.ndarray) -> int:
        """The body whose geom the line from the camera to a head's centre meets first (-1: none)."""
        geom = np.zeros(1, np.int32)
        direction = centre - eye
        mujoco.mj_ray(self.model, self.data, eye, direction / np.linalg.norm(direction), None, 1, self.camera_body,
                      geom)
        return int(self.model.geom_bodyid[geom[0]]) if geom[0] >= 0 else -1

    def box(self, view: HeadView) -> tuple[int, int, int, int]:
        """The box CenterFace draws on this head (the calibration's scale and shift), clipped to the frame."""
        (sw, sh), (dx, dy) = self.table.box_scale, self.table.box_shift
        w, h = sw * view.diameter_px, sh * view.diameter_px
        cx, cy = view.u + dx * view.diameter_px, view.v + dy * view.diameter_px
        x0, y0 = max(0.0, cx - w / 2), max(0.0, cy - h / 2)
        x1, y1 = min(float(self.width), cx + w / 2), min(float(self.height), cy + h / 2)
        return int(round(x0)), int(round(y0)), int(round(x1 - x0)), int(round(y1 - y0))


class ModelledDetector:
    """Face boxes from the scene, found with the measured recall, drawn from `random.Random(seed)`."""

    name = "modelled:centerface"

    def __init__(self, model: mujoco.MjModel, width: int, height: int, *, seed: int = 0,
                 table: RecallTable | None = None) -> None:
        self.scene = SceneFaces(model, width, height, table)
        self._rng = random.Random(seed)

    def detect(self, qpos: np.ndarray) -> list[FaceBox]:
        found = []
        for view in self.scene.look(qpos):
            if view.recall <= 0.0 or self._rng.random() >= view.recall:
                continue
            x, y, w, h = self.scene.box(view)
            if w > 0 and h > 0:
                conf = self.scene.table.confidence_at(skin_tone(view.name), view.distance_m, view.turned_deg)
                found.append(FaceBox(x, y, w, h, round(conf, 3)))
        return sorted(found, key=lambda f: -f.confidence)


class ModelledFaces(Perception):
    """The stand-in's scene looked at `rate_hz` times a second (on the server's clock): no frame is drawn for it."""

    def __init__(self, standin: Any, clock: Clock, *, rate_hz: float, seed: int = 0,
                 table: RecallTable | None = None) -> None:
        self.standin, self.clock = standin, clock
        self.detector = ModelledDetector(standin.model, standin.camera_width, standin.camera_height, seed=seed,
                                         table=table)
        self.name = self.detector.name
        self._period = 1.0 / rate_hz
        self._seq = 0

    async def found(self) -> AsyncIterator[Found]:
        while True:
            qpos, _qvel, _t = self.standin.physics.scene_state()
            self._seq += 1
            yield Found(self._seq, self.clock.time(), self.standin.camera_width, self.standin.camera_height,
                        self.detector.detect(qpos))
            await asyncio.sleep(self._period)
