"""A small classroom for the stand-in: QTrobot on a table, marker-tagged objects, bystanders, lights.

Built with MuJoCo's MjSpec on top of robot_models' MJCF, so the robot part always matches the robot description.
Marker textures are drawn with OpenCV's ArUco module and handed to MuJoCo as pixel buffers (no files). Each
marker's id, size and pose are recorded so perception can be tested against ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from robot_models import RobotModel, load_qtrobot
from robot_models.mjcf import build_qtrobot_mjcf

from .pupils import FIGURES, TABLE_HEIGHT, head_radius, neck_joint

ARUCO_DICTIONARY = "DICT_4X4_50"
OVERVIEW_CAMERA = "overview"  # looks at the robot's face from where a child would sit


@dataclass(frozen=True, eq=False)
class MarkerInfo:
    """One ArUco marker. pose_world: 4x4, origin at the marker's centre on its surface, x to the marker image's
    right, y to its top, z out of the marker toward a viewer (OpenCV's marker frame)."""

    id: int
    size_m: float  # side of the black square (what cv2 pose estimation takes as the marker length)
    body: str
    pose_world: np.ndarray
    dictionary: str = ARUCO_DICTIONARY


@dataclass(frozen=True, eq=False)
class ClassroomScene:
    """The compiled scene and the ground truth a test needs."""

    model: mujoco.MjModel
    robot_base_world: np.ndarray  # 4x4 pose of the robot's base_link in the world
    markers: tuple[MarkerInfo, ...]
    bystanders: tuple[str, ...]
    shadows: bool = False
    spec: mujoco.MjSpec = field(default=None, repr=False)  # type: ignore[assignment]

    def marker(self, marker_id: int) -> MarkerInfo:
        for m in self.markers:
            if m.id == marker_id:
                return m
        raise KeyError(f"no marker {marker_id} in the scene; markers: {[m.id for m in self.markers]}")


def _quat(matrix: np.ndarray) -> list[float]:
    x, y, z, w = Rotation.from_matrix(matrix).as_quat()
    return [w, x, y, z]


def _yaw(deg: float) -> np.ndarray:
    return Rotation.from_euler("z", deg, degrees=True).as_matrix()


def _look_at(eye, target) -> list[float]:
    """MuJoCo camera xyaxes for a camera at `eye` looking at `target`, z up."""
    fwd = np.asarray(target, float) - np.asarray(eye, float)
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    return [*right, *up]


def marker_image(marker_id: int, pixels_per_bit: int = 16) -> np.ndarray:
    """RGB marker with a white quiet zone one bit wide (detectors need it on coloured objects)."""
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, ARUCO_DICTIONARY))
    bits = 4 + 2  # 4x4 data bits plus the one-bit black border
    img = cv2.aruco.generateImageMarker(dictionary, marker_id, bits * pixels_per_bit, borderBits=1)
    img = cv2.copyMakeBorder(img, pixels_per_bit, pixels_per_bit, pixels_per_bit, pixels_per_bit,
                             cv2.BORDER_CONSTANT, value=255)
    return cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)


def _add_texture(spec: mujoco.MjSpec, name: str, rgb: np.ndarray) -> None:
    h, w, _ = rgb.shape
    tex = spec.add_texture(name=name, type=mujoco.mjtTexture.mjTEXTURE_2D, width=w, height=h, nchannel=3)
    tex.data = np.ascontiguousarray(rgb, dtype=np.uint8).tobytes()
    mat = spec.add_material(name=name)
    mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = name


