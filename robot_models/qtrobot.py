"""QTrobot's description (joints, limits, chain, body shapes, camera), loaded from the packaged yaml.

Everything above this module takes joint names, order, limits and velocity caps from a RobotModel, so the
robot's facts live in one file (data/qtrobot.yaml) and nowhere else.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from client_protocol.files import read_document

PARTS = ("head", "right_arm", "left_arm")


@dataclass(frozen=True)
class Joint:
    """One motorised joint; angles in degrees, velocity in deg/s."""

    name: str
    part: str
    lower: float
    upper: float
    home: float
    max_velocity: float


@dataclass(frozen=True)
class ChainElement:
    """One URDF joint (revolute or fixed): origin in its parent's frame, axis in its own frame."""

    name: str
    parent: str
    type: str  # "revolute" or "fixed"
    xyz: tuple[float, float, float]
    rpy_deg: tuple[float, float, float]
    axis: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics of the head camera, pixels."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @property
    def fovy_deg(self) -> float:
        """Vertical field of view, as MuJoCo's camera `fovy` wants it."""
        return math.degrees(2.0 * math.atan(self.height / (2.0 * self.fy)))


@dataclass(frozen=True)
class Geometry:
    """Primitive body shapes for the simulation model (metres)."""

    torso_radius: float
    torso_length: float
    torso_top_z: float
    head_semi_axes: tuple[float, float, float]
    head_center_above_pitch: float
    face_width: float
    face_height: float
    face_thickness: float
    camera_box: tuple[float, float, float]
    upper_arm_radius: float
    forearm_radius: float
    hand_radius: float


