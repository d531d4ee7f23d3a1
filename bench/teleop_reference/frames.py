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
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

# The one frame id under which poses are in Unity's own left-handed axes (x right, y up, z forward). Every other
# frame id (ROS#'s "Unity" included: its PoseStampedPublisher converts before sending) means ROS axes (REP 103).
UNITY_FRAME_ID = "unity_left_handed"

UNITY_TO_ROS = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
UNITY_TO_ROS.setflags(write=False)
_AXIS_SIGN = round(float(np.linalg.det(UNITY_TO_ROS)))  # -1: rotation axes are pseudovectors

# Unity floats are single precision, but clients often round JSON to 3-4 decimals: rounding each component to
# 3 decimals alone moves the norm by up to ~2e-3, so 1e-3 would reject honest messages. 1e-2 accepts those and
# still rejects anything that is not meant to be a rotation (a zero, a scaled or a half-filled quaternion).
DEFAULT_QUATERNION_NORM_TOLERANCE = 1e-2


@dataclass(frozen=True, slots=True)
class Pose:
    """A validated pose in ROS convention: position in metres and a unit rotation (also as a matrix, which the
    per-frame maths uses: a 3x3 product costs a microsecond, a scipy Rotation operation tens)."""

    position: np.ndarray
    rotation: Rotation
    frame_id: str = ""
    matrix: np.ndarray = field(default=None, compare=False)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if self.matrix is None:
            object.__setattr__(self, "matrix", self.rotation.as_matrix())


def unity_to_ros_position(xyz: Any) -> np.ndarray:
    return UNITY_TO_ROS @ np.asarray(xyz, dtype=float).reshape(3)


def unity_to_ros_quaternion(xyzw: Any) -> np.ndarray:
    """Quaternion (x, y, z, w) from Unity's axes to ROS's; see the module docstring for the derivation."""
    q = np.asarray(xyzw, dtype=float).reshape(4)
    axis_part = _AXIS_SIGN * (UNITY_TO_ROS @ q[:3])
    return np.append(axis_part, q[3])


def check_vector(values: Any, field: str, size: int) -> np.ndarray:
    """`values` as a float array of `size` finite numbers, or a ValueError naming `field`."""
    try:
        arr = np.asarray(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{field}: expected {size} numbers, got {values!r}") from None
    if arr.size != size:
        raise ValueError(f"{field}: expected {size} numbers, got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{field}: contains NaN or infinity ({arr.tolist()}); send finite numbers")
    return arr


def check_quaternion(xyzw: Any, field: str, tolerance: float = DEFAULT_QUATERNION_NORM_TOLERANCE) -> np.ndarray:
    """A finite quaternion whose norm is 1 within `tolerance`, renormalised; else a ValueError naming `field`."""
    q = check_vector(xyzw, field, 4)
    with np.errstate(over="ignore"):  # a huge component overflows to an infinite norm, refused below
        norm = float(np.linalg.norm(q))
    if norm == 0.0:
        raise ValueError(f"{field}: the zero quaternion is not a rotation; send a unit quaternion (w=1 for none)")
    if abs(norm - 1.0) > tolerance:
        raise ValueError(
            f"{field}: quaternion norm {norm:.4g} is not 1 (tolerance {tolerance:g}); send a unit quaternion"
        )
    return q / norm


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
    position = check_vector(_xyz(_get(body, "position", prefix or "pose"), f"{dot}position", "xyz"),
                            f"{dot}position", 3)
    orientation = check_quaternion(_xyz(_get(body, "orientation", prefix or "pose"), f"{dot}orientation", "xyzw"),
                                   f"{dot}orientation", quaternion_tolerance)
    return make_pose(position, orientation, frame_id)


def make_pose(position: Any, orientation_xyzw: Any, frame_id: str = "") -> Pose:
    """A Pose from already-validated numbers, converting from Unity's axes if frame_id says "unity_left_handed"."""
    if frame_id.strip().lower() == UNITY_FRAME_ID:
        position = unity_to_ros_position(position)
        orientation_xyzw = unity_to_ros_quaternion(orientation_xyzw)
    return Pose(np.asarray(position, dtype=float).reshape(3), Rotation.from_quat(orientation_xyzw), frame_id)


def heading(rotation: Rotation | np.ndarray) -> float:
    """Yaw (radians, about world z) of the body's forward (x) axis: the compass direction it faces."""
    m = rotation if isinstance(rotation, np.ndarray) else rotation.as_matrix()
    return math.atan2(m[1, 0], m[0, 0])
