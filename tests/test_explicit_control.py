"""Explicit control end to end: a headset streaming over the protocol moves the MuJoCo stand-in's joints.

The headset is roslibpy (as ROS# would be, Unity frame), the robot is the stand-in, and every assertion reads what
a client can see: joint states, /vr_teleop/teleop_state, /vr_teleop/events and status replies.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
import roslibpy

from robot_models import load_qtrobot
from support import (
    EYE_HEIGHT, IDENTITY, Headset, RawClient, Watch, call, engage, joints, pose_msg, still, unity_yaw_pitch,
    wait_for,
)
from vr_teleop_server.teleop import TeleopMapper

MODEL = load_qtrobot()
@pytest.fixture(autouse=True)
def control_is_free_after_each_test(sim_server):
    yield
    assert wait_for(lambda: sim_server.call(lambda: sim_server.server.control.holder) is None, 30)


@pytest.fixture
def headset(ros):
    h = Headset(ros).start()
    yield h
    h.stop()


@pytest.fixture
def state(watch):
    return watch("/vr_teleop/teleop_state", "vr_teleop_msgs/TeleopState")


@pytest.fixture
def joint_states(watch):
    return watch("/qt_robot/joints/state", "sensor_msgs/JointState")


def test_looking_left_turns_the_head_and_beyond_the_limit_clamps(ros, headset, state, joint_states):
    engage(ros)
    assert wait_for(lambda: state.latest.get("engaged") and state.latest.get("state") == "active"
                    and state.latest["head_following"], 30), state.latest
    assert state.latest["holder"]
    headset.head_orientation = unity_yaw_pitch(30.0)
    assert wait_for(lambda: abs(joints(joint_states).get("HeadYaw", 0) - 30.0) < 2.0, 30), joints(joint_states)
    headset.head_orientation = unity_yaw_pitch(80.0)
    assert wait_for(lambda: "HeadYaw" in state.latest.get("clamped", []), 30), state.latest
    assert wait_for(lambda: abs(joints(joint_states)["HeadYaw"] - 60.0) < 2.0, 30), joints(joint_states)
    headset.head_orientation = unity_yaw_pitch(0.0, 10.0)  # looking up: QTrobot's pitch is positive down
    assert wait_for(lambda: abs(joints(joint_states)["HeadPitch"] + 10.0) < 2.0, 30), joints(joint_states)
    headset.head_orientation = unity_yaw_pitch(0.0, 30.0)  # beyond the -15 limit
    assert wait_for(lambda: abs(joints(joint_states)["HeadPitch"] - MODEL.joint("HeadPitch").lower) < 2.0, 30)
    call(ros, "/vr_teleop/control/engage", "std_srvs/SetBool", {"data": False})
    assert wait_for(lambda: state.latest.get("state") == "released" and not state.latest["engaged"], 30)


def expected_arm(hand_unity: tuple[float, float, float]) -> dict[str, float]:
    """What the mapping gives for this hand position once settled, computed offline by the same mapper."""
    from vr_teleop_server.teleop import make_pose
    from vr_teleop_server.teleop.frames import unity_to_ros_position  # noqa: F401  (documents the frame)

    mapper = TeleopMapper(MODEL)
    head = make_pose((0.0, EYE_HEIGHT, 0.0), [0, 0, 0, 1], "unity_left_handed")
    t = 0.0
    mapper.on_head_pose(head, t)
    mapper.engage(t)
    for _ in range(2000):
        t += 1 / 90
        mapper.on_head_pose(head, t)
        mapper.on_controller_pose("right", make_pose(hand_unity, [0, 0, 0, 1], "unity_left_handed"), t)
        mapper.on_joy("right", [0, 0, 0, 1.0], [0, 0, 0, 0], t)
        mapper.step(t)
    return {n: mapper.last_command[n] for n in MODEL.part_joints("right_arm")}


def test_right_controller_moves_the_right_arm_only_while_the_grip_is_held(ros, headset, state, joint_states):
    engage(ros)
    forward = (0.19, EYE_HEIGHT - 0.2, 0.55)  # in front of the right shoulder
    headset.hand_positions["right"] = forward
    headset.send_head_poses(45)  # half a second of the headset's frames with the hand forward
    before = joints(joint_states)
    assert still(lambda: not state.latest["right_arm_following"], state)  # no grip yet: the arm holds
    headset.grips["right"] = 1.0
    assert wait_for(lambda: state.latest.get("right_arm_following"), 30)
    want = expected_arm(forward)
    right = MODEL.part_joints("right_arm")
    assert max(abs(want[n] - before[n]) for n in right) > 20  # the pose is far from where the arm hung
    assert wait_for(lambda: all(abs(joints(joint_states)[n] - want[n]) < 3.0 for n in right), 30), \
        (joints(joint_states), want)
    assert not state.latest["left_arm_following"]
    # Release the grip: the arm holds where it is even as the hand moves away.
    headset.grips["right"] = 0.0
    assert wait_for(lambda: not state.latest.get("right_arm_following"), 30)
    held = joints(joint_states)
    headset.hand_positions["right"] = (0.5, EYE_HEIGHT - 0.2, 0.0)
    headset.send_head_poses(90)  # a second of the headset's frames with the hand away
    assert still(lambda: all(abs(joints(joint_states)[n] - held[n]) < 1.5 for n in right), joint_states, 30)


def test_watchdog_holds_on_a_stalled_stream_and_fresh_poses_resume(ros, headset, state, joint_states):
    events = Watch(ros, "/vr_teleop/events", "vr_teleop_msgs/Event")
    engage(ros)
    headset.head_orientation = unity_yaw_pitch(20.0)
    assert wait_for(lambda: abs(joints(joint_states).get("HeadYaw", 0) - 20.0) < 2.0, 30)
    headset.stop()
    assert wait_for(lambda: state.latest.get("state") == "stalled", 30), state.latest
    assert state.latest["pose_age"] > 0.2 and not state.latest["head_following"]
    assert wait_for(lambda: events.any(lambda e: e["kind"] == "watchdog_stalled"), 30)
    held = joints(joint_states)["HeadYaw"]
    assert still(lambda: abs(joints(joint_states)["HeadYaw"] - held) < 0.5, joint_states)
    headset.head_orientation = unity_yaw_pitch(-20.0)
    headset.start()
    assert wait_for(lambda: state.latest.get("state") == "active", 30)
    assert wait_for(lambda: abs(joints(joint_states)["HeadYaw"] + 20.0) < 2.0, 30)
    events.close()


def test_dropped_operator_holds_the_robot_and_frees_control(sim_server, ros):
    watcher = Watch(ros, "/vr_teleop/teleop_state", "vr_teleop_msgs/TeleopState")
    operator = roslibpy.Ros(host="127.0.0.1", port=sim_server.port)
    operator.run(timeout=10)
    h = Headset(operator).start()
    h.head_orientation = unity_yaw_pitch(-25.0)
    engage(operator)
    assert wait_for(lambda: watcher.latest.get("state") == "active", 30)
    h.stop()
    operator.close()  # the connection drops mid-motion
    assert wait_for(lambda: watcher.latest.get("state") == "disconnected" and watcher.latest["holder"] == "", 30)
    assert not watcher.latest["engaged"]
    watcher.close()


def test_second_client_cannot_steal_control(sim_server, ros, headset, state):
    engage(ros)
    intruder = RawClient(sim_server.url)
    try:
        intruder.send({"op": "publish", "topic": "/vr/head/pose",
                       "msg": pose_msg((0, EYE_HEIGHT, 0), unity_yaw_pitch(45))})
        status = intruder.expect("status", level="error")
        assert "/vr/head/pose" in status["msg"] and "held by another client" in status["msg"]
        intruder.send({"op": "call_service", "id": "steal", "service": "/vr_teleop/control/engage",
                       "args": {"data": True}})
        response = intruder.expect("service_response")  # a refusal: inside the response, as ROS's convention
        assert response["result"] is True and response["values"]["success"] is False
        assert "held by another client" in response["values"]["message"]
        assert state.latest["holder"] != "" and state.latest["pose_age"] >= 0  # still held, poses still counted
        # Once the holder releases, the other client may take control.
        call(ros, "/vr_teleop/control/engage", "std_srvs/SetBool", {"data": False})
        for _ in range(10):
            intruder.send({"op": "publish", "topic": "/vr/head/pose",
                           "msg": pose_msg((0, EYE_HEIGHT, 0), IDENTITY)})
        headset.stop()
        intruder.send({"op": "publish", "topic": "/vr/head/pose", "msg": pose_msg((0, EYE_HEIGHT, 0), IDENTITY)})
        intruder.send({"op": "call_service", "id": "take", "service": "/vr_teleop/control/engage",
                       "args": {"data": True}})
        deadline = time.monotonic() + 30  # only catches a reply that never comes
        while time.monotonic() < deadline:
            reply = intruder.recv()
            if reply.get("op") == "service_response" and reply.get("id") == "take":
                assert reply["result"] and reply["values"]["success"], reply
                break
        else:
            raise AssertionError("no answer to engage")
    finally:
        intruder.close()


@pytest.mark.parametrize("orientation, problem", [
    ({"x": float("nan"), "y": 0.0, "z": 0.0, "w": 1.0}, "NaN"),
    ({"x": 0.0, "y": 0.0, "z": 0.0, "w": 0.5}, "norm"),
    ({"x": 0.0, "y": 0.0, "z": 0.0, "w": 0.0}, "zero quaternion"),
])
def test_bad_poses_get_a_status_error_and_never_reach_the_robot(sim_server, orientation, problem):
    client = RawClient(sim_server.url)
    try:
        client.send({"op": "subscribe", "topic": "/qt_robot/head_position/command",
                     "type": "std_msgs/Float64MultiArray"})
        frame = ('{"op": "publish", "topic": "/vr/head/pose", "msg": {"header": {"frame_id": "unity_left_handed"}, "pose": '
                 '{"position": {"x": 0, "y": 1.6, "z": 0}, "orientation": {"x": %s, "y": 0, "z": 0, "w": %s}}}}'
                 % (("NaN" if math.isnan(orientation["x"]) else orientation["x"]), orientation["w"]))
        client.send_raw(frame)
        status = client.expect("status", level="error")
        assert "/vr/head/pose" in status["msg"] and problem in status["msg"], status
        assert client.silent(0.3)  # no command went out
        client.alive()
    finally:
        client.close()


def test_estop_holds_and_releases_control(ros, headset, state, joint_states):
    engage(ros)
    headset.head_orientation = unity_yaw_pitch(40.0)
    assert wait_for(lambda: joints(joint_states).get("HeadYaw", 0) > 10, 30)
    reply = call(ros, "/vr_teleop/control/estop", "std_srvs/Trigger")
    assert reply["success"]
    assert wait_for(lambda: state.latest.get("state") == "estopped" and state.latest["holder"] == "", 30)
    still(lambda: True, joint_states, 10)  # a command already on its way lands (what the servo does with it)
    held = joints(joint_states)["HeadYaw"]
    # the robot holds although the head still turns, over the robot's own joint states (30 Hz), not a time window
    assert still(lambda: abs(joints(joint_states)["HeadYaw"] - held) < 1.0, joint_states, 20)


def test_calibration_measures_the_operator_in_a_t_pose(ros, headset):
    headset.hand_positions = {"left": (-0.80, EYE_HEIGHT - 0.22, -0.05), "right": (0.80, EYE_HEIGHT - 0.22, -0.05)}
    headset.send_head_poses(27)  # the T-pose, in the headset's frames, before the call (sent after them)
    reply = call(ros, "/vr_teleop/control/calibrate", "std_srvs/Trigger")
    assert reply["success"], reply
    import json

    body = json.loads(reply["message"])
    assert 0.55 < body["arm_length_m"] + body["shoulder_half_width_m"] < 0.95
    assert np.isfinite(list(body.values())).all()


def test_the_telemetry_tells_the_holder_how_good_its_link_is(ros, headset, state, watch):
    """The holder's telemetry entry carries the watchdog's threshold, and the link's word turns poor while the
    robot holds on a silent stream, then names the hold for the next minute."""
    me = call(ros, "/vr_teleop/whoami", "vr_teleop_msgs/WhoAmI")["connection"]
    telemetry = watch("/vr_teleop/telemetry", "vr_teleop_msgs/Telemetry")

    def mine() -> dict:
        return next((c for c in telemetry.latest.get("clients", []) if c["client"] == me), {})

    # its round trip measured and its poses flowing, but no control: there is no link to judge yet
    assert wait_for(lambda: mine().get("ws_rtt", -1) >= 0 and mine()["pose_rate"] > 0, 30), mine()
    assert (mine()["link_quality"], mine()["link_warning"]) == ("", ""), mine()
    engage(ros)
    assert wait_for(lambda: mine().get("watchdog_threshold", -1) > 0 and mine()["link_quality"], 30), mine()
    entry = mine()
    assert 0.2 <= entry["watchdog_threshold"] <= 0.5 and entry["watchdog_holds"] == 0
    assert entry["link_quality"] in ("good", "degraded") and entry["pose_jitter"] >= 0  # loopback, busy or not
    headset.stop()
    assert wait_for(lambda: state.latest.get("state") == "stalled", 30), state.latest
    assert wait_for(lambda: mine().get("link_quality") == "poor", 30), mine()
    assert "not arriving" in mine()["link_warning"] and mine()["watchdog_holds"] == 1
    headset.start()
    assert wait_for(lambda: state.latest.get("state") == "active", 30)
    assert wait_for(lambda: "not arriving" not in mine()["link_warning"], 30), mine()
    assert mine()["link_quality"] in ("degraded", "poor") and "held 1 time in the last minute" in mine()["link_warning"]
    call(ros, "/vr_teleop/control/engage", "std_srvs/SetBool", {"data": False})
    # not holding: no watchdog figures
    assert wait_for(lambda: mine().get("watchdog_threshold") == -1.0 and mine()["watchdog_holds"] == 0, 30), mine()
    assert (mine()["link_quality"], mine()["link_warning"]) == ("", ""), mine()  # nor a verdict


def test_recenter_makes_the_current_head_direction_straight_ahead_for_the_holder_only(sim_server, ros, headset,
                                                                                      state, joint_states, watch):
    events = watch("/vr_teleop/events", "vr_teleop_msgs/Event")
    refused_before = call(ros, "/vr_teleop/control/recenter", "std_srvs/Trigger")
    assert refused_before["success"] is False and "engage first" in refused_before["message"], refused_before
    engage(ros)
    headset.head_orientation = unity_yaw_pitch(35.0)
    assert wait_for(lambda: abs(joints(joint_states).get("HeadYaw", 0) - 35.0) < 2.0, 30), joints(joint_states)
    intruder = roslibpy.Ros(host="127.0.0.1", port=sim_server.port)
    intruder.run(timeout=10)
    try:
        other = call(intruder, "/vr_teleop/control/recenter", "std_srvs/Trigger")
        assert other["success"] is False and "only it can recenter" in other["message"], other
    finally:
        intruder.close()
    reply = call(ros, "/vr_teleop/control/recenter", "std_srvs/Trigger")
    assert reply["success"] and "recentered" in reply["message"], reply
    # looking 35 degrees left is now straight ahead: the robot's head comes back to the centre, then follows
    assert wait_for(lambda: abs(joints(joint_states)["HeadYaw"]) < 2.0, 30), joints(joint_states)
    headset.head_orientation = unity_yaw_pitch(50.0)
    assert wait_for(lambda: abs(joints(joint_states)["HeadYaw"] - 15.0) < 2.0, 30), joints(joint_states)
    assert wait_for(lambda: events.any(lambda e: e["kind"] == "recenter"), 30)
    assert state.latest["state"] == "active"
    call(ros, "/vr_teleop/control/engage", "std_srvs/SetBool", {"data": False})
