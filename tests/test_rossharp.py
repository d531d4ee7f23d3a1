"""A stock ROS# Unity rig against the server, through a client that behaves as ROS# does (rossharp_client.py).

What works today is asserted plainly. What issue 18's core work fixes is marked xfail(strict=True): each such test
states the behaviour ROS# needs, fails today for the reason given, and must flip to passing when the core lands
(strict: an unexpected pass fails the run, so the marks are removed then).
"""

from __future__ import annotations

import base64
import json
import math
import re
from collections.abc import Iterator

import cv2
import numpy as np
import pytest
from websockets.exceptions import InvalidStatus

from robot_models import load_qtrobot
from robot_models.urdf import resolve_package_uri
from rossharp_client import (
    JoyPublisher, PoseStampedPublisher, RosSharpBroken, RosSharpConnection, Subscriber, msg_type, read_ros2_time,
    srv_type,
)
from support import wait_for

MODEL = load_qtrobot()
ISSUE18 = "issue 18 core: "
HEAD_TOPIC = "/vr/head/pose"
ENGAGE = "/vr_teleop/control/engage"
JOINTS = "/qt_robot/joints/state"
TOKEN = "operator-secret-123"


def _yaw_left(deg: float) -> tuple[float, float, float, float]:
    """A Unity rotation turning the head left by `deg` (Unity's y is up and left-handed: left is negative)."""
    half = math.radians(-deg) / 2
    return (0.0, math.sin(half), 0.0, math.cos(half))


@pytest.fixture
def rig(sim_server) -> Iterator[list]:
    """Components opened by a test, closed after it; control is free again afterwards."""
    made: list = []
    yield made
    for component in reversed(made):
        (component.stop if hasattr(component, "stop") else component.close)()
        if hasattr(component, "connection"):
            component.connection.close()
    assert wait_for(lambda: sim_server.call(lambda: sim_server.server.control.holder) is None, 30)


def _joints(sub: Subscriber) -> dict[str, float]:
    return dict(zip(sub.latest.get("name", []), sub.latest.get("position", [])))


def _settle_head_ahead(joints: Subscriber) -> None:
    """With the operator looking straight ahead, the robot's head comes to HeadYaw 0 (from wherever it was)."""
    assert wait_for(lambda: abs(_joints(joints).get("HeadYaw", 99.0)) < 2.0, 30), _joints(joints)


def _engage(connection: RosSharpConnection, on: bool = True) -> dict:
    return connection.call_service(ENGAGE, srv_type("std_srvs/SetBool"), {"data": on})


# ---- what works today ---------------------------------------------------------------------------------------------

def test_joint_states_arrive_on_a_ros2_typed_subscription(sim_server, rig):
    joints = Subscriber(sim_server.url, JOINTS, msg_type("sensor_msgs/JointState"))
    rig.append(joints)
    assert wait_for(lambda: len(joints.messages) >= 3, 30)
    assert set(joints.latest["name"]) == set(MODEL.names)
    assert len(joints.latest["position"]) == len(MODEL.names)
    assert joints.connection.broken is None


def test_a_service_call_with_a_ros2_type_name_returns_its_values(sim_server, rig):
    connection = RosSharpConnection(sim_server.url)
    rig.append(connection)
    topics = connection.call_service("/rosapi/topics", srv_type("rosapi/Topics"))
    assert JOINTS in topics["topics"] and len(topics["types"]) == len(topics["topics"])
    selected = connection.call_service("/vr_teleop/menu/select", srv_type("vr_teleop_msgs/MenuSelect"),
                                       {"id": "emotion.happy", "args": ""})
    assert selected["success"] is True, selected


def test_camera_frames_arrive_whole_as_jpeg(sim_server, rig):
    camera = Subscriber(sim_server.url, "/camera/color/image_raw/compressed", msg_type("sensor_msgs/CompressedImage"))
    rig.append(camera)
    assert wait_for(lambda: camera.messages, 30)
    frame = camera.latest
    image = cv2.imdecode(np.frombuffer(base64.b64decode(frame["data"]), np.uint8), cv2.IMREAD_COLOR)
    assert image is not None and image.shape[:2] == (MODEL.camera.height, MODEL.camera.width)
    assert "fragment" not in camera.connection.ignored_ops  # int-max fragment_size: never split


def test_poses_in_ros_axes_turn_the_head_when_the_frame_id_is_not_unity(sim_server, rig):
    """The pose path works for a ROS# rig whose inspector frame id is not "Unity" (engage on the head's own
    connection, as the server requires today)."""
    head = PoseStampedPublisher(sim_server.url, HEAD_TOPIC, frame_id="operator")
    joints = Subscriber(sim_server.url, JOINTS, msg_type("sensor_msgs/JointState"))
    rig.extend([joints, head])
    assert wait_for(lambda: head.sent >= 5, 30)
    assert _engage(head.connection)["success"] is True
    _settle_head_ahead(joints)  # the robot holds where an earlier test left it
    head.rotation = _yaw_left(30.0)
    assert wait_for(lambda: abs(_joints(joints).get("HeadYaw", 0.0) - 30.0) < 3.0, 30), _joints(joints)
    assert _engage(head.connection, False)["success"] is True


