"""Arm mapping: body model, calibration, and arms straight forward, down and to the side, end to end from Unity."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from robot_models import arm_ik, forward_kinematics, load_qtrobot
from vr_teleop_server.teleop import BodyModel, TeleopMapper, make_pose
from vr_teleop_server.teleop.body import (
    calibrate_forward, calibrate_t_pose, hand_target, robot_arms, shoulder_positions,
)

MODEL = load_qtrobot()
ZERO = forward_kinematics(MODEL, {})
BODY = BodyModel()  # defaults: neck 0.08 behind the eyes, shoulders 0.20 below, half-width 0.19, arm 0.60
EYES_UNITY = np.array([0.0, 1.2, 0.0])  # seated operator, Unity axes (x right, y up, z forward)


def link_lengths(side):
    p = side.capitalize()
    roll, elbow, hand = (ZERO[k][:3, 3] for k in (f"{p}ShoulderRoll", f"{p}ElbowRoll", f"{side}_hand"))
    return float(np.linalg.norm(elbow - roll)), float(np.linalg.norm(hand - elbow)), roll


def planar_expectation(d, l1, l2):
    """Roll and elbow (deg) for the hand at distance d from the roll joint along the swing direction (roll=-90).

    In the plane of the two parallel roll axes, the elbow's interior angle follows from the law of cosines;
    QTrobot's elbow limits are negative, so the elbow bends to the negative side; the upper arm then leads the
    target direction by the triangle's angle at the shoulder.
    """
    q3 = -math.acos((d * d - l1 * l1 - l2 * l2) / (2 * l1 * l2))
    lead = math.atan2(l2 * math.sin(-q3), l1 + l2 * math.cos(q3))
    return math.degrees(-math.pi / 2 + lead), math.degrees(q3)


def unity_pose(pos, quat=(0, 0, 0, 1)):
    return make_pose(pos, quat, "unity_left_handed")


def engaged_mapper(head_quat=(0, 0, 0, 1), **settings):
    from vr_teleop_server.teleop import TeleopSettings

    m = TeleopMapper(MODEL, TeleopSettings(**settings))
    m.on_head_pose(unity_pose(EYES_UNITY, head_quat), 0.0)
    m.engage(0.0)
    return m


def drive(m, left_unity, right_unity, seconds=4.0, t0=0.0, head_quat=(0, 0, 0, 1), grip=1.0, rate=90.0):
    out = None
    for i in range(1, int(seconds * rate) + 1):
        t = t0 + i / rate
        m.on_head_pose(unity_pose(EYES_UNITY, head_quat), t)
        for side, pos in (("left", left_unity), ("right", right_unity)):
            m.on_controller_pose(side, unity_pose(pos), t)
            m.on_joy(side, [0.0, 0.0, 0.0, grip], [0, 0, 0, 0], t)
        out = m.step(t)
    return out


def shoulder_unity(side):
    """Where the default body model puts the operator's shoulders, in Unity axes."""
    sign = -1.0 if side == "left" else 1.0  # Unity x is right
    return EYES_UNITY + np.array([sign * BODY.shoulder_half_width_m, -BODY.eye_to_shoulder_drop_m,
                                  -BODY.eye_to_neck_back_m])


@pytest.mark.parametrize("direction", ["forward", "down"])
def test_arms_straight_forward_and_down(direction):
    k = 0.9  # hands at 90% of arm length: within the robot's reach
    offset = {"forward": np.array([0, 0, 1.0]), "down": np.array([0, -1.0, 0])}[direction] * k * BODY.arm_length_m
    m = engaged_mapper()
    out = drive(m, shoulder_unity("left") + offset, shoulder_unity("right") + offset)
    assert out.arms_following == {"left": True, "right": True}
    reach = robot_arms(MODEL).reach_m
    for side in ("left", "right"):
        l1, l2, roll_joint = link_lengths(side)
        exp_roll, exp_elbow = planar_expectation(k * reach, l1, l2)
        # Pitch turns the swing direction: left 0 = forward, +90 = down; the right arm's frame is mirrored.
        exp_pitch = {"forward": 0.0, "down": 90.0}[direction] * (1 if side == "left" else -1)
        got = out.commands[f"{side}_arm"]
        assert got == pytest.approx((exp_pitch, exp_roll, exp_elbow), abs=1e-3), side
        assert out.ik[side].reached
        target = roll_joint + k * reach * {"forward": np.array([1, 0, 0]), "down": np.array([0, 0, -1])}[direction]
        hand = forward_kinematics(MODEL, dict(zip(MODEL.parts[f"{side}_arm"], got)))[f"{side}_hand"][:3, 3]
        np.testing.assert_allclose(hand, target, atol=1e-5)
    assert out.clamped == ()


