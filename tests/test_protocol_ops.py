"""Every rosbridge op and every error case, over a real WebSocket, asserting the exact replies."""

from __future__ import annotations

import base64
import json
import struct
import threading
import time

import cbor2
import pytest

from client_protocol import ops
from testbed.server import Pace
from vr_teleop_server.core.session.dispatch import OP_HANDLERS, Session
from vr_teleop_server.core.wire import png_unpack

POSE = {"header": {"seq": 3, "stamp": {"secs": 10, "nsecs": 20}, "frame_id": "unity_left_handed"},
        "pose": {"position": {"x": 0.1, "y": 1.6, "z": 0.3}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}


def test_every_client_op_has_one_handler_of_the_session():
    """The table of handlers and the ops' models name the same ops, each handled by the session's own method."""
    assert list(OP_HANDLERS) == list(ops.CLIENT_OPS)
    assert all(getattr(Session, f"_op_{ops.op_name(model)}") is handler for model, handler in OP_HANDLERS.items())


def test_publish_reaches_subscriber_with_defaults_filled(client_factory):
    sub, pub = client_factory(), client_factory()
    sub.send({"op": "subscribe", "id": "s1", "topic": "/vr/head/pose", "type": "geometry_msgs/PoseStamped"})
    pub.send({"op": "advertise", "id": "a1", "topic": "/vr/head/pose", "type": "geometry_msgs/msg/PoseStamped"})
    pub.send({"op": "publish", "id": "p1", "topic": "/vr/head/pose", "msg": POSE})
    assert sub.expect("publish", topic="/vr/head/pose")["msg"] == POSE
    pub.send({"op": "publish", "topic": "/vr/head/pose", "msg": {"pose": {"position": {"x": 1}}}})
    msg = sub.expect("publish")["msg"]
    assert msg["pose"] == {"position": {"x": 1.0, "y": 0.0, "z": 0.0},
                           "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 0.0}}
    assert msg["header"]["frame_id"] == "" and abs(msg["header"]["stamp"]["secs"] - time.time()) < 5
    assert pub.silent(0.2)  # the publisher did not subscribe, so it gets nothing back


def test_one_frame_per_topic_per_connection_including_the_publisher(client):
    client.send({"op": "subscribe", "id": "a", "topic": "/t", "type": "std_msgs/String"})
    client.send({"op": "subscribe", "id": "b", "topic": "/t", "type": "std_msgs/String"})
    client.send({"op": "subscribe", "topic": "/t"})
    client.send({"op": "publish", "topic": "/t", "msg": {"data": "once"}})
    assert client.expect("publish", topic="/t")["msg"] == {"data": "once"}
    assert client.silent()


def test_unsubscribe_by_id_and_without_id(client):
    client.send({"op": "advertise", "topic": "/t", "type": "std_msgs/String"})
    client.send({"op": "subscribe", "id": "a", "topic": "/t", "type": "std_msgs/String"})
    client.send({"op": "subscribe", "id": "b", "topic": "/t", "type": "std_msgs/String"})
    client.send({"op": "unsubscribe", "id": "a", "topic": "/t"})
    client.send({"op": "publish", "topic": "/t", "msg": {"data": "b still holds"}})
    assert client.expect("publish")["msg"]["data"] == "b still holds"
    client.send({"op": "subscribe", "id": "c", "topic": "/t"})
    client.send({"op": "unsubscribe", "topic": "/t"})  # no id: every subscription goes
    client.send({"op": "publish", "topic": "/t", "msg": {"data": "nobody"}})
    assert client.silent()
    client.send({"op": "unsubscribe", "id": "zz", "topic": "/t"})
    client.send({"op": "set_level", "level": "warning"})
    client.send({"op": "unsubscribe", "id": "zz", "topic": "/t"})
    status = client.expect("status", level="warning", id="zz")
    assert "not subscribed to /t" in status["msg"]


def test_type_names_with_and_without_msg_are_one_type(client):
    client.send({"op": "advertise", "topic": "/j", "type": "sensor_msgs/msg/JointState"})
    client.send({"op": "subscribe", "topic": "/j", "type": "sensor_msgs/JointState"})
    client.send({"op": "publish", "topic": "/j", "msg": {"name": ["HeadYaw"], "position": [1.5]}})
    assert client.expect("publish")["msg"]["position"] == [1.5]


def test_type_mismatch_and_misfit_message_get_status_naming_the_field(client):
    client.send({"op": "advertise", "topic": "/f", "type": "std_msgs/Float64"})
    client.send({"op": "advertise", "id": "x", "topic": "/f", "type": "std_msgs/String"})
    assert client.expect("status", level="error", id="x")["msg"] == \
        "advertise: topic /f has type std_msgs/Float64, not std_msgs/String"
    client.send({"op": "publish", "id": "p", "topic": "/f", "msg": {"data": "not a number"}})
    status = client.expect("status", level="error", id="p")
    assert "msg.data" in status["msg"] and "'not a number'" in status["msg"]
    client.send({"op": "publish", "id": "q", "topic": "/f", "msg": {"value": 1.0}})
    assert "'msg.value' is not a field" in client.expect("status", id="q")["msg"]
    client.alive()


def test_publish_to_unknown_topic_and_subscribe_without_type(client):
    client.send({"op": "publish", "id": 7, "topic": "/nowhere", "msg": {}})
    assert client.expect("status", id=7)["msg"] == \
        "publish: topic /nowhere does not exist: advertise it with a type before publishing"
    client.send({"op": "subscribe", "id": "s", "topic": "/nowhere"})
    assert "give 'type' when subscribing" in client.expect("status", id="s")["msg"]


def test_unknown_types_travel_as_opaque_json_exactly(client_factory):
    a, b = client_factory(), client_factory()
    custom = {"anything": [1, "two", {"three": None}], "nested": {"x": 1.5}}
    b.send({"op": "subscribe", "topic": "/unity/custom", "type": "unity_msgs/Whatever"})
    a.send({"op": "advertise", "topic": "/unity/custom", "type": "unity_msgs/msg/Whatever"})
    a.send({"op": "publish", "topic": "/unity/custom", "msg": custom})
    assert b.expect("publish")["msg"] == custom


def test_uint8_arrays_go_out_as_base64_and_come_in_either_way(client):
    client.send({"op": "subscribe", "topic": "/audio", "type": "audio_common_msgs/AudioData"})
    client.send({"op": "publish", "topic": "/audio", "msg": {"data": [0, 1, 254, 255]}})
    assert client.expect("publish")["msg"]["data"] == base64.b64encode(bytes([0, 1, 254, 255])).decode()
    client.send({"op": "publish", "topic": "/audio", "msg": {"data": "AAEC"}})
    assert client.expect("publish")["msg"]["data"] == "AAEC"
    client.send({"op": "publish", "id": "bad", "topic": "/audio", "msg": {"data": [1, 256]}})
    assert "0..255" in client.expect("status", id="bad")["msg"]


def test_time_accepts_both_styles_and_sends_the_configured_one(servers, connect_raw):
    for style, expected in (("ros1", {"secs": 5, "nsecs": 6}), ("ros2", {"sec": 5, "nanosec": 6})):
        srv = servers(time_style=style)
        c = connect_raw(srv.url)
        c.send({"op": "subscribe", "topic": "/h", "type": "std_msgs/Header"})
        for stamp in ({"secs": 5, "nsecs": 6}, {"sec": 5, "nanosec": 6}):
            c.send({"op": "publish", "topic": "/h", "msg": {"stamp": stamp, "frame_id": "f"}})
            assert c.expect("publish")["msg"]["stamp"] == expected


def test_latched_topic_delivers_last_message_to_late_subscriber(client_factory):
    a, b = client_factory(), client_factory()
    a.send({"op": "advertise", "topic": "/menus", "type": "std_msgs/String", "latch": True})
    a.send({"op": "publish", "topic": "/menus", "msg": {"data": "first"}})
    a.send({"op": "publish", "topic": "/menus", "msg": {"data": "last"}})
    a.alive()  # both publishes were handled
    b.send({"op": "subscribe", "topic": "/menus", "type": "std_msgs/String"})
    assert b.expect("publish")["msg"] == {"data": "last"}
    assert b.silent()


def test_throttle_rate_sends_at_most_one_message_per_interval(client_factory):
    client, publisher = client_factory(), client_factory()
    client.send({"op": "subscribe", "topic": "/fast", "type": "std_msgs/Int32", "throttle_rate": 200})
    client.alive()

    sent_at: list[float] = []  # the publisher's own clock: when each message left

    def publish() -> None:
        pace = Pace(50)
        for i in range(30):
            sent_at.append(time.monotonic())
            publisher.send({"op": "publish", "topic": "/fast", "msg": {"data": i}})
            pace.wait()

    thread = threading.Thread(target=publish)
    thread.start()
    received = []
    while not received or received[-1][1]["msg"]["data"] != 29:  # until the newest arrives (the timeout: a hang)
        message = client.recv(timeout=30)
        received.append((time.monotonic(), message))
    thread.join()
    datas = [m["msg"]["data"] for _, m in received]
    assert datas[0] == 0 and datas[-1] == 29  # the first goes out at once; the newest is kept, not lost
    assert datas == sorted(set(datas)), datas  # in order, none twice
    # At most one message per 200 ms interval: the k-th can leave no sooner than k intervals after the first
    # publish, whatever the load (a loaded machine only delays and merges them). Counted on the publisher's clock.
    for k, (arrived, message) in enumerate(received):
        assert arrived - sent_at[0] >= k * 0.2 - 0.005, (k, arrived - sent_at[0], datas)
    assert len(datas) <= (received[-1][0] - sent_at[0]) / 0.2 + 1, datas
    assert client.silent(), "a message after the newest"


def test_queue_length_keeps_the_newest_and_drops_the_oldest(client):
    client.send({"op": "subscribe", "topic": "/q", "type": "std_msgs/Int32", "throttle_rate": 300,
                 "queue_length": 3})
    for i in range(10):
        client.send({"op": "publish", "topic": "/q", "msg": {"data": i}})
    datas = []
    while True:
        try:
            datas.append(client.expect("publish", timeout=1)["msg"]["data"])
        except TimeoutError:
            break
    # The throttle lets one message go at once: whichever was oldest in the queue when the writer woke (0, or on a
    # busy machine a later one, the queue already full), or none if all ten came first; after it, the newest three.
    assert datas[-3:] == [7, 8, 9] and len(datas) <= 4, datas
    assert len(datas) == 3 or datas[0] < 7, datas


def test_outgoing_fragments_honour_fragment_size(client):
    client.send({"op": "subscribe", "id": "s", "topic": "/big", "type": "std_msgs/String", "fragment_size": 50})
    text = "x" * 300
    client.send({"op": "publish", "topic": "/big", "msg": {"data": text}})
    pieces = [client.expect("fragment")]
    total = pieces[0]["total"]
    pieces += [client.expect("fragment") for _ in range(total - 1)]
    assert [p["num"] for p in pieces] == list(range(total)) and len({p["id"] for p in pieces}) == 1
    assert all(len(p["data"]) <= 50 for p in pieces)
    assert json.loads("".join(p["data"] for p in pieces)) == {"op": "publish", "topic": "/big", "msg": {"data": text}}


def test_incoming_fragments_reassemble_in_any_order(client):
    client.send({"op": "subscribe", "topic": "/chat", "type": "std_msgs/String"})
    text = json.dumps({"op": "publish", "topic": "/chat", "msg": {"data": "from pieces"}})
    parts = [text[i:i + 10] for i in range(0, len(text), 10)]
    order = list(range(len(parts)))[::-1]
    for n in order:
        client.send({"op": "fragment", "id": "f1", "data": parts[n], "num": n, "total": len(parts)})
    assert client.expect("publish")["msg"] == {"data": "from pieces"}


def test_fragment_errors(client):
    client.send({"op": "fragment", "id": "f", "data": "{", "num": 3, "total": 2})
    assert "out of range" in client.expect("status", id="f")["msg"]
    client.send({"op": "fragment", "id": "g", "data": "ab", "num": 0, "total": 3})
    client.send({"op": "fragment", "id": "g", "data": "XY", "num": 0, "total": 3})
    assert "arrived twice with different data" in client.expect("status", id="g")["msg"]
    client.send({"op": "fragment", "id": "h", "data": "ab", "num": 0, "total": 3})
    client.send({"op": "fragment", "id": "h", "data": "cd", "num": 1, "total": 4})
    assert "says total 4" in client.expect("status", id="h")["msg"]
    client.alive()


def test_incomplete_fragments_are_discarded_after_the_timeout(servers, connect_raw):
    srv = servers(fragment_timeout=0.3)
    c = connect_raw(srv.url)
    c.send({"op": "set_level", "level": "warning"})
    c.send({"op": "fragment", "id": "lost", "data": "{\"op\":", "num": 0, "total": 2})
    status = c.expect("status", level="warning", id="lost", timeout=2)
    assert "1 of 2 arrived" in status["msg"]
    assert srv.call(lambda: sum(len(s.fragments) for s in srv.server.sessions.values())) == 0


def test_png_compression_round_trips(client):
    client.send({"op": "subscribe", "topic": "/p", "type": "std_msgs/String", "compression": "png"})
    client.send({"op": "publish", "topic": "/p", "msg": {"data": "pixels ünïcode"}})
    frame = client.expect("png")
    assert json.loads(png_unpack(frame["data"])) == {"op": "publish", "topic": "/p", "msg": {"data": "pixels ünïcode"}}


def test_cbor_compression_sends_binary_with_typed_arrays(client):
    client.send({"op": "subscribe", "topic": "/js", "type": "sensor_msgs/JointState", "compression": "cbor"})
    client.send({"op": "publish", "topic": "/js", "msg": {"name": ["a", "b"], "position": [1.5, -2.0]}})
    frame = client.recv_frame()
    assert isinstance(frame, bytes)
    decoded = cbor2.loads(frame)
    assert decoded["op"] == "publish" and decoded["msg"]["name"] == ["a", "b"]
    tag = decoded["msg"]["position"]
    assert isinstance(tag, cbor2.CBORTag) and tag.tag == 86  # float64 little-endian typed array
    assert struct.unpack("<2d", tag.value) == (1.5, -2.0)


def test_cbor_raw_carries_ros1_bytes(client):
    client.send({"op": "subscribe", "topic": "/s", "type": "std_msgs/String", "compression": "cbor-raw"})
    client.send({"op": "publish", "topic": "/s", "msg": {"data": "hey"}})
    decoded = cbor2.loads(client.recv_frame())
    assert decoded["msg"]["bytes"] == b"\x03\x00\x00\x00hey"
    assert decoded["msg"]["secs"] > 0


def test_binary_json_frames_are_accepted_like_ros_sharp_sends_them(client):
    client.send({"op": "subscribe", "topic": "/b", "type": "std_msgs/String"})
    payload = json.dumps({"op": "publish", "topic": "/b", "msg": {"data": "y" * 3000}}).encode()
    client.ws.send([payload[i:i + 1024] for i in range(0, len(payload), 1024)])  # continuation frames
    assert client.expect("publish")["msg"]["data"] == "y" * 3000
    client.send_raw(cbor2.dumps({"op": "publish", "topic": "/b", "msg": {"data": "cbor in"}}))
    assert client.expect("publish")["msg"]["data"] == "cbor in"


def test_binary_pose_frames_publish_like_their_json_frames_and_bad_ones_are_named(client_factory):
    """A pose frame (client_protocol/pose_frame.py) on the WebSocket publishes each of its messages as the JSON
    publish frame would; one that is not a pose frame of this version gets a status naming why, and the
    connection goes on."""
    from client_protocol import pose_frame

    sub, pub = client_factory(), client_factory()
    for topic in ("/vr/head/pose", "/vr/left_controller/joy"):
        sub.send({"op": "subscribe", "topic": topic, "type": "geometry_msgs/PoseStamped" if "pose" in topic
                  else "sensor_msgs/Joy"})
    sub.alive()
    pub.send_raw(pose_frame.encode(10.5, poses={"/vr/head/pose": (0.25, 1.5, 0.125, 0.0, 0.0, 0.0, 1.0)},
                                   joys={"/vr/left_controller/joy": ((0.5, -0.25, 1.0, 0.0), (1, 0, 0, 1))}))
    head = sub.expect("publish", topic="/vr/head/pose")["msg"]
    assert head["header"]["frame_id"] == "unity_left_handed" and head["header"]["stamp"] == {"secs": 10,
                                                                                              "nsecs": 500000000}
    assert head["pose"]["position"] == {"x": 0.25, "y": 1.5, "z": 0.125}
    joy = sub.expect("publish", topic="/vr/left_controller/joy")["msg"]
    assert joy["axes"] == [0.5, -0.25, 1.0, 0.0] and joy["buttons"] == [1, 0, 0, 1]
    pub.send_raw(b"VP\x02" + bytes(9))
    assert "pose frame version 2" in pub.expect("status", level="error")["msg"]
    pub.send({"op": "publish", "topic": "/vr/head/pose", "msg": POSE})  # still up
    assert sub.expect("publish", topic="/vr/head/pose")["msg"] == POSE


def test_service_call_with_list_and_dict_args(client_factory):
    provider, caller = client_factory(), client_factory()
    provider.send({"op": "advertise_service", "service": "/set_mode", "type": "std_srvs/SetBool"})
    provider.alive()
    for args in ([True], {"data": True}):
        caller.send({"op": "call_service", "id": "c1", "service": "/set_mode", "args": args})
        request = provider.expect("call_service", service="/set_mode")
        assert request["args"] == {"data": True} and request["id"] != "c1"
        provider.send({"op": "service_response", "id": request["id"], "service": "/set_mode",
                       "values": {"success": True, "message": "done"}, "result": True})
        assert caller.expect("service_response", id="c1") == {
            "op": "service_response", "id": "c1", "service": "/set_mode",
            "values": {"success": True, "message": "done"}, "result": True}


def test_service_errors_unknown_bad_args_timeout_failure(client_factory):
    provider, caller = client_factory(), client_factory()
    caller.send({"op": "call_service", "id": "u", "service": "/missing"})
    assert caller.expect("status", id="u", level="error")["msg"] == "call_service: service /missing does not exist"
    assert caller.expect("service_response", id="u", result=False)["values"] == "service /missing does not exist"

    provider.send({"op": "advertise_service", "service": "/slow", "type": "std_srvs/SetBool"})
    provider.alive()
    caller.send({"op": "call_service", "id": "bad", "service": "/slow", "args": {"data": "yes"}})
    assert "args.data" in caller.expect("status", id="bad")["msg"]
    caller.expect("service_response", id="bad", result=False)

    caller.send({"op": "call_service", "id": "t", "service": "/slow", "args": {"data": True}, "timeout": 0.3})
    provider.expect("call_service")  # ...and never answers
    assert caller.expect("status", id="t")["msg"] == "call_service: service /slow did not answer within 0.3 s"
    caller.expect("service_response", id="t", result=False)

    caller.send({"op": "call_service", "id": "f", "service": "/slow", "args": {"data": False}})
    request = provider.expect("call_service")
    provider.send({"op": "service_response", "id": request["id"], "service": "/slow", "values": "motors are off",
                   "result": False})
    assert "reported failure: motors are off" in caller.expect("status", id="f")["msg"]
    caller.expect("service_response", id="f", result=False)

    caller.send({"op": "call_service", "id": "w", "service": "/slow", "args": {"data": False}})
    request = provider.expect("call_service")
    provider.send({"op": "service_response", "id": request["id"], "service": "/slow",
                   "values": {"success": "yes"}, "result": True})
    assert "values.success" in provider.expect("status", id=request["id"])["msg"]
    assert "does not fit std_srvs/SetBool" in caller.expect("status", id="w")["msg"]
    caller.expect("service_response", id="w", result=False)
    caller.alive()
    provider.alive()


def test_unadvertised_and_disconnected_providers(client_factory):
    provider, caller = client_factory(), client_factory()
    provider.send({"op": "advertise_service", "service": "/gone", "type": "std_srvs/Trigger"})
    provider.alive()
    caller.send({"op": "call_service", "id": "g", "service": "/gone"})
    provider.expect("call_service")
    provider.close()
    assert "disconnected" in caller.expect("status", id="g")["msg"]
    caller.expect("service_response", id="g", result=False)
    caller.send({"op": "call_service", "id": "h", "service": "/gone"})
    assert "does not exist" in caller.expect("status", id="h")["msg"]


def test_actions_are_routed_between_clients(client_factory):
    server_side, caller = client_factory(), client_factory()
    server_side.send({"op": "advertise_action", "action": "/wave", "type": "qt_msgs/action/Gesture"})
    server_side.alive()
    caller.send({"op": "send_action_goal", "id": "goal-1", "action": "/wave", "action_type": "qt_msgs/Gesture",
                 "args": {"name": "bye"}, "feedback": True})
    goal = server_side.expect("send_action_goal", action="/wave", args={"name": "bye"})
    server_side.send({"op": "action_feedback", "id": goal["id"], "action": "/wave", "values": {"progress": 0.5}})
    assert caller.expect("action_feedback", id="goal-1")["values"] == {"progress": 0.5}
    server_side.send({"op": "action_result", "id": goal["id"], "action": "/wave", "values": {"ok": True},
                      "status": 4, "result": True})
    assert caller.expect("action_result", id="goal-1") == {
        "op": "action_result", "id": "goal-1", "action": "/wave", "values": {"ok": True}, "status": 4,
        "result": True}

    caller.send({"op": "send_action_goal", "id": "goal-2", "action": "/wave", "action_type": "qt_msgs/Gesture",
                 "args": {"name": "hi"}})
    goal = server_side.expect("send_action_goal")
    caller.send({"op": "cancel_action_goal", "id": "goal-2", "action": "/wave"})
    assert server_side.expect("cancel_action_goal")["id"] == goal["id"]
    server_side.send({"op": "action_result", "id": goal["id"], "action": "/wave", "status": 5, "result": False})
    assert caller.expect("action_result", id="goal-2")["status"] == 5

    caller.send({"op": "send_action_goal", "id": "g3", "action": "/nope", "action_type": "x/Y"})
    assert caller.expect("action_result", id="g3", result=False, status=6)["values"] == "action /nope does not exist"
    assert caller.expect("status", id="g3")["msg"] == "send_action_goal: action /nope does not exist"


def test_bad_frames_get_clear_errors_and_the_connection_goes_on(client):
    cases = [
        ("{not json", "invalid JSON: Expecting property name enclosed in double quotes at line 1 column 2"),
        ("[1, 2]", "a rosbridge message must be a JSON object with an 'op' field, not list"),
        ('{"id": "x"}', "the message has no 'op' field (a string such as \"publish\")"),
        ('{"op": 5}', "'op' must be a string, not int"),
        (b"\xff\xfe\x00garbage", "binary frame is neither JSON nor valid CBOR"),
    ]
    for frame, expected in cases:
        client.send_raw(frame)
        status = client.expect("status", level="error")
        assert status["msg"].startswith(expected), status
    client.send({"op": "frobnicate", "id": "z"})
    status = client.expect("status", id="z")
    assert status["msg"].startswith("unknown op 'frobnicate'; this server understands: action_feedback")
    client.send({"op": "subscribe", "id": "m"})
    assert client.expect("status", id="m")["msg"] == "subscribe: 'topic' is required"
    client.send({"op": "subscribe", "id": "n", "topic": "/t", "type": "std_msgs/String", "throttle_rate": "fast"})
    assert "'throttle_rate': Input should be a valid integer" in client.expect("status", id="n")["msg"]
    client.send({"op": "subscribe", "id": "o", "topic": "/t", "compression": "zip"})
    assert "'compression'" in client.expect("status", id="o")["msg"]
    client.alive()


def test_oversized_frame_gets_status_and_connection_survives(servers, connect_raw):
    srv = servers(max_message_size=4096)
    c = connect_raw(srv.url)
    c.send({"op": "publish", "topic": "/x", "msg": {"data": "z" * 5000}})
    assert "over this server's limit of 4096 bytes" in c.expect("status", level="error")["msg"]
    c.alive()
    c.send_raw("x" * 4096 * 5)  # beyond the hard limit: closed with 1009, as documented
    with pytest.raises(Exception):
        c.recv(timeout=3)
    assert c.ws.close_code == 1009


def test_set_level_filters_status_messages(client):
    client.send({"op": "unadvertise", "id": "u", "topic": "/never"})
    assert client.silent()  # a warning, below the default level (error)
    client.send({"op": "set_level", "level": "warning"})
    client.send({"op": "unadvertise", "id": "u", "topic": "/never"})
    assert client.expect("status", level="warning", id="u")["msg"] == \
        "unadvertise: topic /never is not advertised by this client"
    client.send({"op": "set_level", "level": "none"})
    client.send({"op": "frobnicate"})
    assert client.silent()


def test_slow_reader_is_bounded_and_does_not_slow_others(servers, connect_raw):
    srv = servers(queue_bound=50)
    stalled, healthy, pub = connect_raw(srv.url), connect_raw(srv.url), connect_raw(srv.url)
    for c in (stalled, healthy):
        c.send({"op": "subscribe", "topic": "/flood", "type": "std_msgs/String"})
    pub.send({"op": "advertise", "topic": "/flood", "type": "std_msgs/String"})
    stalled.alive()
    healthy.alive()
    payload = "p" * 100_000
    n = 200

    def publish() -> None:
        pace = Pace(100)
        for i in range(n):
            pub.send({"op": "publish", "topic": "/flood", "msg": {"data": f"{i}:{payload}"}})
            pace.wait()

    thread = threading.Thread(target=publish)
    thread.start()
    got = [int(healthy.expect("publish", timeout=5)["msg"]["data"].split(":")[0]) for _ in range(n)]
    thread.join()
    assert got == list(range(n))  # the healthy reader lost nothing while the other stalled
    queued = srv.call(lambda: [len(s.queue) for sess in srv.server.sessions.values()
                               for s in sess.subscriptions.values()])
    assert max(queued) <= 50
    dropped = srv.call(lambda: sum(s.counters["dropped"] for s in srv.server.sessions.values()))
    assert dropped > 0  # the stalled client lost its oldest messages rather than growing a backlog
