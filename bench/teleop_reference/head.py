"""Operator head orientation -> QTrobot HeadYaw and HeadPitch (degrees, unclamped; safety clamps last).

Angles are the intrinsic Z-Y-X (yaw, then pitch, roll discarded) decomposition of R_zero^-1 R, the head's
rotation relative to the orientation captured at engage, in ROS's frame. For R = Rz(yaw) Ry(pitch) Rx(roll)
the forward axis R e_x is (cos p cos y, cos p sin y, -sin p), so yaw = atan2(f_y, f_x) and
pitch = atan2(-f_z, hypot(f_x, f_y)): the same yaw and pitch scipy's as_euler("ZYX") gives (a test checks),
without its gimbal-lock warning and with a handle on the singularity: when cos(pitch) is tiny, yaw is
undefined, so the previous yaw is held.

Signs, from QTrobot's URDF (REP 103 base frame, x forward, y left, z up):
- HeadYaw turns about +z, so positive = looking LEFT; the operator's yaw to the left is positive too.
- HeadPitch turns about +y. With x forward and z up, a positive turn about +y tilts the nose DOWN
  (R_y(+a) e_x = (cos a, 0, -sin a)). So positive HeadPitch = looking down, and its range -15..25 means QTrobot
  can look 25 deg down but only 15 deg up. The operator's Z-Y-X pitch has the same sign (down is positive).
Both map 1:1 by default (configurable scales).

Yaw is unwrapped against the previous sample so that turning through +-180 deg behind the operator does not
swing the robot from one side to the other; it re-wraps only once it has gone `wrap_hysteresis_deg` past
+-180, so a head held near 180 deg cannot chatter between the limits.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation


def yaw_pitch_deg(relative: Rotation | np.ndarray) -> tuple[float, float, float]:
    """(yaw, pitch, cos(pitch)) of a rotation (or its matrix), intrinsic Z-Y-X, degrees."""
    m = relative if isinstance(relative, np.ndarray) else relative.as_matrix()
    fx, fy, fz = m[0, 0], m[1, 0], m[2, 0]
    horizontal = math.hypot(fx, fy)
    return math.degrees(math.atan2(fy, fx)), math.degrees(math.atan2(-fz, horizontal)), horizontal


class HeadTracker:
    """Holds the calibrated zero, the unwrapped yaw and the last good yaw; one per operator."""

    def __init__(
        self,
        yaw_scale: float = 1.0,
        pitch_scale: float = 1.0,
        wrap_hysteresis_deg: float = 90.0,
        gimbal_margin_deg: float = 5.0,
    ) -> None:
        self.yaw_scale = yaw_scale
        self.pitch_scale = pitch_scale
        self.wrap_hysteresis_deg = wrap_hysteresis_deg
        self._min_cos_pitch = math.sin(math.radians(gimbal_margin_deg))
        self._zero_inv: np.ndarray | None = None  # R_zero^-1 as a matrix (its transpose)
        self._yaw: float | None = None  # unwrapped, operator degrees

    @property
    def calibrated(self) -> bool:
        return self._zero_inv is not None

    def set_zero(self, rotation: Rotation) -> None:
        """Capture the orientation that means "looking straight ahead" (robot head at 0, 0)."""
        self._zero_inv = rotation.as_matrix().T
        self._yaw = 0.0

    def clear(self) -> None:
        self._zero_inv = None
        self._yaw = None

    def update(self, rotation: Rotation | np.ndarray) -> tuple[float, float]:
        """(HeadYaw, HeadPitch) targets in degrees for the head's current orientation (Rotation or matrix)."""
        if self._zero_inv is None:
            raise RuntimeError("head zero not captured; engage before mapping head poses")
        m = rotation if isinstance(rotation, np.ndarray) else rotation.as_matrix()
        yaw, pitch, cos_pitch = yaw_pitch_deg(self._zero_inv @ m)
        prev = self._yaw if self._yaw is not None else 0.0
        if cos_pitch < self._min_cos_pitch:
            yaw = prev  # looking (almost) straight up or down: heading undefined, keep the last one
        else:
            yaw = prev + (yaw - prev + 180.0) % 360.0 - 180.0  # nearest equivalent of yaw to prev
            limit = 180.0 + self.wrap_hysteresis_deg
            if abs(yaw) > limit:
                yaw = (yaw + 180.0) % 360.0 - 180.0
        self._yaw = yaw
        return yaw * self.yaw_scale, pitch * self.pitch_scale
