"""The per-frame forms the teleop step uses (plain floats) against the array forms they replace, and the stand-in's
two per-pose calls, which must not wait for a physics batch."""

from __future__ import annotations

import concurrent.futures
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from testbed.server import wait_for
from vr_teleop_server.teleop import BodyModel, make_pose
from vr_teleop_server.teleop.body import hand_point, shoulder_points
from vr_teleop_server.teleop.head import HeadTracker

quaternions = st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1)
points = st.tuples(*[st.floats(-3, 3)] * 3)


@settings(max_examples=200, deadline=None)
@given(quaternions, points, st.sampled_from(["unity_left_handed", "odom"]))
def test_pose_forward_is_the_rotation_matrix_first_column(q, xyz, frame):
    pose = make_pose(xyz, q, frame)
    np.testing.assert_allclose(pose.forward, pose.rotation.as_matrix()[:, 0], atol=1e-12)
    np.testing.assert_allclose(pose.matrix, pose.rotation.as_matrix())
    assert pose.position.tolist() == list(pose.xyz)


@settings(max_examples=200, deadline=None)
@given(quaternions, quaternions)
def test_head_from_the_forward_axis_equals_head_from_the_matrix(zero, q):
    a, b = HeadTracker(), HeadTracker()
    for t in (a, b):
        t.set_zero(Rotation.from_quat(zero))
    rot = Rotation.from_quat(q)
    assert a.update_forward(*rot.as_matrix()[:, 0]) == pytest.approx(b.update(rot), abs=1e-9)


@settings(max_examples=200, deadline=None)
@given(points, st.floats(-math.pi, math.pi), st.floats(-math.pi, math.pi), points, st.floats(0.1, 2.0))
def test_shoulders_and_hand_targets_in_floats_equal_the_matrix_forms(eyes, head_h, torso_h, controller, scale):
    """The float forms against the matrix formulas of body.py's docstring, written out here with NumPy."""
    body = BodyModel()

    def rz(a):
        return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])

    centre = np.array(eyes) + rz(head_h) @ [-body.eye_to_neck_back_m, 0, 0] - [0, 0, body.eye_to_shoulder_drop_m]
    lateral = rz(torso_h) @ [0, body.shoulder_half_width_m, 0]
    left, right = shoulder_points(body, eyes, head_h, torso_h)
    np.testing.assert_allclose(left, centre + lateral, atol=1e-12)
    np.testing.assert_allclose(right, centre - lateral, atol=1e-12)
    robot_shoulder = (0.01, 0.1, 0.3)
    got = hand_point(controller, left, math.cos(torso_h), math.sin(torso_h), scale, robot_shoulder)
    want = np.array(robot_shoulder) + scale * (rz(-torso_h) @ (np.array(controller) - (centre + lateral)))
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_standin_commands_and_state_do_not_wait_for_a_physics_batch():
    """While the physics state's lock is held (as the physics thread holds it for a batch of steps), the calls the
    server makes on every pose and joint-state tick return, the new goal is read back at once, and once the lock
    is free again the published state follows the physics (the simulated clock advances, the head turns)."""
    from sim.standin import StandIn

    standin = StandIn(camera_fps=1.0)
    try:
        with standin.physics.lock, concurrent.futures.ThreadPoolExecutor(1) as pool:
            applied = pool.submit(standin.set_targets, {"HeadYaw": 12.5}).result(timeout=60)
            held = pool.submit(standin.joint_state).result(timeout=60)
        assert applied == {"HeadYaw": 12.5}
        assert held.targets[held.names.index("HeadYaw")] == 12.5
        yaw = held.position("HeadYaw")
        def followed() -> bool:
            later = standin.joint_state()
            return later.sim_time > held.sim_time and later.position("HeadYaw") > yaw + 1.0

        assert wait_for(followed, 60), "the published joint state did not follow the physics"
    finally:
        standin.close()