def test_arms_out_to_the_side_t_pose_reach_the_nearest_point():
    lateral = np.array([BODY.arm_length_m, 0, 0])  # Unity x is right
    m = engaged_mapper()
    out = drive(m, shoulder_unity("left") - lateral, shoulder_unity("right") + lateral)
    elbow_limit = MODEL.joint("LeftElbowRoll").upper  # the straightest the elbow gets (-7 deg)
    for side, sign in (("left", 1), ("right", -1)):
        l1, l2, roll_joint = link_lengths(side)
        # Straight out is on the pitch axis, so ShoulderPitch is free; the elbow stops at its limit and the
        # upper arm leads by the small triangle angle so that the hand lies on the lateral line.
        lead = math.degrees(math.atan2(l2 * math.sin(math.radians(-elbow_limit)), l1 + l2 * math.cos(math.radians(elbow_limit))))
        got = out.commands[f"{side}_arm"]
        assert got[1:] == pytest.approx((lead, elbow_limit), abs=0.05), side
        d_max = math.sqrt(l1 * l1 + l2 * l2 + 2 * l1 * l2 * math.cos(math.radians(elbow_limit)))
        hand = forward_kinematics(MODEL, dict(zip(MODEL.parts[f"{side}_arm"], got)))[f"{side}_hand"][:3, 3]
        np.testing.assert_allclose(hand, roll_joint + np.array([0, sign * d_max, 0]), atol=1e-3)
        assert not out.ik[side].reached
        assert out.ik[side].error_m == pytest.approx(robot_arms(MODEL).reach_m - d_max, abs=1e-3)


def test_operator_facing_sideways_in_the_room_still_maps_body_relative():
    """Engaged while facing Unity's -x (left); arms forward relative to the body must give forward robot arms."""
    head_q = Rotation.from_rotvec([0, -math.pi / 2, 0]).as_quat()  # Unity: 90 deg to the left
    m = engaged_mapper(head_quat=head_q)
    k = 0.9
    # In the operator's body: forward is Unity -x, the left side is Unity -z.
    neck = EYES_UNITY + np.array([BODY.eye_to_neck_back_m, -BODY.eye_to_shoulder_drop_m, 0])
    left = neck + np.array([-k * BODY.arm_length_m, 0, -BODY.shoulder_half_width_m])
    right = neck + np.array([-k * BODY.arm_length_m, 0, BODY.shoulder_half_width_m])
    out = drive(m, left, right, head_quat=head_q)
    assert out.commands["left_arm"][0] == pytest.approx(0.0, abs=1e-3)
    assert out.commands["right_arm"][0] == pytest.approx(0.0, abs=1e-3)
    assert out.ik["left"].reached and out.ik["right"].reached


def test_hand_target_scales_by_reach_ratio():
    arms = robot_arms(MODEL)
    assert arms.reach_m == pytest.approx(0.07708 + 0.184, abs=1e-6)
    head = make_pose([0.0, 0.0, 1.5], [0, 0, 0, 1])
    sh = shoulder_positions(BODY, head, 0.0)
    np.testing.assert_allclose(sh["left"], [-0.08, 0.19, 1.3])
    np.testing.assert_allclose(sh["right"], [-0.08, -0.19, 1.3])
    scale = arms.reach_m / BODY.arm_length_m
    tgt = hand_target("left", sh["left"] + [0.3, 0.0, -0.1], sh["left"], 0.0, scale, arms)
    np.testing.assert_allclose(tgt, arms.shoulder["left"] + scale * np.array([0.3, 0.0, -0.1]))
    # Turning the head moves the neck point behind the eyes but not the torso's sideways axis.
    turned = make_pose([0.0, 0.0, 1.5], Rotation.from_euler("z", 90, degrees=True).as_quat())
    sh2 = shoulder_positions(BODY, turned, 0.0)
    np.testing.assert_allclose(sh2["left"], [0.0, 0.19 - 0.08, 1.3], atol=1e-12)


