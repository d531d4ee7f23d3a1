"""The operator's body, estimated from the headset, and the mapping of a hand onto QTrobot's arm.

Operator model (metres, ROS axes of the tracking space, z up). Only the head and the hands are tracked, so
the shoulders are estimated:

    neck     = eyes + Rz(head heading) (-eye_to_neck_back, 0, 0)    the neck is behind the eyes and turns with
                                                                     the head's yaw; head pitch and roll ignored
    centre   = neck - (0, 0, eye_to_shoulder_drop)                  shoulder line below the eyes
    shoulder = centre + Rz(torso heading) (0, +-shoulder_half_width, 0)      (+ left, - right)

Defaults are adult anthropometry, rounded: eye height minus shoulder (acromion) height is about 0.20 m both
standing and seated; the eyes are about 0.08 m ahead of the neck's axis; biacromial breadth about 0.38 m;
shoulder to the grip of a held controller about 0.60 m. A calibration pose replaces them with the operator's.

The torso heading is captured at engage (the operator faces the robot's view) and follows the head's heading
by `torso_yaw_follow` (0 = not at all, 1 = fully). Following the head fully would make the robot's arms move
whenever the operator merely looks around, so the default is 0; a swivel chair is handled by re-engaging.

Hand mapping: d = controller - shoulder, expressed in the torso frame, is scaled by
robot_reach / operator_arm_length and added to the robot's shoulder, then solved by arm_ik (which moves
unreachable targets to the nearest reachable point). QTrobot's "shoulder" here is the ShoulderRoll joint, the
point the upper arm swings about, and its reach is upper arm + forearm (0.077 + 0.184 = 0.261 m, read from FK),
so an operator arm held straight in any direction asks for the robot arm straight in that direction. (The
0.306 m "shoulder to hand" figure adds the 0.0445 m pitch-to-roll offset, which lies along the shoulder axis
and adds no reach.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from robot_models import RobotModel, forward_kinematics

from .frames import Pose, heading

SIDES = ("left", "right")


@dataclass(frozen=True)
class BodyModel:
    eye_to_neck_back_m: float = 0.08
    eye_to_shoulder_drop_m: float = 0.20
    shoulder_half_width_m: float = 0.19
    arm_length_m: float = 0.60


def _rz(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def shoulder_positions(body: BodyModel, head: Pose, torso_heading: float) -> dict[str, np.ndarray]:
    """Estimated operator shoulders (tracking space) from the head pose."""
    fx, fy, _ = head.forward
    return {side: np.array(p) for side, p in zip(SIDES, shoulder_points(body, head.xyz, math.atan2(fy, fx),
                                                                         torso_heading))}


def shoulder_points(body: BodyModel, eyes: tuple[float, float, float], head_heading: float, torso_heading: float
                    ) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """(left, right) shoulders as plain floats: the per-frame form of shoulder_positions."""
    back, half = body.eye_to_neck_back_m, body.shoulder_half_width_m
    cx = eyes[0] - back * math.cos(head_heading)
    cy = eyes[1] - back * math.sin(head_heading)
    cz = eyes[2] - body.eye_to_shoulder_drop_m
    lx, ly = -half * math.sin(torso_heading), half * math.cos(torso_heading)
    return (cx + lx, cy + ly, cz), (cx - lx, cy - ly, cz)


def _check_range(value: float, lo: float, hi: float, what: str, hint: str) -> None:
    if not lo <= value <= hi:
        raise ValueError(f"calibration: {what} came out {value:.2f} m, outside {lo}..{hi} m; {hint}")


def calibrate_t_pose(head: Pose, left: Pose, right: Pose, defaults: BodyModel = BodyModel()) -> tuple[BodyModel, float]:
    """Body dimensions and torso heading from a T-pose: arms straight out to the sides at shoulder height.

    The controllers then lie on the shoulder line: their mean height gives the shoulder drop, their midpoint
    (against the eyes) the neck offset, half their span minus the shoulder half-width the arm length, and the
    line from right to left hand the torso heading. The shoulder width itself is not observable and is kept.
    """
    hint = "stand facing forward with both arms straight out to the sides at shoulder height, then calibrate"
    span_vec = left.position - right.position
    horiz = float(np.hypot(span_vec[0], span_vec[1]))
    _check_range(horiz, 0.9, 2.4, "the distance between the controllers", hint)
    torso_heading = math.atan2(span_vec[1], span_vec[0]) - math.pi / 2  # left is +90 deg from forward
    face = heading(head.rotation)
    if abs(math.remainder(face - torso_heading, 2 * math.pi)) > math.radians(45):
        raise ValueError(f"calibration: the head faces {math.degrees(face - torso_heading):.0f} deg away from the "
                         f"chest the arms imply; {hint}")
    mid = (left.position + right.position) / 2
    drop = float(head.position[2] - mid[2])
    _check_range(drop, 0.05, 0.45, "the drop from eyes to shoulders", hint)
    back = float(-(_rz(-torso_heading) @ (mid - head.position))[0])
    back = min(max(back, 0.0), 0.20)  # arms a little forward or back of the true line: keep it plausible
    arm = horiz / 2 - defaults.shoulder_half_width_m
    _check_range(arm, 0.35, 1.0, "the arm length", hint)
    return replace(defaults, eye_to_neck_back_m=back, eye_to_shoulder_drop_m=drop, arm_length_m=arm), torso_heading


def calibrate_forward(head: Pose, left: Pose, right: Pose, defaults: BodyModel = BodyModel()) -> tuple[BodyModel, float]:
    """Body dimensions and torso heading from both arms held straight forward, parallel, at shoulder height.

    The hands' mean height gives the shoulder drop, their sideways spacing the shoulder width, and their
    forward distance from the estimated neck (default neck offset) the arm length.
    """
    hint = "face forward with both arms straight ahead at shoulder height, hands shoulder-width apart, then calibrate"
    torso_heading = heading(head.rotation)
    to_torso = _rz(-torso_heading)
    l_t = to_torso @ (left.position - head.position)
    r_t = to_torso @ (right.position - head.position)
    half_width = float(l_t[1] - r_t[1]) / 2
    _check_range(half_width, 0.10, 0.35, "half the sideways spacing of the hands", hint)
    drop = float(-(l_t[2] + r_t[2]) / 2)
    _check_range(drop, 0.05, 0.45, "the drop from eyes to shoulders", hint)
    # The hands lie forward of the shoulders by the arm length; the shoulders are behind the eyes by the neck offset.
    arm = float((l_t[0] + r_t[0]) / 2) + defaults.eye_to_neck_back_m
    _check_range(arm, 0.35, 1.0, "the arm length", hint)
    return replace(defaults, eye_to_shoulder_drop_m=drop, shoulder_half_width_m=half_width, arm_length_m=arm), torso_heading


@dataclass(frozen=True)
class RobotArms:
    """QTrobot's shoulder (ShoulderRoll joint) positions in the base frame and the arm's reach, from FK."""

    shoulder: dict[str, np.ndarray]
    reach_m: float


def robot_arms(model: RobotModel) -> RobotArms:
    frames = forward_kinematics(model, {})
    shoulders, reaches = {}, []
    for side in SIDES:
        p = side.capitalize()
        s = frames[f"{p}ShoulderRoll"][:3, 3]
        e = frames[f"{p}ElbowRoll"][:3, 3]
        h = frames[f"{side}_hand"][:3, 3]
        shoulders[side] = s.copy()
        reaches.append(float(np.linalg.norm(e - s) + np.linalg.norm(h - e)))
    return RobotArms(shoulders, min(reaches))


def hand_target(
    side: str, controller: np.ndarray, shoulder: np.ndarray, torso_heading: float, scale: float, robot: RobotArms
) -> np.ndarray:
    """The robot hand target (base frame, metres) for one controller position (tracking space)."""
    c, s = (tuple(float(v) for v in a) for a in (controller, shoulder))
    origin = tuple(float(v) for v in robot.shoulder[side])
    return np.array(hand_point(c, s, math.cos(torso_heading), math.sin(torso_heading), scale, origin))


def hand_point(controller: tuple[float, float, float], shoulder: tuple[float, float, float], cos_torso: float,
               sin_torso: float, scale: float, robot_shoulder: tuple[float, float, float]
               ) -> tuple[float, float, float]:
    """hand_target as plain floats: robot_shoulder + scale Rz(-torso) (controller - shoulder)."""
    dx, dy, dz = controller[0] - shoulder[0], controller[1] - shoulder[1], controller[2] - shoulder[2]
    return (robot_shoulder[0] + scale * (cos_torso * dx + sin_torso * dy),
            robot_shoulder[1] + scale * (-sin_torso * dx + cos_torso * dy),
            robot_shoulder[2] + scale * dz)
