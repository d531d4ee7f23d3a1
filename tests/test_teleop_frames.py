"""Unity -> ROS pose conversion: known turns, the derivation by matrix conjugation, and input validation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from vr_teleop_server.teleop.frames import (
    UNITY_TO_ROS, heading, make_pose, pose_from_message, unity_to_ros_position, unity_to_ros_quaternion,
)


def unity_quat(axis_unity, deg):
    """Unity's Quaternion.AngleAxis(deg, axis): the standard axis-angle formula on Unity's axes."""
    return Rotation.from_rotvec(np.asarray(axis_unity, float) * math.radians(deg)).as_quat()


def stamped(frame_id, pos, quat):
    return {"header": {"frame_id": frame_id, "stamp": {"sec": 0, "nanosec": 0}},
            "pose": {"position": dict(zip("xyz", map(float, pos))), "orientation": dict(zip("xyzw", map(float, quat)))}}


UP, RIGHT, FORWARD = [0, 1, 0], [1, 0, 0], [0, 0, 1]  # Unity axes


def test_position_axes():
    assert unity_to_ros_position([1, 0, 0]).tolist() == [0, -1, 0]  # right -> -y
    assert unity_to_ros_position([0, 1, 0]).tolist() == [0, 0, 1]  # up -> z
    assert unity_to_ros_position([0, 0, 1]).tolist() == [1, 0, 0]  # forward -> x
    assert np.linalg.det(UNITY_TO_ROS) == pytest.approx(-1.0)


def test_unity_yaw_right_is_ros_negative_yaw():
    # Unity: +30 deg about y turns forward (z) towards right (x); in ROS that is yaw -30 about z.
    q_unity = unity_quat(UP, 30)
    fwd_unity = Rotation.from_quat(q_unity).apply([0, 0, 1])
    assert fwd_unity[0] > 0  # really turning right in Unity
    r = Rotation.from_quat(unity_to_ros_quaternion(q_unity))
    yaw, pitch, roll = r.as_euler("ZYX", degrees=True)
    assert yaw == pytest.approx(-30.0) and pitch == pytest.approx(0.0, abs=1e-9) and roll == pytest.approx(0.0, abs=1e-9)
    f = r.apply([1, 0, 0])
    assert f[1] < 0  # ROS: facing towards -y = right


def test_unity_pitch_down_is_ros_pitch_down():
    q_unity = unity_quat(RIGHT, 20)  # +20 about Unity's right axis
    assert Rotation.from_quat(q_unity).apply([0, 0, 1])[1] < 0  # nose goes down in Unity
    r = Rotation.from_quat(unity_to_ros_quaternion(q_unity))
    assert r.apply([1, 0, 0])[2] < 0  # nose goes down in ROS
    assert r.as_euler("ZYX", degrees=True)[1] == pytest.approx(20.0)  # positive about +y = down


def test_unity_roll_left_ear_down():
    q_unity = unity_quat(FORWARD, 15)  # +15 about forward: in left-handed Unity, up tilts towards -x (left)
    up_unity = Rotation.from_quat(q_unity).apply([0, 1, 0])
    r = Rotation.from_quat(unity_to_ros_quaternion(q_unity))
    up_ros = r.apply([0, 0, 1])
    np.testing.assert_allclose(up_ros, unity_to_ros_position(up_unity), atol=1e-12)
    assert up_unity[0] < 0 and up_ros[1] > 0  # same physical tilt: towards the left in both


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1),
       st.lists(st.floats(-5, 5), min_size=3, max_size=3))
def test_quaternion_conversion_is_the_change_of_basis(q, v):
    """Rotating in Unity then converting equals converting then rotating in ROS."""
    q = np.asarray(q) / np.linalg.norm(q)
    r_unity = Rotation.from_quat(q)
    r_ros = Rotation.from_quat(unity_to_ros_quaternion(q))
    np.testing.assert_allclose(r_ros.as_matrix(), UNITY_TO_ROS @ r_unity.as_matrix() @ UNITY_TO_ROS.T, atol=1e-12)
    np.testing.assert_allclose(r_ros.apply(unity_to_ros_position(v)), unity_to_ros_position(r_unity.apply(v)),
                               atol=1e-9)


def test_message_in_unity_frame_is_converted_and_ros_frame_passes_through():
    q = unity_quat(UP, -40)
    p = pose_from_message(stamped("unity_left_handed", [0.1, 1.5, 0.3], q))
    np.testing.assert_allclose(p.position, [0.3, -0.1, 1.5])
    assert math.degrees(heading(p.rotation)) == pytest.approx(40.0)  # Unity left turn = ROS +yaw
    p2 = pose_from_message(stamped("odom", [0.1, 1.5, 0.3], q))
    np.testing.assert_allclose(p2.position, [0.1, 1.5, 0.3])
    np.testing.assert_allclose(p2.rotation.as_quat(), q / np.linalg.norm(q))
    bare = pose_from_message({"position": {"x": 1, "y": 2, "z": 3}, "orientation": {"x": 0, "y": 0, "z": 0, "w": 1}})
    np.testing.assert_allclose(bare.position, [1, 2, 3])
    assert pose_from_message(stamped(" Unity_Left_Handed ", [0, 0, 1], [0, 0, 0, 1])).position.tolist() == [1, 0, 0]
    # ROS#'s PoseStampedPublisher labels poses it already converted "Unity": those are ROS axes, as any frame id
    assert pose_from_message(stamped("Unity", [0, 0, 1], [0, 0, 0, 1])).position.tolist() == [0, 0, 1]


@pytest.mark.parametrize(("quat", "field", "words"), [
    ([0, 0, 0, 0], "pose.orientation", "zero quaternion"),
    ([0, 0, 0, 0.5], "pose.orientation", "norm 0.5"),
    ([0, 0, 0, 1.02], "pose.orientation", "norm 1.02"),
    ([float("nan"), 0, 0, 1], "pose.orientation", "NaN"),
    ([0, 0, float("inf"), 1], "pose.orientation", "infinity"),
    ([1e200, 0, 0, 1], "pose.orientation", "norm inf"),  # finite, but its norm overflows
])
@pytest.mark.filterwarnings("error")
def test_bad_quaternions_are_rejected_naming_the_field(quat, field, words):
    with pytest.raises(ValueError) as exc:
        pose_from_message(stamped("unity_left_handed", [0, 0, 0], quat))
    assert field in str(exc.value) and words in str(exc.value)


def test_slightly_unnormalised_quaternion_is_accepted_and_normalised():
    q = np.round(unity_quat(UP, 33), 3)  # a client rounding to 3 decimals
    p = pose_from_message(stamped("unity_left_handed", [0, 0, 0], q))
    assert np.linalg.norm(p.rotation.as_quat()) == pytest.approx(1.0)


def test_bad_positions_and_shapes_are_rejected():
    with pytest.raises(ValueError, match=r"pose\.position.*NaN"):
        pose_from_message(stamped("unity_left_handed", [float("nan"), 0, 0], [0, 0, 0, 1]))
    with pytest.raises(ValueError, match=r"pose\.orientation\.w: missing"):
        pose_from_message({"header": {"frame_id": "unity_left_handed"},
                           "pose": {"position": {"x": 0, "y": 0, "z": 0}, "orientation": {"x": 0, "y": 0, "z": 0}}})
    with pytest.raises(ValueError, match=r"pose\.position"):
        pose_from_message({"pose": {"position": {"x": "a", "y": 0, "z": 0},
                                    "orientation": {"x": 0, "y": 0, "z": 0, "w": 1}}})
    with pytest.raises(ValueError, match="expected an object"):
        pose_from_message([1, 2, 3])


def test_make_pose_matches_message_path():
    q = unity_quat([0.3, 0.8, 0.1], 50)
    a = make_pose([0.2, 1.1, 0.4], q, "unity_left_handed")
    b = pose_from_message(stamped("unity_left_handed", [0.2, 1.1, 0.4], q))
    np.testing.assert_allclose(a.position, b.position)
    assert a.rotation.approx_equal(b.rotation)
