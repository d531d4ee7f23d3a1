"""QTrobot's MuJoCo model (MJCF), generated from the robot description so the two cannot disagree.

`build_qtrobot_mjcf(model)` writes the XML from data/qtrobot.yaml; robot_models/mjcf/qtrobot.xml is its output,
checked in for people and tools that want a file (regenerate with `python -m robot_models.mjcf`).
Angles in the XML are degrees (compiler angle="degree"); actuators take radians, as MuJoCo's always do.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from importlib import resources
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..qtrobot import RobotModel, load_qtrobot

FACE_TEXTURE = "qt_face"  # the sim replaces this texture's pixels at run time to show emotions
FACE_TEXTURE_SIZE = (320, 192)  # width, height in texels; 5:3 like the screen
HEAD_CAMERA = "head_camera"
# Servo model: stiff position servos, damped near critically for the (light, hollow) links, with gravity
# compensated as the real robot's servos hold their pose. Gains in N m/rad and N m s/rad.
PART_GAINS = {"head": (30.0, 1.5), "right_arm": (20.0, 0.6), "left_arm": (20.0, 0.6)}
SHELL_DENSITY = 250.0  # kg/m^3: the robot is a hollow plastic shell, not solid water
SENSOR_PIXEL_PITCH = 1e-5  # metres; arbitrary, MuJoCo only needs focal length and sensor size in one unit


def _f(*values: float) -> str:
    return " ".join(f"{v:.6g}" if abs(v) > 1e-12 else "0" for v in values)


def _quat(matrix: np.ndarray) -> str:
    x, y, z, w = Rotation.from_matrix(matrix).as_quat()
    if w < 0:
        x, y, z, w = -x, -y, -z, -w
    return _f(w, x, y, z)  # MuJoCo quaternions are scalar first


def _rpy_matrix(rpy_deg) -> np.ndarray:
    return Rotation.from_euler("xyz", rpy_deg, degrees=True).as_matrix()


def build_qtrobot_mjcf(model: RobotModel | None = None) -> str:
    """The MJCF text of QTrobot: bodies along the URDF chain, hinge joints, position actuators, face, camera."""
    model = model or load_qtrobot()
    g, cam = model.geometry, model.camera
    if g is None or cam is None:
        raise ValueError("the robot model has no geometry or camera section; load it with load_qtrobot()")
    root = ET.Element("mujoco", model="qtrobot")
    ET.SubElement(root, "compiler", angle="degree", autolimits="true")
    ET.SubElement(root, "option", timestep="0.002", integrator="implicitfast")
    visual = ET.SubElement(root, "visual")
    ET.SubElement(visual, "global", offwidth=str(cam.width), offheight=str(cam.height))

    default = ET.SubElement(ET.SubElement(root, "default"), "default", {"class": "qtrobot"})
    ET.SubElement(default, "joint", type="hinge", armature="0.005", damping="0.05")
    # Robot geoms are visual only: the stand-in's job is poses and the camera view, and contacts would fight
    # the position servos (a real QTrobot has no contact sensing either).
    ET.SubElement(default, "geom", contype="0", conaffinity="0", density=_f(SHELL_DENSITY), material="qt_shell")

    asset = ET.SubElement(root, "asset")
    ET.SubElement(asset, "texture", name=FACE_TEXTURE, type="2d", builtin="flat",
                  width=str(FACE_TEXTURE_SIZE[0]), height=str(FACE_TEXTURE_SIZE[1]), rgb1="0.05 0.05 0.08")
    ET.SubElement(asset, "material", name=FACE_TEXTURE, texture=FACE_TEXTURE, emission="0.8", specular="0.1")
    ET.SubElement(asset, "material", name="qt_shell", rgba="0.93 0.93 0.9 1", specular="0.3", shininess="0.4")
    ET.SubElement(asset, "material", name="qt_dark", rgba="0.15 0.15 0.17 1")

    world = ET.SubElement(root, "worldbody")
    base = ET.SubElement(world, "body", name="base_link", childclass="qtrobot")
    ET.SubElement(base, "geom", name="torso", type="cylinder", size=_f(g.torso_radius, g.torso_length / 2),
                  pos=_f(0, 0, g.torso_top_z - g.torso_length / 2))

    bodies = {"base_link": base}
    for el in model.chain:
        parent = bodies[el.parent]
        if el.type == "revolute":
            joint = model.joint(el.name)
            body = ET.SubElement(parent, "body", name=el.name, pos=_f(*el.xyz), quat=_quat(_rpy_matrix(el.rpy_deg)))
            ET.SubElement(body, "joint", name=el.name, axis=_f(*el.axis), range=_f(joint.lower, joint.upper))
            bodies[el.name] = body
        elif el.name == "camera":
            # MuJoCo cameras look along their -z with y up; the URDF optical frame looks along +z with y down.
            optical = _rpy_matrix(el.rpy_deg)
            mj = optical @ Rotation.from_euler("x", 180, degrees=True).as_matrix()
            ET.SubElement(parent, "geom", name="camera_body", type="box", size=_f(*g.camera_box),
                          pos=_f(el.xyz[0] - g.camera_box[0], el.xyz[1], el.xyz[2]), material="qt_dark")
            # A post from the head's centre up to the camera, which sits on top of the head as on the robot.
            bottom = el.xyz[2] - g.camera_box[2]
            zc = g.head_center_above_pitch
            ET.SubElement(parent, "geom", name="camera_mount", type="box", size=_f(0.008, 0.015, (bottom - zc) / 2),
                          pos=_f(el.xyz[0] - 2 * g.camera_box[0], el.xyz[1], (bottom + zc) / 2), material="qt_dark")
            # Principal point: MuJoCo takes its offset from the image centre, measured with x and y as the
            # render's projection has them (checked in tests by projecting known points).
            ET.SubElement(parent, "camera", name=HEAD_CAMERA, pos=_f(*el.xyz), quat=_quat(mj),
                          resolution=f"{cam.width} {cam.height}",
                          sensorsize=_f(cam.width * SENSOR_PIXEL_PITCH, cam.height * SENSOR_PIXEL_PITCH),
                          focalpixel=_f(cam.fx, cam.fy),
                          principalpixel=_f(cam.width / 2 - cam.cx, cam.height / 2 - cam.cy))
            ET.SubElement(parent, "site", name="camera", pos=_f(*el.xyz), quat=_quat(optical), size="0.005", group="4")
        else:  # a hand
            ET.SubElement(parent, "geom", name=el.name, type="sphere", size=_f(g.hand_radius), pos=_f(*el.xyz))
            ET.SubElement(parent, "site", name=el.name, pos=_f(*el.xyz), quat=_quat(_rpy_matrix(el.rpy_deg)),
                          size="0.01", group="4")
        if el.type == "revolute":
            _add_link_shapes(model, el.name, body)

    actuators = ET.SubElement(root, "actuator")
    for joint in model.joints:
        kp, kv = PART_GAINS[joint.part]
        # inheritrange: the control range is the joint's range, converted to radians by MuJoCo itself.
        ET.SubElement(actuators, "position", name=joint.name, joint=joint.name, kp=_f(kp), kv=_f(kv),
                      inheritrange="1")
    sensors = ET.SubElement(root, "sensor")
    for joint in model.joints:
        ET.SubElement(sensors, "jointpos", name=f"{joint.name}_pos", joint=joint.name)
    ET.indent(root)
    return ET.tostring(root, encoding="unicode") + "\n"


def _add_link_shapes(model: RobotModel, name: str, body: ET.Element) -> None:
    """Primitive shapes hung on a joint's body; every length comes from the chain or the geometry section."""
    g = model.geometry
    assert g is not None
    children = [el for el in model.chain if el.parent == name]
    # gravcomp: the real servos hold their pose against gravity; the stand-in's should too.
    body.set("gravcomp", "1")
    if name == "HeadYaw":
        pitch = children[0]
        ET.SubElement(body, "geom", name="neck", type="cylinder", size=_f(0.03, pitch.xyz[2] / 2),
                      pos=_f(0, 0, pitch.xyz[2] / 2), material="qt_dark")
    elif name == "HeadPitch":
        a, b, c = g.head_semi_axes
        zc = g.head_center_above_pitch
        ET.SubElement(body, "geom", name="head", type="ellipsoid", size=_f(a, b, c), pos=_f(0, 0, zc))
        # The screen is a thin box whose local z faces forward (+x); MuJoCo maps the 2-D texture onto it
        # (found by rendering a test pattern: local x toward base +y and local y up show the image upright).
        screen = np.column_stack([[0, 1, 0], [0, 0, 1], [1, 0, 0]]).astype(float)
        ET.SubElement(body, "geom", name="face_screen", type="box",
                      size=_f(g.face_width / 2, g.face_height / 2, g.face_thickness / 2),
                      pos=_f(a + g.face_thickness / 2 + 0.001, 0, zc), quat=_quat(screen), material=FACE_TEXTURE)
    elif name.endswith("ShoulderPitch"):
        roll = children[0]
        ET.SubElement(body, "geom", name=f"{name}_link", type="capsule", size=_f(g.upper_arm_radius * 1.1),
                      fromto=_f(0, 0, 0, *roll.xyz))
    elif name.endswith("ShoulderRoll"):
        elbow = children[0]
        ET.SubElement(body, "geom", name=f"{name}_link", type="capsule", size=_f(g.upper_arm_radius),
                      fromto=_f(0, 0, 0, *elbow.xyz))
    elif name.endswith("ElbowRoll"):
        hand = children[0]
        ET.SubElement(body, "geom", name=f"{name}_link", type="capsule", size=_f(g.forearm_radius),
                      fromto=_f(0, 0, 0, hand.xyz[0], hand.xyz[1] - g.hand_radius, hand.xyz[2]))


def packaged_mjcf_path() -> Path:
    return Path(str(resources.files("robot_models").joinpath("mjcf/qtrobot.xml")))


def main() -> None:
    packaged_mjcf_path().write_text(build_qtrobot_mjcf(), encoding="utf-8")
    print(packaged_mjcf_path())
