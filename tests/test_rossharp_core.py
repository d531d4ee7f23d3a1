"""Issue 18's core beyond the stock ROS# rig (test_rossharp.py): the bad input the issue lists, the refusal
mechanism across the server's services, operators made of several connections, time styles and ASCII output."""

from __future__ import annotations

import json
import logging

import pytest
import roslibpy
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from rossharp_client import PoseStampedPublisher, RosSharpConnection, srv_type
from support import RawClient, call, wait_for
from vr_teleop_server.core.wire import ascii_json

TOKEN = "operator-secret-456"
SPECTATOR = "spectator-secret-789"
WHOAMI = "/vr_teleop/whoami"
ENGAGE = "/vr_teleop/control/engage"


@pytest.fixture
def token_server(servers, tmp_path):
    return servers(backend="sim", operator_token=TOKEN, spectator_token=SPECTATOR, record=tmp_path / "session.mcap")


def _call(client: RawClient, service: str, args: dict | None = None, call_id: str = "c1") -> dict:
    client.send({"op": "call_service", "id": call_id, "service": service, "args": args or {}})
    for _ in range(10):
        frame = client.recv(5)
        if frame["op"] == "service_response" and frame.get("id") == call_id:
            return frame
    raise AssertionError("no service_response")


# ---- log-in from the URL ------------------------------------------------------------------------------------------

def test_a_wrong_url_token_gets_401_the_log_says_why_and_others_go_on(token_server, caplog, tmp_path):
    caplog.set_level(logging.DEBUG)
    good = RosSharpConnection(token_server.url, token=TOKEN)
    try:
        with pytest.raises(InvalidStatus) as refused:
            RosSharpConnection(token_server.url, token="wrong-token-000").close()
        assert refused.value.response.status_code == 401
        assert b"not known" in refused.value.response.body
        assert any("refused (401)" in r.getMessage() and "not known" in r.getMessage() for r in caplog.records)
        # the server keeps serving the connection that logged in, and new ones
        assert "/rosout" in good.call_service("/rosapi/topics", srv_type("rosapi/Topics"))["topics"]
        with connect(token_server.url, additional_headers={"Authorization": f"Bearer {TOKEN}"}) as ws:
            ws.send(json.dumps({"op": "call_service", "id": "w", "service": WHOAMI, "args": {}}))
            who = json.loads(ws.recv(5))
            assert who["values"]["role"] == "operator" and who["values"]["success"] is True
        with pytest.raises(InvalidStatus) as bearer:
            connect(token_server.url, additional_headers={"Authorization": "Bearer nope"}).close()
        assert bearer.value.response.status_code == 401
    finally:
        good.close()
    token_server.stop()
    # the server's records (the test's own websockets client logs its request line, token and all, at debug)
    logged = "\n".join(r.getMessage() for r in caplog.records if not r.name.startswith("websockets.client"))
    assert "GET /?token=***" in logged  # websockets' server debug line, redacted
    assert TOKEN not in logged and "wrong-token-000" not in logged
    recording = (tmp_path / "session.mcap").read_bytes()
    assert TOKEN.encode() not in recording and b"wrong-token-000" not in recording


def test_the_auth_op_token_is_not_recorded(token_server, tmp_path):
    client = RawClient(token_server.url)
    try:
        client.send({"op": "auth", "mac": TOKEN})
        assert _call(client, WHOAMI)["values"]["role"] == "operator"
    finally:
        client.close()
    token_server.stop()
    recording = (tmp_path / "session.mcap").read_bytes()
    assert TOKEN.encode() not in recording


def test_whoami_before_any_token_answers_a_clear_error_inside_the_response(token_server):
    client = RawClient(token_server.url)
    try:
        reply = _call(client, WHOAMI)
        assert reply["result"] is True and reply["values"]["success"] is False
        assert "authenticate first" in reply["values"]["message"], reply
        client.send({"op": "auth", "mac": TOKEN})
        who = _call(client, WHOAMI, call_id="c2")["values"]
        assert who["success"] and who["role"] == "operator" and who["operator"].startswith("op-")
        assert TOKEN not in json.dumps(who)
        # the same token on another connection is the same operator
        other = RosSharpConnection(token_server.url, token=TOKEN)
        try:
            assert other.call_service(WHOAMI, srv_type("vr_teleop_msgs/WhoAmI"))["operator"] == who["operator"]
        finally:
            other.close()
        spectator = RosSharpConnection(token_server.url, token=SPECTATOR)
        try:  # a role refusal is readable too
            refused = spectator.call_service(ENGAGE, srv_type("std_srvs/SetBool"), {"data": True})
            assert refused["success"] is False and "spectator" in refused["message"]
        finally:
            spectator.close()
    finally:
        client.close()


def test_a_bad_time_query_is_refused_with_400(token_server):
    with pytest.raises(InvalidStatus) as refused:
        RosSharpConnection(token_server.url, token=TOKEN, time="ros3").close()
    assert refused.value.response.status_code == 400


# ---- refusals: one mechanism across services ----------------------------------------------------------------------

def test_refusals_come_inside_the_response_and_failures_as_result_false(sim_server):
    client = RawClient(sim_server.url)
    try:
        # std_srvs: success false + message
        engage = _call(client, ENGAGE, {"data": True})
        assert engage["result"] is True and engage["values"]["success"] is False
        assert "head pose" in engage["values"]["message"]
        # the project's own type
        menu = _call(client, "/vr_teleop/menu/select", {"id": "no.such.item", "args": ""}, "c2")
        assert menu["result"] is True and menu["values"] == {"success": False, "message": menu["values"]["message"]}
        assert "no.such.item" in menu["values"]["message"]
        # LuxAI's: status false
        gesture = _call(client, "/qt_robot/gesture/play", {"name": "moonwalk", "speed": 1.0}, "c3")
        assert gesture["result"] is True and gesture["values"]["status"] is False
        # calls that could not run: result false with the reason
        missing = _call(client, "/no/such/service", {}, "c4")
        assert missing["result"] is False and "does not exist" in missing["values"]
        bad_args = _call(client, ENGAGE, {"data": "yes"}, "c5")
        assert bad_args["result"] is False and "data" in bad_args["values"]
    finally:
        client.close()