@dataclass(frozen=True)
class RobotModel:
    """The robot's joints in canonical order, plus the data kinematics and the simulator need."""

    joints: tuple[Joint, ...]
    chain: tuple[ChainElement, ...] = ()
    camera: CameraIntrinsics | None = None
    geometry: Geometry | None = None
    name: str = "QTrobot"
    emotions: tuple[str, ...] = ()  # LuxAI emotion names, without the "QT/" prefix
    gestures: tuple[str, ...] = ()  # LuxAI built-in gesture names, without the "QT/" prefix
    _index: Mapping[str, Joint] = field(  # type: ignore[assignment]
        default=None, init=False, repr=False, compare=False, hash=False)
    _parts: Mapping[str, tuple[str, ...]] = field(  # type: ignore[assignment]
        default=None, init=False, repr=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        index = {j.name: j for j in self.joints}
        if len(index) != len(self.joints):
            raise ValueError(f"duplicate joint names in {[j.name for j in self.joints]}")
        object.__setattr__(self, "_index", index)
        parts: dict[str, tuple[str, ...]] = {}
        for j in self.joints:
            parts[j.part] = parts.get(j.part, ()) + (j.name,)
        object.__setattr__(self, "_parts", parts)  # read on every command: built once

    def joint(self, name: str) -> Joint:
        try:
            return self._index[name]
        except KeyError:
            raise KeyError(f"unknown joint {name!r}; valid joints: {', '.join(self.names)}") from None

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def alphabetical_names(self) -> tuple[str, ...]:
        """The order /qt_robot/joints/state uses."""
        return tuple(sorted(self.names))

    @property
    def parts(self) -> dict[str, tuple[str, ...]]:
        """Part name -> its joints, in the order of LuxAI's /qt_robot/<part>_position/command arrays."""
        return dict(self._parts)

    def part_joints(self, part: str) -> tuple[str, ...]:
        try:
            return self._parts[part]
        except KeyError:
            raise KeyError(f"unknown part {part!r}; valid parts: {', '.join(self.parts)}") from None

    def clamp(self, name: str, deg: float) -> float:
        j = self.joint(name)
        if math.isnan(deg):
            raise ValueError(f"joint {name}: target is NaN; send a number of degrees in [{j.lower}, {j.upper}]")
        return min(max(float(deg), j.lower), j.upper)

    def home_pose(self) -> dict[str, float]:
        return {j.name: j.home for j in self.joints}

    def narrowed(self, limits: Mapping[str, Mapping[str, float]]) -> RobotModel:
        """A copy limited to what a robot reports for its joints ({name: {lower, upper, max_velocity}}, each key
        optional): each range is the intersection of the robot's and this model's (the narrower wins), each velocity
        cap the smaller of the two, and each home is moved inside its new range. Joints the robot does not name keep
        the model's values; a range whose intersection is empty fails, naming the joint."""
        joints = []
        for j in self.joints:
            reported = limits.get(j.name)
            if not reported:
                joints.append(j)
                continue
            lower = max(j.lower, float(reported.get("lower", j.lower)))
            upper = min(j.upper, float(reported.get("upper", j.upper)))
            if not (math.isfinite(lower) and math.isfinite(upper) and lower < upper):
                raise ValueError(f"joint {j.name}: the robot's range {reported.get('lower')} .. "
                                 f"{reported.get('upper')} deg does not overlap the model's {j.lower} .. {j.upper}")
            cap = float(reported.get("max_velocity", j.max_velocity))
            cap = min(j.max_velocity, cap) if math.isfinite(cap) and cap > 0 else j.max_velocity
            joints.append(dataclasses.replace(j, lower=lower, upper=upper, home=min(max(j.home, lower), upper),
                                              max_velocity=cap))
        return dataclasses.replace(self, joints=tuple(joints))

    def with_velocity_caps(self, caps: Mapping[str, float]) -> RobotModel:
        """A copy with some joints' velocity caps (deg/s) replaced; unknown joints or non-positive caps fail."""
        for name, cap in caps.items():
            self.joint(name)
            if not (isinstance(cap, (int, float)) and math.isfinite(cap) and cap > 0):
                raise ValueError(f"velocity cap for {name} must be a positive number of deg/s, got {cap!r}")
        joints = tuple(
            dataclasses.replace(j, max_velocity=float(caps[j.name])) if j.name in caps else j for j in self.joints
        )
        return dataclasses.replace(self, joints=joints)


def _vec3(value: Any, where: str) -> tuple[float, float, float]:
    if not (isinstance(value, (list, tuple)) and len(value) == 3):
        raise ValueError(f"{where}: expected a list of 3 numbers, got {value!r}")
    return (float(value[0]), float(value[1]), float(value[2]))


def _parse(doc: Mapping[str, Any], source: str) -> RobotModel:
    try:
        joints = []
        for j in doc["joints"]:
            joint = Joint(
                name=str(j["name"]), part=str(j["part"]), lower=float(j["lower"]), upper=float(j["upper"]),
                home=float(j["home"]), max_velocity=float(j["max_velocity"]),
            )
            if joint.part not in PARTS:
                raise ValueError(f"joint {joint.name}: part {joint.part!r} is not one of {PARTS}")
            if not joint.lower <= joint.home <= joint.upper:
                raise ValueError(f"joint {joint.name}: home {joint.home} outside [{joint.lower}, {joint.upper}]")
            if joint.max_velocity <= 0:
                raise ValueError(f"joint {joint.name}: max_velocity must be > 0")
            joints.append(joint)
        chain = []
        known = {"base_link"}
        for c in doc["chain"]:
            el = ChainElement(
                name=str(c["name"]), parent=str(c["parent"]), type=str(c["type"]),
                xyz=_vec3(c["xyz"], f"chain {c['name']} xyz"),
                rpy_deg=_vec3(c["rpy_deg"], f"chain {c['name']} rpy_deg"),
                axis=_vec3(c["axis"], f"chain {c['name']} axis") if c.get("axis") is not None else None,
            )
            if el.parent not in known:
                raise ValueError(f"chain {el.name}: parent {el.parent!r} must be base_link or an earlier element")
            if el.type not in ("revolute", "fixed") or (el.type == "revolute") != (el.axis is not None):
                raise ValueError(f"chain {el.name}: type must be revolute (with axis) or fixed (without)")
            known.add(el.name)
            chain.append(el)
        revolute = {c.name for c in chain if c.type == "revolute"}
        if revolute != {j.name for j in joints}:
            raise ValueError(f"chain revolute joints {sorted(revolute)} differ from joints "
                             f"{sorted(j.name for j in joints)}")
        cam = doc["camera"]
        camera = CameraIntrinsics(int(cam["width"]), int(cam["height"]), float(cam["fx"]), float(cam["fy"]),
                                  float(cam["cx"]), float(cam["cy"]))
        g = doc["geometry"]
        geometry = Geometry(
            torso_radius=float(g["torso"]["radius"]), torso_length=float(g["torso"]["length"]),
            torso_top_z=float(g["torso"]["top_z"]),
            head_semi_axes=_vec3(g["head"]["semi_axes"], "geometry head semi_axes"),
            head_center_above_pitch=float(g["head"]["center_above_pitch"]),
            face_width=float(g["face_screen"]["width"]), face_height=float(g["face_screen"]["height"]),
            face_thickness=float(g["face_screen"]["thickness"]),
            camera_box=_vec3(g["camera_box"], "geometry camera_box"),
            upper_arm_radius=float(g["upper_arm_radius"]), forearm_radius=float(g["forearm_radius"]),
            hand_radius=float(g["hand_radius"]),
        )
        return RobotModel(joints=tuple(joints), chain=tuple(chain), camera=camera, geometry=geometry,
                          name=str(doc.get("robot", "QTrobot")),
                          emotions=tuple(str(e) for e in doc.get("emotions", ())),
                          gestures=tuple(str(g) for g in doc.get("gestures", ())))
    except (KeyError, TypeError) as exc:
        raise ValueError(f"{source}: malformed robot description ({exc!r}); "
                         "compare it with the packaged robot_models/data/qtrobot.yaml") from exc


def load_qtrobot(path: str | Path | None = None) -> RobotModel:
    """Load QTrobot's description; `path` overrides the packaged robot_models/data/qtrobot.yaml."""
    if path is None:
        file, source = resources.files("robot_models").joinpath("data/qtrobot.yaml"), "robot_models/data/qtrobot.yaml"
    else:
        file, source = Path(path), str(path)
    doc = read_document(file, shown=source)
    if not isinstance(doc, Mapping):
        raise ValueError(f"{source}: expected a mapping at top level")
    return _parse(doc, source)