# ---- what issue 18's core work fixes ------------------------------------------------------------------------------

def test_ros_sharp_default_frame_id_unity_is_already_in_ros_axes(sim_server, rig):
    head = PoseStampedPublisher(sim_server.url, HEAD_TOPIC)  # frame_id "Unity", 50 Hz, ROS axes
    joints = Subscriber(sim_server.url, JOINTS, msg_type("sensor_msgs/JointState"))
    rig.extend([joints, head])
    assert wait_for(lambda: head.sent >= 5, 30)
    assert _engage(head.connection)["success"] is True
    try:
        _settle_head_ahead(joints)  # looking ahead reads the same in either axes
        head.rotation = _yaw_left(-25.0)  # to the right
        assert wait_for(lambda: abs(_joints(joints).get("HeadYaw", 0.0) + 25.0) < 3.0, 30), _joints(joints)
    finally:
        _engage(head.connection, False)


def test_take_control_pressed_twice_changes_nothing(sim_server, rig):
    """A rig whose "take control" button is pressed again while it holds control: the second engage answers
    success, says control is already held, and does not re-zero the head (the robot keeps following where the
    operator looks, it does not swing back to the centre)."""
    head = PoseStampedPublisher(sim_server.url, HEAD_TOPIC)
    joints = Subscriber(sim_server.url, JOINTS, msg_type("sensor_msgs/JointState"))
    rig.extend([joints, head])
    assert wait_for(lambda: head.sent >= 5, 30)
    assert _engage(head.connection)["success"] is True
    try:
        _settle_head_ahead(joints)
        head.rotation = _yaw_left(30.0)
        assert wait_for(lambda: abs(_joints(joints).get("HeadYaw", 0.0) - 30.0) < 3.0, 30), _joints(joints)
        again = _engage(head.connection)
        assert again["success"] is True and "already held" in again["message"], again
        head.rotation = _yaw_left(40.0)  # re-zeroed at 30 this would be 10
        assert wait_for(lambda: abs(_joints(joints).get("HeadYaw", 0.0) - 40.0) < 3.0, 30), _joints(joints)
        recentered = head.connection.call_service("/vr_teleop/control/recenter", srv_type("std_srvs/Trigger"))
        assert recentered["success"] is True, recentered
        assert wait_for(lambda: abs(_joints(joints).get("HeadYaw", 99.0)) < 3.0, 30), _joints(joints)
    finally:
        _engage(head.connection, False)


def test_a_refusal_is_a_response_ros_sharp_can_read(sim_server, rig):
    connection = RosSharpConnection(sim_server.url)
    rig.append(connection)
    refused = _engage(connection)
    assert refused["success"] is False and refused["message"], refused
    # the connection is still alive: a menu item that fails is also a readable refusal
    failed = connection.call_service("/vr_teleop/menu/select", srv_type("vr_teleop_msgs/MenuSelect"),
                                     {"id": "no.such.item", "args": ""})
    assert failed["success"] is False and "no.such.item" in failed["message"], failed
    assert "/rosout" in connection.call_service("/rosapi/topics", srv_type("rosapi/Topics"))["topics"]


def test_text_reaches_an_ascii_decoding_client_intact(sim_server, rig):
    listener = Subscriber(sim_server.url, "/rossharp_test/text", msg_type("std_msgs/String"))
    talker = RosSharpConnection(sim_server.url)
    rig.extend([listener, talker])
    talker.advertise("/rossharp_test/text", msg_type("std_msgs/String"))
    assert wait_for(lambda: (talker.publish("/rossharp_test/text", {"data": "Très bien, ça marche"}),
                             listener.messages)[1], 30)
    assert listener.latest["data"] == "Très bien, ça marche"


def test_the_time_style_is_learned_from_the_first_stamp_a_connection_sends(sim_server, rig):
    head = PoseStampedPublisher(sim_server.url, "/rossharp_test/pose", frame_id="operator")  # ROS 2 stamps
    rig.append(head)
    assert wait_for(lambda: head.sent >= 3, 30)
    seen: list[dict] = []
    head.connection.subscribe(JOINTS, msg_type("sensor_msgs/JointState"), seen.append)
    assert wait_for(lambda: seen, 30)
    assert read_ros2_time(seen[-1]["header"]["stamp"])[0] > 0, seen[-1]["header"]


def test_the_time_style_can_be_set_in_the_url(sim_server, rig):
    joints = Subscriber(sim_server.url, JOINTS, msg_type("sensor_msgs/JointState"), time="ros2")
    rig.append(joints)
    assert wait_for(lambda: joints.messages, 30)
    assert read_ros2_time(joints.latest["header"]["stamp"])[0] > 0, joints.latest["header"]