def _operator(torso_deg, back, drop, half, arm, posture):
    h = math.radians(torso_deg)
    rz = Rotation.from_euler("z", h)
    eyes = np.array([0.5, -0.2, 1.25])
    centre = eyes + rz.apply([-back, 0, -drop])
    if posture == "t_pose":
        left, right = centre + rz.apply([0, half + arm, 0]), centre + rz.apply([0, -half - arm, 0])
    else:
        left, right = centre + rz.apply([arm, half, 0]), centre + rz.apply([arm, -half, 0])
    q = rz.as_quat()
    return make_pose(eyes, q), make_pose(left, q), make_pose(right, q)


def test_calibrate_t_pose_recovers_the_body():
    head, left, right = _operator(30, back=0.1, drop=0.25, half=0.19, arm=0.7, posture="t_pose")
    body, torso = calibrate_t_pose(head, left, right)
    assert math.degrees(torso) == pytest.approx(30)
    assert (body.eye_to_neck_back_m, body.eye_to_shoulder_drop_m, body.arm_length_m) == pytest.approx((0.1, 0.25, 0.7))


def test_calibrate_forward_recovers_the_body():
    head, left, right = _operator(-45, back=0.08, drop=0.22, half=0.17, arm=0.55, posture="forward")
    body, torso = calibrate_forward(head, left, right)
    assert math.degrees(torso) == pytest.approx(-45)
    assert (body.eye_to_shoulder_drop_m, body.shoulder_half_width_m, body.arm_length_m) == pytest.approx((0.22, 0.17, 0.55))


def test_bad_calibration_poses_say_what_to_do():
    head, left, right = _operator(0, 0.08, 0.2, 0.19, 0.6, "forward")  # hands forward, asked for a T-pose
    with pytest.raises(ValueError, match="arms straight out to the sides"):
        calibrate_t_pose(head, left, right)
    head, left, right = _operator(0, 0.08, 0.2, 0.19, 0.6, "t_pose")
    with pytest.raises(ValueError, match="straight ahead"):
        calibrate_forward(head, left, right)


def test_mapper_calibration_changes_the_mapping():
    m = engaged_mapper()
    # Operator with 0.75 m arms in a T-pose (Unity axes), then calibrate.
    drop, half, arm = 0.2, 0.19, 0.75
    centre = EYES_UNITY + np.array([0, -drop, -0.08])
    m.on_controller_pose("left", unity_pose(centre + [-(half + arm), 0, 0]), 0.0)
    m.on_controller_pose("right", unity_pose(centre + [half + arm, 0, 0]), 0.0)
    body = m.calibrate(0.0, "t_pose")
    assert body.arm_length_m == pytest.approx(arm) and m.body == body
    # Now 90% of *this* arm forward is 90% of the robot's reach.
    out = drive(m, centre + [-half, 0, 0.9 * arm], centre + [half, 0, 0.9 * arm])
    l1, l2, _ = link_lengths("left")
    assert out.commands["left_arm"][1:] == pytest.approx(planar_expectation(0.9 * robot_arms(MODEL).reach_m, l1, l2),
                                                        abs=1e-3)


def test_ik_directly_agrees_with_the_planar_expectation():
    l1, l2, roll_joint = link_lengths("left")
    d = 0.22
    r = arm_ik("left", roll_joint + [d, 0, 0], MODEL)
    assert r.reached
    assert [r.angles_deg[n] for n in MODEL.parts["left_arm"]] == pytest.approx((0.0, *planar_expectation(d, l1, l2)),
                                                                                abs=1e-6)