def _add_marker(spec, body, body_name: str, body_pose: np.ndarray, marker_id: int, size: float,
                local_pos, local_rot: np.ndarray) -> MarkerInfo:
    """A thin plate carrying the marker; its local z is the marker's outward normal."""
    _add_texture(spec, f"aruco_{marker_id}", marker_image(marker_id))
    plate = size * (6 + 2) / 6  # black square of `size` plus the one-bit quiet zone each side
    half_thickness = 0.001
    centre = np.asarray(local_pos, float) + local_rot[:, 2] * half_thickness
    body.add_geom(name=f"aruco_{marker_id}", type=mujoco.mjtGeom.mjGEOM_BOX,
                  size=[plate / 2, plate / 2, half_thickness], pos=centre.tolist(), quat=_quat(local_rot),
                  material=f"aruco_{marker_id}")
    surface = np.eye(4)
    surface[:3, :3] = local_rot
    surface[:3, 3] = np.asarray(local_pos, float) + local_rot[:, 2] * 2 * half_thickness
    return MarkerInfo(id=marker_id, size_m=size, body=body_name, pose_world=body_pose @ surface)


def _pose(pos, rot) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = rot
    t[:3, 3] = pos
    return t


def build_classroom(robot: RobotModel | None = None, *, shadows: bool = False, antialias: int = 4,
                    offscreen_size: tuple[int, int] = (1280, 720)) -> ClassroomScene:
    """Compile the classroom.

    shadows=False by default, and `antialias` (MSAA samples, 0 for none) is adjustable, because on a machine
    without a GPU MuJoCo renders through Mesa's software rasteriser, where both cost most of a frame's time.
    """
    robot = robot or load_qtrobot()
    spec = mujoco.MjSpec.from_string(build_qtrobot_mjcf(robot))
    spec.modelname = "qtrobot_classroom"
    vis = spec.visual
    vis.global_.offwidth = max(vis.global_.offwidth, offscreen_size[0])
    vis.global_.offheight = max(vis.global_.offheight, offscreen_size[1])
    vis.headlight.ambient = [0.35, 0.35, 0.35]
    vis.headlight.diffuse = [0.35, 0.35, 0.35]
    vis.headlight.specular = [0.0, 0.0, 0.0]
    vis.quality.shadowsize = 2048 if shadows else 0
    vis.quality.offsamples = antialias

    robot_base = _pose([0.0, 0.0, TABLE_HEIGHT], np.eye(3))
    spec.body("base_link").pos = robot_base[:3, 3].tolist()

    world = spec.worldbody
    # Floor, walls and a whiteboard.
    floor_tex = spec.add_texture(name="floor", type=mujoco.mjtTexture.mjTEXTURE_2D,
                                 builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER, width=256, height=256,
                                 rgb1=[0.55, 0.45, 0.35], rgb2=[0.5, 0.4, 0.3])
    del floor_tex
    floor_mat = spec.add_material(name="floor", texrepeat=[6, 6], reflectance=0.0)
    floor_mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "floor"
    world.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[4, 4, 0.1], material="floor")
    wall = [0.86, 0.88, 0.84, 1]
    world.add_geom(name="back_wall", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.05, 3.0, 1.5], pos=[3.3, 0, 1.5],
                   rgba=wall)
    for side in (-1, 1):
        world.add_geom(name=f"side_wall_{'left' if side > 0 else 'right'}", type=mujoco.mjtGeom.mjGEOM_BOX,
                       size=[3.3, 0.05, 1.5], pos=[0.0, side * 3.0, 1.5], rgba=[0.8, 0.84, 0.88, 1])
    world.add_geom(name="front_wall", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.05, 3.0, 1.5], pos=[-1.3, 0, 1.5],
                   rgba=wall)
    world.add_geom(name="whiteboard", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.02, 1.0, 0.5], pos=[3.24, 0.3, 1.55],
                   rgba=[0.97, 0.97, 0.97, 1])
    world.add_geom(name="whiteboard_frame", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.015, 1.04, 0.54],
                   pos=[3.25, 0.3, 1.55], rgba=[0.4, 0.4, 0.45, 1])

    # The table: the robot stands at its back edge, the objects lie in front of it.
    table = world.add_body(name="table", pos=[0.45, 0.0, 0.0])
    wood = [0.62, 0.45, 0.28, 1]
    table.add_geom(name="table_top", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.6, 0.6, 0.015],
                   pos=[0, 0, TABLE_HEIGHT - 0.015], rgba=wood)
    for i, (lx, ly) in enumerate(((-0.55, -0.55), (-0.55, 0.55), (0.55, -0.55), (0.55, 0.55))):
        table.add_geom(name=f"table_leg_{i}", type=mujoco.mjtGeom.mjGEOM_BOX,
                       size=[0.025, 0.025, TABLE_HEIGHT / 2 - 0.015],
                       pos=[lx, ly, TABLE_HEIGHT / 2 - 0.015], rgba=[0.3, 0.3, 0.32, 1])

    markers: list[MarkerInfo] = []
    toward_robot = np.column_stack([[0, -1, 0], [0, 0, 1], [-1, 0, 0]]).astype(float)  # marker on a -x face
    facing_up = np.column_stack([[0, -1, 0], [1, 0, 0], [0, 0, 1]]).astype(float)  # marker on a top face
    objects = [
        # name, half sizes, position on the table (x, y), yaw deg, colour, marker id, marker size, face
        ("red_cube", (0.035, 0.035, 0.035), (0.70, 0.22), 0.0, (0.85, 0.2, 0.2, 1), 0, 0.05, "front"),
        ("blue_cube", (0.045, 0.045, 0.045), (0.85, -0.25), 20.0, (0.2, 0.35, 0.85, 1), 1, 0.07, "front"),
        ("green_book", (0.08, 0.11, 0.015), (0.66, -0.02), 10.0, (0.2, 0.6, 0.3, 1), 2, 0.08, "top"),
        ("yellow_box", (0.06, 0.09, 0.13), (1.0, 0.05), -15.0, (0.9, 0.8, 0.2, 1), 3, 0.10, "front"),
    ]
    for name, half, (x, y), yaw, rgba, mid, msize, face in objects:
        pos = np.array([x, y, TABLE_HEIGHT + half[2]])
        rot = _yaw(yaw)
        body = world.add_body(name=name, pos=pos.tolist(), quat=_quat(rot))
        body.add_geom(name=f"{name}_geom", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(half), rgba=list(rgba))
        if face == "front":
            local_pos, local_rot = [-half[0], 0.0, 0.0], toward_robot
        else:
            local_pos, local_rot = [0.0, 0.0, half[2]], facing_up
        markers.append(_add_marker(spec, body, name, _pose(pos, rot), mid, msize, local_pos, local_rot))

    # Bystanders: simple figures facing the robot, with eyes, mouth and hair on a head sphere.
    # (sim/pupils.py holds the figures: the simulated pupils are the same people)
    figures = FIGURES
    for name, (x, y), height, shirt, skin, hair in figures:
        head_r = head_radius(height)
        head_z = height - head_r
        facing = np.degrees(np.arctan2(-y, -x))  # local +x turned towards the robot: they watch it
        body = world.add_body(name=name, pos=[x, y, 0.0], quat=_quat(_yaw(facing)))
        body.add_geom(name=f"{name}_legs", type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[0.07, 0, 0],
                      fromto=[0, 0, 0.07, 0, 0, 0.47 * height], rgba=[0.2, 0.22, 0.3, 1])
        body.add_geom(name=f"{name}_torso", type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[0.12 * height / 1.5, 0, 0],
                      fromto=[0, 0, 0.5 * height, 0, 0, head_z - head_r - 0.12 * height / 1.5], rgba=list(shirt))
        for side in (-1, 1):
            body.add_geom(name=f"{name}_arm_{'l' if side > 0 else 'r'}", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                          size=[0.035, 0, 0], fromto=[0, side * 0.17 * height / 1.5, head_z - 0.28 * height / 1.5,
                                                       0.04, side * 0.2 * height / 1.5, 0.5 * height],
                          rgba=list(shirt))
        # The head turns on a neck (a vertical hinge through its centre, sim/pupils.py's neck_joint): a pupil who
        # looks away shows the robot the back of its head. No force turns it but the stand-in's look().
        head = body.add_body(name=f"{name}_head", pos=[0, 0, head_z])
        head.add_joint(name=neck_joint(name), type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 0, 1], damping=1.0)
        head.add_geom(name=f"{name}_head", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[head_r, 0, 0], rgba=list(skin))
        head.add_geom(name=f"{name}_hair", type=mujoco.mjtGeom.mjGEOM_ELLIPSOID,
                      size=[head_r * 1.02, head_r * 1.04, head_r * 0.75],
                      pos=[-0.25 * head_r, 0, 0.45 * head_r], rgba=list(hair))
        # A face as a detector (and a child) reads one: eyes with whites and dark irises under brows, a nose that
        # catches the light, lips, ears; the same features on every skin tone.
        def on_face(yaw: float, z: float, out: float = 1.0) -> list[float]:
            c = np.sqrt(1.0 - z * z)
            return [out * c * np.cos(yaw) * head_r, out * c * np.sin(yaw) * head_r, z * head_r]
        for side in (-1, 1):
            head.add_geom(name=f"{name}_eye_{side}", type=mujoco.mjtGeom.mjGEOM_ELLIPSOID,
                          size=[0.05 * head_r, 0.17 * head_r, 0.1 * head_r], pos=on_face(side * 0.36, 0.1, 0.97),
                          quat=_quat(_yaw(np.degrees(side * 0.36))), rgba=[0.95, 0.94, 0.92, 1])
            head.add_geom(name=f"{name}_iris_{side}", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.075 * head_r, 0, 0],
                          pos=on_face(side * 0.36, 0.1, 0.985), rgba=[0.12, 0.08, 0.05, 1])
            head.add_geom(name=f"{name}_brow_{side}", type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[0.06 * head_r, 0, 0],
                          fromto=on_face(side * 0.15, 0.36, 0.99) + on_face(side * 0.6, 0.38, 0.97),
                          rgba=list(hair))
            head.add_geom(name=f"{name}_ear_{side}", type=mujoco.mjtGeom.mjGEOM_ELLIPSOID,
                          size=[0.1 * head_r, 0.06 * head_r, 0.2 * head_r], pos=on_face(side * 1.57, 0.0, 0.98),
                          rgba=list(skin))
        head.add_geom(name=f"{name}_nose", type=mujoco.mjtGeom.mjGEOM_ELLIPSOID,
                      size=[0.16 * head_r, 0.1 * head_r, 0.2 * head_r], pos=on_face(0.0, -0.12, 0.97),
                      rgba=list(skin))
        head.add_geom(name=f"{name}_mouth", type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[0.07 * head_r, 0, 0],
                      fromto=on_face(-0.3, -0.45, 0.97) + on_face(0.3, -0.45, 0.97),
                      rgba=[0.55 * skin[0] + 0.2, 0.35 * skin[1], 0.35 * skin[2], 1])

    # Lights: a key light from above the table and a fill from behind the robot; no shadows unless asked.
    world.add_light(name="key", type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, pos=[1.0, 0.5, 3.0],
                    dir=[-0.2, -0.2, -1.0], diffuse=[0.55, 0.55, 0.52], castshadow=shadows)
    world.add_light(name="fill", type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, pos=[-1.0, 0.0, 2.0],
                    dir=[1.0, 0.0, -0.6], diffuse=[0.3, 0.3, 0.32], castshadow=False)
    eye = [0.95, 0.35, TABLE_HEIGHT + 0.45]
    world.add_camera(name=OVERVIEW_CAMERA, pos=eye, xyaxes=_look_at(eye, [0.0, 0.0, TABLE_HEIGHT + 0.4]), fovy=45)

    model = spec.compile()
    return ClassroomScene(model=model, robot_base_world=robot_base, markers=tuple(markers),
                          bystanders=tuple(f[0] for f in figures), shadows=shadows, spec=spec)
