"""robot_models: the yaml's facts, forward kinematics against hand-computed URDF numbers, IK round trips."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_models import Joint, RobotModel, arm_ik, forward_kinematics, load_qtrobot

MODEL = load_qtrobot()


def test_joints_in_canonical_order_with_reference_ranges_and_homes():
    assert MODEL.names == ("HeadYaw", "HeadPitch", "RightShoulderPitch", "RightShoulderRoll", "RightElbowRoll",
                           "LeftShoulderPitch", "LeftShoulderRoll", "LeftElbowRoll")
    expected = {  # qtrobot.md's table: (lower, upper, home)
        "HeadYaw": (-60, 60, 0), "HeadPitch": (-15, 25, 0), "RightShoulderPitch": (-140, 140, -90),
        "RightShoulderRoll": (-75, 7, -55), "RightElbowRoll": (-90, -7, -35), "LeftShoulderPitch": (-140, 140, 90),
        "LeftShoulderRoll": (-75, 7, -55), "LeftElbowRoll": (-90, -7, -35),
    }
    for name, (lo, hi, home) in expected.items():
        j = MODEL.joint(name)
        assert (j.lower, j.upper, j.home) == (lo, hi, home)
        assert j.max_velocity > 0
    assert MODEL.alphabetical_names == ("HeadPitch", "HeadYaw", "LeftElbowRoll", "LeftShoulderPitch",
                                        "LeftShoulderRoll", "RightElbowRoll", "RightShoulderPitch", "RightShoulderRoll")
    assert MODEL.parts == {"head": ("HeadYaw", "HeadPitch"),
                           "right_arm": ("RightShoulderPitch", "RightShoulderRoll", "RightElbowRoll"),
                           "left_arm": ("LeftShoulderPitch", "LeftShoulderRoll", "LeftElbowRoll")}


def test_unknown_joint_names_the_valid_ones():
    with pytest.raises(KeyError, match="HeadYaw"):
        MODEL.joint("Neck")


def test_clamp_and_nan():
    assert MODEL.clamp("HeadPitch", 40) == 25
    assert MODEL.clamp("HeadPitch", -40) == -15
    assert MODEL.clamp("HeadPitch", 3.5) == 3.5
    with pytest.raises(ValueError, match="HeadPitch"):
        MODEL.clamp("HeadPitch", float("nan"))


def test_velocity_caps_are_configurable_and_validated():
    m = MODEL.with_velocity_caps({"HeadYaw": 30.0})
    assert m.joint("HeadYaw").max_velocity == 30.0
    assert m.joint("HeadPitch").max_velocity == MODEL.joint("HeadPitch").max_velocity
    assert MODEL.joint("HeadYaw").max_velocity != 30.0  # the original is untouched (frozen)
    with pytest.raises(KeyError):
        MODEL.with_velocity_caps({"Tail": 10})
    with pytest.raises(ValueError, match="HeadYaw"):
        MODEL.with_velocity_caps({"HeadYaw": 0})


def test_camera_intrinsics():
    cam = MODEL.camera
    assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (640, 480, 376.40, 376.08, 314.64, 255.58)
    assert cam.fovy_deg == pytest.approx(2 * math.degrees(math.atan(240 / 376.08)))


def test_load_from_path_and_malformed_file(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("joints: []\n")
    with pytest.raises(ValueError, match="bad.yaml"):
        load_qtrobot(bad)


def test_fk_zero_pose_matches_hand_computed_urdf_numbers():
    f = forward_kinematics(MODEL, {})
    # Camera: 0.338 + 0.0962 + 0.162 above the base, 0.094 ahead.
    np.testing.assert_allclose(f["camera"][:3, 3], [0.094, 0.0, 0.5962], atol=1e-12)
    # Optical frame: z (view) forward along base x, x (image right) along base -y, y (image down) along base -z.
    np.testing.assert_allclose(f["camera"][:3, 2], [1, 0, 0], atol=1e-9)
    np.testing.assert_allclose(f["camera"][:3, 0], [0, -1, 0], atol=1e-9)
    np.testing.assert_allclose(f["camera"][:3, 1], [0, 0, -1], atol=1e-9)
    # At zero the arms stretch sideways along the pitch axis: shoulder 0.08 out, then 0.0445 + 0.07708 + 0.184.
    reach = 0.0445 + 0.07708 + 0.184
    np.testing.assert_allclose(f["left_hand"][:3, 3], [0, 0.08 + reach, 0.396], atol=1e-12)
    np.testing.assert_allclose(f["right_hand"][:3, 3], [0, -0.08 - reach, 0.396], atol=1e-12)
    assert reach == pytest.approx(0.306, abs=1e-3)


def test_fk_head_turns_move_the_camera_as_expected():
    yaw = forward_kinematics(MODEL, {"HeadYaw": 90})["camera"][:3, 3]
    np.testing.assert_allclose(yaw, [0.0, 0.094, 0.5962], atol=1e-9)  # yaw left turns the camera to +y
    pitch = forward_kinematics(MODEL, {"HeadPitch": 90})["camera"]
    # Pitch about +y by 90 deg maps the offset (0.094, 0, 0.162) to (0.162, 0, -0.094) above the pitch origin.
    np.testing.assert_allclose(pitch[:3, 3], [0.162, 0.0, 0.338 + 0.0962 - 0.094], atol=1e-9)
    np.testing.assert_allclose(pitch[:3, 2], [0, 0, -1], atol=1e-9)  # positive pitch looks down


def test_fk_home_pose_arms_hang_down_symmetrically():
    f = forward_kinematics(MODEL, MODEL.home_pose())
    lh, rh = f["left_hand"][:3, 3], f["right_hand"][:3, 3]
    np.testing.assert_allclose(lh * [1, -1, 1], rh, atol=1e-9)  # mirror images
    # Hand by hand: roll -55 then elbow -35 in the lateral plane below the shoulder.
    y = 0.08 + 0.0445 + 0.07708 * math.cos(math.radians(55)) + 0.184 * math.cos(math.radians(90))
    z = 0.396 - 0.07708 * math.sin(math.radians(55)) - 0.184 * math.sin(math.radians(90))
    np.testing.assert_allclose(lh, [0.0, y, z], atol=1e-9)


def test_fk_rejects_unknown_joint():
    with pytest.raises(KeyError, match="HeadYaw"):
        forward_kinematics(MODEL, {"Headyaw": 1.0})


def _limits(side):
    p = side.capitalize()
    joints = [MODEL.joint(p + n) for n in ("ShoulderPitch", "ShoulderRoll", "ElbowRoll")]
    return [(j.lower, j.upper) for j in joints]


def _within_limits(angles):
    return all(MODEL.joint(n).lower - 1e-9 <= a <= MODEL.joint(n).upper + 1e-9 for n, a in angles.items())


@st.composite
def arm_pose(draw):
    side = draw(st.sampled_from(["left", "right"]))
    angles = [draw(st.floats(lo, hi, allow_nan=False)) for lo, hi in _limits(side)]
    p = side.capitalize()
    return side, dict(zip((p + "ShoulderPitch", p + "ShoulderRoll", p + "ElbowRoll"), angles))


@settings(max_examples=300, deadline=None)
@given(arm_pose())
def test_ik_fk_round_trip_across_the_reachable_workspace(pose):
    side, angles = pose
    target = forward_kinematics(MODEL, angles)[f"{side}_hand"][:3, 3]
    result = arm_ik(side, target, MODEL)
    assert result.reached, (angles, result)
    assert _within_limits(result.angles_deg)
    reached = forward_kinematics(MODEL, result.angles_deg)[f"{side}_hand"][:3, 3]
    assert np.linalg.norm(reached - target) < 1e-6
    assert result.error_m == pytest.approx(float(np.linalg.norm(reached - target)), abs=1e-9)


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(["left", "right"]),
       st.tuples(*[st.floats(-2.0, 2.0, allow_nan=False) for _ in range(3)]))
def test_ik_respects_limits_and_reports_error_for_arbitrary_targets(side, target):
    result = arm_ik(side, np.array(target), MODEL)
    assert _within_limits(result.angles_deg)
    hand = forward_kinematics(MODEL, result.angles_deg)[f"{side}_hand"][:3, 3]
    assert result.error_m == pytest.approx(float(np.linalg.norm(hand - np.array(target))), abs=1e-9)
    assert result.reached == (result.error_m <= 1e-4)


def test_ik_out_of_reach_is_clamped_along_the_same_direction():
    shoulder_roll_joint = forward_kinematics(MODEL, {})["LeftShoulderRoll"][:3, 3]
    # 1 m away, out, forward and down (a direction the roll range allows): far beyond the 0.26 m the arm
    # can stretch from its roll joint.
    want = np.array([0.5, 0.7, -0.5]) / np.linalg.norm([0.5, 0.7, -0.5])
    target = shoulder_roll_joint + want
    result = arm_ik("left", target, MODEL)
    assert not result.reached
    assert _within_limits(result.angles_deg)
    hand = forward_kinematics(MODEL, result.angles_deg)["left_hand"][:3, 3]
    direction = (hand - shoulder_roll_joint) / np.linalg.norm(hand - shoulder_roll_joint)
    np.testing.assert_allclose(direction, want, atol=1e-6)
    # On the boundary: elbow at its least bent (-7 deg) gives the longest reach.
    assert result.angles_deg["LeftElbowRoll"] == pytest.approx(-7.0)
    assert result.error_m == pytest.approx(1.0 - np.linalg.norm(hand - shoulder_roll_joint), abs=1e-9)


def test_ik_prefers_the_branch_nearest_the_given_pose():
    target = forward_kinematics(MODEL, MODEL.home_pose())["right_hand"][:3, 3]
    result = arm_ik("right", target, MODEL)
    assert result.reached
    for name in ("RightShoulderPitch", "RightShoulderRoll", "RightElbowRoll"):
        assert result.angles_deg[name] == pytest.approx(MODEL.joint(name).home, abs=1e-6)


def test_ik_rejects_bad_input():
    with pytest.raises(ValueError, match="left"):
        arm_ik("middle", [0, 0, 0], MODEL)
    with pytest.raises(ValueError, match="finite"):
        arm_ik("left", [0, float("nan"), 0], MODEL)


def test_robot_model_is_constructible_and_frozen():
    m = RobotModel(joints=(Joint("A", "head", -1, 1, 0, 10),))
    assert m.names == ("A",) and m.clamp("A", 5) == 1
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.joints = ()  # type: ignore[misc]


def test_emotion_and_gesture_names():
    assert len(MODEL.emotions) == 23 and "happy" in MODEL.emotions and "talking" in MODEL.emotions
    assert len(MODEL.gestures) == 32 and "bye-bye" in MODEL.gestures and "show_QT" in MODEL.gestures
    assert not any(name.startswith("QT/") for name in MODEL.emotions + MODEL.gestures)


def test_a_robots_own_limits_narrow_the_model():
    """The intersection of ranges (the narrower wins on each side), the smaller velocity cap, home kept inside."""
    model = load_qtrobot()
    narrowed = model.narrowed({"HeadYaw": {"lower": -90.0, "upper": 45.0, "max_velocity": 500.0},
                               "HeadPitch": {"lower": 5.0, "upper": 20.0, "max_velocity": 10.0},
                               "LeftElbowRoll": {}})
    yaw, pitch = narrowed.joint("HeadYaw"), narrowed.joint("HeadPitch")
    assert (yaw.lower, yaw.upper) == (model.joint("HeadYaw").lower, 45.0)  # the model's -60 is narrower than -90
    assert yaw.max_velocity == model.joint("HeadYaw").max_velocity
    assert (pitch.lower, pitch.upper, pitch.max_velocity, pitch.home) == (5.0, 20.0, 10.0, 5.0)
    assert narrowed.joint("LeftElbowRoll") == model.joint("LeftElbowRoll")
    assert narrowed.clamp("HeadYaw", 55.0) == 45.0
    with pytest.raises(ValueError, match="HeadPitch.*does not overlap"):
        model.narrowed({"HeadPitch": {"lower": 30.0, "upper": 40.0}})
