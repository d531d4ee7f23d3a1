"""Poses from the headset, validated and expressed in ROS's frame (REP 103: x forward, y left, z up).

Unity is left-handed (x right, y up, z forward). A Unity vector v has ROS coordinates M v with

    M = [[0, 0, 1], [-1, 0, 0], [0, 1, 0]]      i.e. (x, y, z)_unity -> (z, -x, y)_ros

det(M) = -1: the change of basis includes a reflection. A Unity quaternion q encodes the rotation matrix R_u
by the usual formula (Unity's left-handedness lives in its axes, not in the quaternion algebra, which is why
a positive turn about Unity's y looks clockwise from above). The same physical rotation written in ROS
coordinates is M R_u M^T, still a proper rotation. Its angle is unchanged, but its axis is a pseudovector, so it
maps to det(M) M axis = -M axis. Hence q_ros = (-M q_xyz, q_w) = (-q_z, q_x, -q_y, q_w), the conversion ROS#
and Unity's ROS-TCP-Connector use. Tests check it against the matrix conjugation and known turns.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

# The one frame id under which poses are in Unity's own left-handed axes (x right, y up, z forward). Every other
# frame id (ROS#'s "Unity" included: its PoseStampedPublisher converts before sending) means ROS axes (REP 103).
UNITY_FRAME_ID = "unity_left_handed"

UNITY_TO_ROS = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
UNITY_TO_ROS.setflags(write=False)

# Unity floats are single precision, but clients often round JSON to 3-4 decimals: rounding each component to
# 3 decimals alone moves the norm by up to ~2e-3, so 1e-3 would reject honest messages. 1e-2 accepts those and
# still rejects anything that is not meant to be a rotation (a zero, a scaled or a half-filled quaternion).
DEFAULT_QUATERNION_NORM_TOLERANCE = 1e-2


class Pose:
    """A validated pose in ROS convention: position in metres and a unit quaternion (x, y, z, w), as plain floats.

    The per-frame maths reads `xyz` and `forward`: scalar arithmetic, since a NumPy or scipy call on a 3-vector
    costs microseconds, which was most of a teleop step. `position`, `rotation` and `matrix` build the array
    forms on demand (calibration, tests)."""

    __slots__ = ("xyz", "quat", "frame_id")

    def __init__(self, xyz: tuple[float, float, float], quat: tuple[float, float, float, float],
                 frame_id: str = "") -> None:
        self.xyz = xyz
        self.quat = quat
        self.frame_id = frame_id

    @property
    def position(self) -> np.ndarray:
        return np.array(self.xyz)

    @property
    def rotation(self) -> Rotation:
        return Rotation.from_quat(self.quat)

    @property
    def matrix(self) -> np.ndarray:
        return self.rotation.as_matrix()

    @property
    def forward(self) -> tuple[float, float, float]:
        """The body's x axis (R e_x) in the tracking space: the rotation matrix's first column."""
        x, y, z, w = self.quat
        return (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + z * w), 2.0 * (x * z - y * w))

    def __repr__(self) -> str:
        return f"Pose(xyz={self.xyz}, quat={self.quat}, frame_id={self.frame_id!r})"


def _unity_position(x: float, y: float, z: float) -> tuple[float, float, float]:
    """UNITY_TO_ROS v: (x, y, z)_unity -> (z, -x, y)_ros."""
    return (z, -x, y)


def _unity_quaternion(x: float, y: float, z: float, w: float) -> tuple[float, float, float, float]:
    """(det(M) M q_xyz, q_w) = (-q_z, q_x, -q_y, q_w); see the module docstring for the derivation."""
    return (-z, x, -y, w)


def unity_to_ros_position(xyz: Any) -> np.ndarray:
    return np.array(_unity_position(*np.asarray(xyz, dtype=float).reshape(3).tolist()))


def unity_to_ros_quaternion(xyzw: Any) -> np.ndarray:
    """Quaternion (x, y, z, w) from Unity's axes to ROS's; see the module docstring for the derivation."""
    return np.array(_unity_quaternion(*np.asarray(xyzw, dtype=float).reshape(4).tolist()))


def check_floats(values: Iterable[Any], field: str, size: int | None = None) -> list[float]:
    """`values` as finite floats (`size` of them, if given), or a ValueError naming `field`."""
    what = f"{size} numbers" if size is not None else "numbers"
    try:
        out = [float(v) for v in values]
    except (TypeError, ValueError):
        raise ValueError(f"{field}: expected {what}, got {values!r}") from None
    if size is not None and len(out) != size:
        raise ValueError(f"{field}: expected {size} numbers, got {len(out)}")
    for v in out:
        if not math.isfinite(v):
            raise ValueError(f"{field}: contains NaN or infinity ({out}); send finite numbers")
    return out


def check_quaternion(xyzw: Any, field: str, tolerance: float = DEFAULT_QUATERNION_NORM_TOLERANCE
                     ) -> tuple[float, float, float, float]:
    """A finite quaternion whose norm is 1 within `tolerance`, renormalised; else a ValueError naming `field`."""
    x, y, z, w = check_floats(xyzw, field, 4)
    norm = math.sqrt(x * x + y * y + z * z + w * w)  # a huge component overflows to an infinite norm, refused below
    if norm == 0.0:
        raise ValueError(f"{field}: the zero quaternion is not a rotation; send a unit quaternion (w=1 for none)")
    if abs(norm - 1.0) > tolerance:
        raise ValueError(
            f"{field}: quaternion norm {norm:.4g} is not 1 (tolerance {tolerance:g}); send a unit quaternion"
        )
    return (x / norm, y / norm, z / norm, w / norm)


def _get(msg: Mapping[str, Any], key: str, field: str) -> Any:
    if not isinstance(msg, Mapping):
        raise ValueError(f"{field}: expected an object, got {type(msg).__name__}")
    if key not in msg:
        raise ValueError(f"{field}.{key}: missing")
    return msg[key]


def _xyz(msg: Any, field: str, keys: str) -> list[Any]:
    return [_get(msg, k, field) for k in keys]


def pose_from_message(
    msg: Mapping[str, Any] | Any, *, quaternion_tolerance: float = DEFAULT_QUATERNION_NORM_TOLERANCE
) -> Pose:
    """A geometry_msgs/PoseStamped (or bare Pose) as a dict, converted to ROS's frame and validated.

    header.frame_id "unity_left_handed" (case and surrounding spaces ignored) marks Unity's axes; any other frame id, or a
    bare Pose, is taken as already right-handed ROS (x forward, y left, z up). Raises ValueError naming the
    offending field, e.g. "pose.orientation: quaternion norm 0.5 is not 1".
    """
    if hasattr(msg, "model_dump"):
        msg = msg.model_dump()
    if not isinstance(msg, Mapping):
        raise ValueError(f"pose message: expected an object, got {type(msg).__name__}")
    if "pose" in msg:
        header = msg.get("header") or {}
        frame_id = header.get("frame_id", "") if isinstance(header, Mapping) else ""
        if not isinstance(frame_id, str):
            raise ValueError(f"header.frame_id: expected a string, got {frame_id!r}")
        body, prefix = msg["pose"], "pose"
    else:
        frame_id, body, prefix = "", msg, ""
    dot = f"{prefix}." if prefix else ""
    position = check_floats(_xyz(_get(body, "position", prefix or "pose"), f"{dot}position", "xyz"),
                            f"{dot}position", 3)
    orientation = check_quaternion(_xyz(_get(body, "orientation", prefix or "pose"), f"{dot}orientation", "xyzw"),
                                   f"{dot}orientation", quaternion_tolerance)
    return _pose(position, orientation, frame_id)


def _pose(position: Sequence[float], q: Sequence[float], frame_id: str) -> Pose:
    if frame_id and frame_id.strip().lower() == UNITY_FRAME_ID:
        return Pose(_unity_position(*position), _unity_quaternion(*q), frame_id)
    return Pose((position[0], position[1], position[2]), (q[0], q[1], q[2], q[3]), frame_id)


def make_pose(position: Any, orientation_xyzw: Any, frame_id: str = "") -> Pose:
    """A Pose from already-validated numbers, converting from Unity's axes if frame_id says "unity_left_handed".
    The quaternion is normalised; one that is zero or not finite is refused."""
    xyz = np.asarray(position, dtype=float).reshape(3).tolist()
    q = np.asarray(orientation_xyzw, dtype=float).reshape(4).tolist()
    norm = math.sqrt(sum(c * c for c in q))
    if not (norm > 0.0 and math.isfinite(norm)):
        raise ValueError(f"orientation: {q} is not a rotation; send a unit quaternion (w=1 for none)")
    return _pose(xyz, [c / norm for c in q], frame_id)


def heading(rotation: Rotation | np.ndarray) -> float:
    """Yaw (radians, about world z) of the body's forward (x) axis: the compass direction it faces."""
    m = rotation if isinstance(rotation, np.ndarray) else rotation.as_matrix()
    return math.atan2(m[1, 0], m[0, 0])
