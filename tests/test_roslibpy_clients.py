"""roslibpy, the real third-party client, against the running server: Topic, Service, Param, ActionClient, rosapi."""

from __future__ import annotations

import threading
import time

import pytest
import roslibpy

from support import wait_for


@pytest.fixture
def ros_factory(server):
    clients: list[roslibpy.Ros] = []

    def make() -> roslibpy.Ros:
        ros = roslibpy.Ros(host="127.0.0.1", port=server.port)
        ros.run(timeout=10)
        assert ros.is_connected
        clients.append(ros)
        return ros

    yield make
    for ros in clients:
        ros.close()  # not terminate(): the Twisted reactor is shared by every test in the process


def test_topic_publish_subscribe_between_two_clients(ros_factory):
    a, b = ros_factory(), ros_factory()
    received = []
    listener = roslibpy.Topic(b, "/vr/head/pose", "geometry_msgs/PoseStamped")
    listener.subscribe(received.append)
    talker = roslibpy.Topic(a, "/vr/head/pose", "geometry_msgs/PoseStamped")
    pose = {"header": {"seq": 1, "stamp": {"secs": 1, "nsecs": 2}, "frame_id": "unity_left_handed"},
            "pose": {"position": {"x": 0.0, "y": 1.6, "z": 0.2}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0,
                                                                                   "w": 1.0}}}
    assert wait_for(lambda: b.get_topic_type("/vr/head/pose") == "geometry_msgs/PoseStamped")
    for _ in range(5):
        talker.publish(roslibpy.Message(pose))
    assert wait_for(lambda: len(received) == 5), received
    assert received[0] == pose
    listener.unsubscribe()
    talker.unadvertise()


def test_service_advertised_by_one_client_called_by_another(ros_factory):
    provider_ros, caller_ros = ros_factory(), ros_factory()
    calls = []

    def handler(request, response):
        calls.append(request["data"])
        response["success"] = request["data"]
        response["message"] = "engaged" if request["data"] else "released"
        return True

    service = roslibpy.Service(provider_ros, "/vr_teleop/test/engage", "std_srvs/SetBool")
    service.advertise(handler)
    assert wait_for(lambda: "/vr_teleop/test/engage" in caller_ros.get_services())
    client = roslibpy.Service(caller_ros, "/vr_teleop/test/engage", "std_srvs/SetBool")
    assert client.call(roslibpy.ServiceRequest({"data": True}), timeout=5) == {"success": True, "message": "engaged"}
    assert client.call(roslibpy.ServiceRequest({"data": False}), timeout=5)["message"] == "released"
    assert calls == [True, False]
    assert caller_ros.get_service_type("/vr_teleop/test/engage") == "std_srvs/SetBool"


def test_service_errors_reach_roslibpy_errback(ros_factory):
    ros = ros_factory()
    errors = []
    done = threading.Event()
    roslibpy.Service(ros, "/does/not/exist", "std_srvs/Trigger").call(
        roslibpy.ServiceRequest({}), callback=lambda r: done.set(), errback=lambda e: (errors.append(e), done.set()))
    assert done.wait(5)
    assert errors == ["service /does/not/exist does not exist"]


def test_params(ros_factory):
    ros = ros_factory()
    param = roslibpy.Param(ros, "/vr_teleop/operator_name")
    assert param.get(timeout=5) is None  # a missing parameter reads as null
    param.set({"name": "Ms. Smith", "arm_ratio": 1.2}, timeout=5)
    assert param.get(timeout=5) == {"name": "Ms. Smith", "arm_ratio": 1.2}
    assert "/vr_teleop/operator_name" in ros.get_params()
    param.delete(timeout=5)
    assert param.get(timeout=5) is None


def test_rosapi_introspection(ros_factory):
    ros = ros_factory()
    topic = roslibpy.Topic(ros, "/robot/joints", "sensor_msgs/JointState")
    topic.advertise()
    assert wait_for(lambda: "/robot/joints" in ros.get_topics())
    assert "/rosout" in ros.get_topics()
    assert ros.get_topics_for_type("sensor_msgs/JointState") == ["/robot/joints"]
    assert "/rosapi/topics" in ros.get_services()
    assert ros.get_services_for_type("rosapi/Topics") == ["/rosapi/topics"]
    assert "/rosapi" in ros.get_nodes()
    details = ros.get_message_details("sensor_msgs/JointState")["typedefs"]
    assert details[0]["fieldnames"] == ["header", "name", "position", "velocity", "effort"]
    assert details[0]["fieldarraylen"] == [-1, 0, 0, 0, 0]
    assert {d["type"] for d in details} == {"sensor_msgs/JointState", "std_msgs/Header"}
    request = ros.get_service_request_details("std_srvs/SetBool")["typedefs"][0]
    assert request["fieldnames"] == ["data"] and request["fieldtypes"] == ["bool"]
    now = ros.get_time()
    assert abs(now["secs"] - time.time()) < 5


def test_action_client_against_a_client_provided_action(ros_factory, server, connect_raw):
    provider = connect_raw(server.url)
    provider.send({"op": "advertise_action", "action": "/qt_robot/gesture/play_action",
                   "type": "qt_gesture_msgs/action/Play"})
    provider.alive()
    ros = ros_factory()
    action = roslibpy.ActionClient(ros, "/qt_robot/gesture/play_action", "qt_gesture_msgs/action/Play")
    feedback, results, errors = [], [], []
    goal_id = action.send_goal(roslibpy.Goal({"name": "QT/bye"}), results.append, feedback.append, errors.append)
    goal = provider.expect("send_action_goal", timeout=5)
    assert goal["args"] == {"name": "QT/bye"}
    provider.send({"op": "action_feedback", "id": goal["id"], "action": goal["action"], "values": {"done": 0.5}})
    provider.send({"op": "action_result", "id": goal["id"], "action": goal["action"], "values": {"ok": True},
                   "status": 4, "result": True})
    action.wait_goal(goal_id, timeout=5)
    assert feedback == [{"done": 0.5}]
    assert results[0]["values"] == {"ok": True} and results[0]["status"].value == 4
    assert errors == []
