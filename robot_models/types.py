"""Value types the stand-in (sim) and the server's robot interface both speak, defined once here, below both."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Any


class MotorMode(enum.IntEnum):
    """LuxAI's /qt_robot/motors/setControlMode values."""

    ON = 0  # M_ON: the motor follows commands
    OFF = 1  # M_OFF: no torque; the link can be moved by hand (and falls under gravity)
    BRAKE = 2  # M_BREAK: hold the current position and ignore commands


@dataclass(frozen=True)
class CapturePose:
    """The robot's head (HeadYaw, HeadPitch, degrees) at the moment a camera frame was taken.

    `source` "render": the stand-in's, exactly the pose its render used (gap_s 0). "joint_states": a real robot's,
    interpolated between the joint states around the frame's stamp (robot/head_history.py); gap_s is how far (s)
    the frame's stamp lies from the nearest joint state used, so a consumer can tell a close estimate from a stale
    one."""

    yaw: float
    pitch: float
    gap_s: float = 0.0
    source: str = "render"


@dataclass(frozen=True)
class CameraFrame:
    """One frame from the head camera; whoever holds frames keeps only the newest.

    `jpeg` is empty when nobody asked for JPEG (see Robot.live_frames); the stand-in's frames also carry `ring`,
    the worker_process.frame_ring.FrameRing whose slot holds the frame's RGB pixels under its seq (until newer
    frames overwrite it), which the video encoder reads instead of decompressing a JPEG."""

    jpeg: bytes
    width: int
    height: int
    seq: int
    stamp_monotonic: float  # time.monotonic() when the image was taken
    stamp_wall: float  # time.time() at the same moment, for message headers
    # The stand-in's own figures (None from a real camera): simulated time, and what rendering and encoding cost.
    sim_time: float | None = None
    render_ms: float | None = None
    encode_ms: float | None = None
    ring: Any = field(default=None, repr=False, compare=False)
    pose: CapturePose | None = None  # the head's pose when it was taken (None: not known)