def test_the_robot_avatar_imports_from_robot_description_and_file_server(sim_server, rig):
    connection = RosSharpConnection(sim_server.url)
    rig.append(connection)
    param = connection.call_service("/rosapi/get_param", srv_type("rosapi/GetParam"), {"name": "robot_description"})
    urdf = json.loads(param["value"] or "null")  # rosapi returns parameter values as JSON text
    assert isinstance(urdf, str), f"robot_description is {param['value']!r}"
    assert "<robot" in urdf and all(f'name="{n}"' in urdf for n in MODEL.names)
    uris = sorted(set(re.findall(r'filename="(package://[^"]+)"', urdf)))
    assert uris
    for uri in uris:
        got = connection.call_service("/file_server/get_file", srv_type("file_server/GetBinaryFile"), {"name": uri})
        assert base64.b64decode(got["value"]) == resolve_package_uri(uri).read_bytes()
    outside = connection.call_service("/file_server/get_file", srv_type("file_server/GetBinaryFile"),
                                      {"name": "package://qtrobot_description/../../etc/passwd"})
    assert outside.get("value", "") == ""  # refused, and the connection still reads responses
    assert connection.call_service("/rosapi/topics", srv_type("rosapi/Topics"))["topics"]


def test_joint_states_in_radians_for_the_joint_state_patcher(sim_server, rig):
    radians = Subscriber(sim_server.url, "/joint_states", msg_type("sensor_msgs/JointState"))
    degrees = Subscriber(sim_server.url, JOINTS, msg_type("sensor_msgs/JointState"))
    rig.extend([radians, degrees])
    assert wait_for(lambda: radians.messages and degrees.messages, 30)
    rad, deg = dict(zip(radians.latest["name"], radians.latest["position"])), _joints(degrees)
    assert set(rad) == set(MODEL.names)
    for name in MODEL.names:  # the stand-in rests at home: compare loosely, both are live readings
        assert abs(math.degrees(rad[name]) - deg[name]) < 2.0, (name, rad[name], deg[name])


# ---- log-in from the URL (a server with tokens) ------------------------------------------------------------------

@pytest.fixture
def token_server(servers):
    return servers(operator_token=TOKEN)


def test_a_token_in_the_url_logs_in(token_server):
    connection = RosSharpConnection(token_server.url, token=TOKEN)
    try:
        assert "/rosout" in connection.call_service("/rosapi/topics", srv_type("rosapi/Topics"), timeout=5)["topics"]
    finally:
        connection.close()


def test_a_wrong_token_in_the_url_is_refused_at_the_handshake(token_server):
    with pytest.raises(InvalidStatus) as refused:
        RosSharpConnection(token_server.url, token="not-the-token").close()
    assert refused.value.response.status_code == 401


@pytest.fixture
def token_sim_server(servers):
    return servers(backend="sim", operator_token=TOKEN)


def test_one_operator_on_several_connections_engages_from_any(token_sim_server):
    url = token_sim_server.url
    components: list = []
    try:
        head = PoseStampedPublisher(url, HEAD_TOPIC, frame_id="operator", token=TOKEN)
        right = PoseStampedPublisher(url, "/vr/right_controller/pose", frame_id="operator", token=TOKEN)
        joy = JoyPublisher(url, "/vr/right_controller/joy", token=TOKEN)
        joints = Subscriber(url, JOINTS, msg_type("sensor_msgs/JointState"), token=TOKEN)
        buttons = RosSharpConnection(url, token=TOKEN)  # the menu/engage button's own RosConnector
        components += [head, right, joy, joints, buttons]
        assert wait_for(lambda: head.sent >= 5, 30)
        assert _engage(buttons)["success"] is True
        _settle_head_ahead(joints)
        head.rotation = _yaw_left(20.0)
        assert wait_for(lambda: abs(_joints(joints).get("HeadYaw", 0.0) - 20.0) < 3.0, 30), _joints(joints)
        # the right hand forward with the grip held (the scene's readers give the grip as the fourth axis)
        before = _joints(joints)
        right.position = (0.19, 1.4, 0.55)
        joy.axes[3] = 1.0
        arm = MODEL.part_joints("right_arm")
        assert wait_for(lambda: max(abs(_joints(joints)[n] - before[n]) for n in arm) > 20.0, 30), _joints(joints)
        assert _engage(buttons, False)["success"] is True
    finally:
        for component in reversed(components):
            (component.stop if hasattr(component, "stop") else component.close)()
            if hasattr(component, "connection"):
                component.connection.close()


def test_the_client_surfaces_a_broken_connection_as_ros_sharp_would(sim_server, rig):
    """The test client itself: a response whose values are not an object breaks it (as ROS#'s receive loop
    ends), and every later call says so instead of waiting forever. Today engage-before-pose produces one."""
    connection = RosSharpConnection(sim_server.url)
    rig.append(connection)
    try:
        values = _engage(connection)
    except RosSharpBroken:
        with pytest.raises(RosSharpBroken, match="stopped receiving"):
            connection.call_service("/rosapi/topics", srv_type("rosapi/Topics"))
    else:  # issue 18's core answers the refusal inside the response: then the client must not break
        assert values["success"] is False and connection.broken is None