def test_a_client_provided_service_answering_result_false_passes_its_values_on(sim_server, ros):
    provider = RawClient(sim_server.url)
    try:
        provider.send({"op": "advertise_service", "service": "/core_test/add", "type": "rospy_tutorials/AddTwoInts"})
        assert wait_for(lambda: "/core_test/add" in sim_server.call(lambda: set(sim_server.server.bus.services)), 30)
        service = roslibpy.Service(ros, "/core_test/add", "rospy_tutorials/AddTwoInts")
        answers: list = []
        service.call(roslibpy.ServiceRequest({"a": 1, "b": 2}), answers.append, answers.append)
        request = provider.expect("call_service", timeout=5)
        provider.send({"op": "service_response", "id": request["id"], "service": "/core_test/add",
                       "values": {}, "result": False})
        assert wait_for(lambda: answers, 30)
        assert answers[0] == {"sum": 0}  # filled with defaults, as rosbridge does
    finally:
        provider.close()


# ---- one operator, several connections (open access: ?operator=KEY) ----------------------------------------------

def test_connections_with_one_operator_key_share_control_and_another_operator_is_refused(sim_server):
    head = PoseStampedPublisher(sim_server.url, "/vr/head/pose", frame_id="operator", operator="alice")
    alice = RosSharpConnection(sim_server.url, operator="alice")
    bob = RosSharpConnection(sim_server.url, operator="bob")
    try:
        assert wait_for(lambda: head.sent >= 5, 30)
        setbool = srv_type("std_srvs/SetBool")
        assert alice.call_service(ENGAGE, setbool, {"data": True})["success"] is True
        who = alice.call_service(WHOAMI, srv_type("vr_teleop_msgs/WhoAmI"))
        assert who["holding"] is True
        holder = sim_server.call(lambda: sim_server.server.control.holder)
        assert holder == who["operator"] and holder != who["connection"]
        taken = bob.call_service(ENGAGE, setbool, {"data": True})
        assert taken["success"] is False and "held by another" in taken["message"]
        assert bob.call_service(WHOAMI, srv_type("vr_teleop_msgs/WhoAmI"))["holding"] is False
        # the head publisher's connection closing leaves alice holding (another of her connections is open)
        head.stop()
        head.connection.close()
        assert sim_server.call(lambda: sim_server.server.control.holder) == holder
        assert alice.call_service(ENGAGE, setbool, {"data": False})["success"] is True
    finally:
        for c in (alice, bob):
            c.close()
        head.stop()
        head.connection.close()


# ---- time style and text --------------------------------------------------------------------------------------------

def test_a_stamp_in_neither_style_gets_a_clear_error(sim_server):
    client = RawClient(sim_server.url)
    try:
        client.send({"op": "advertise", "topic": "/core_test/pose", "type": "geometry_msgs/PoseStamped"})
        client.send({"op": "publish", "topic": "/core_test/pose",
                     "msg": {"header": {"stamp": {"seconds": 5}, "frame_id": "x"}, "pose": {}}})
        status = client.expect("status", level="error")
        assert "{secs, nsecs}" in status["msg"] and "{sec, nanosec}" in status["msg"], status
        client.alive()
    finally:
        client.close()


def test_a_ros1_connection_keeps_ros1_stamps_beside_a_ros2_one(sim_server):
    ros1 = RawClient(sim_server.url + "/?time=ros1")
    ros2 = RawClient(sim_server.url + "/?time=ros2")
    try:
        for client in (ros1, ros2):
            client.send({"op": "subscribe", "topic": "/qt_robot/joints/state", "type": "sensor_msgs/JointState"})
        one, two = ros1.expect("publish", timeout=5), ros2.expect("publish", timeout=5)
        assert set(one["msg"]["header"]["stamp"]) == {"secs", "nsecs"}
        assert set(two["msg"]["header"]["stamp"]) == {"sec", "nanosec"}
        assert one["msg"]["name"] == two["msg"]["name"]
    finally:
        ros1.close()
        ros2.close()


def test_ascii_json_escapes_every_non_ascii_character_as_json_reads_it():
    text = json.dumps({"data": "Très bien, ça marche 🤖"}, ensure_ascii=False)
    escaped = ascii_json(text)
    assert escaped.isascii() and json.loads(escaped) == json.loads(text)
    assert ascii_json('{"data":"plain"}') == '{"data":"plain"}'


def test_a_file_server_path_outside_the_package_is_refused_readably(sim_server):
    client = RawClient(sim_server.url)
    try:
        client.send({"op": "set_level", "level": "warning"})
        client.send({"op": "call_service", "id": "f", "service": "/file_server/get_file",
                     "args": {"name": "package://qtrobot_description/../../etc/passwd"}})
        frames = [client.recv(5), client.recv(5)]
        response = next(f for f in frames if f["op"] == "service_response")
        warning = next(f for f in frames if f["op"] == "status")
        assert response["result"] is True and response["values"] == {"value": ""}
        assert warning["level"] == "warning" and "'..'" in warning["msg"], warning
        client.alive()
    finally:
        client.close()
