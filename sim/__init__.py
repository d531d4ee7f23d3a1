"""sim: the MuJoCo stand-in for QTrobot (classroom scene, physics and camera threads, face screen).

MuJoCo picks its OpenGL backend when it is imported; a headless machine needs EGL, so default to it here,
before any sim module imports mujoco. An explicit MUJOCO_GL in the environment wins.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

from .standin import CameraFrame, JointSnapshot, MotorMode, PhysicsStats, StandIn  # noqa: E402

__all__ = ["CameraFrame", "JointSnapshot", "MotorMode", "PhysicsStats", "StandIn"]
