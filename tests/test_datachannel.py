"""Poses over the WebRTC data channel (issue 21), with real peers: an aiortc client opens the "poses" channel
(unordered, no retransmissions) with its media offer through /vr_teleop/media/offer, engages over its rosbridge
connection, then streams its head poses and Joy on the channel; the stand-in's head follows. Bad input on the
channel is refused, counted in the telemetry, and never reaches the robot."""

from __future__ import annotations

import asyncio
import json
import re
import time

import pytest
from aiortc import RTCPeerConnection

from testbed.media_client import MediaPeer, Rosbridge
from testbed.server import Pace, until
from support import IDENTITY, RunningServer, pose_msg, unity_yaw_pitch

pytestmark = [pytest.mark.timeout(300), pytest.mark.slow]  # WebRTC peers with the stand-in

HEAD_POSE = "/vr/head/pose"
HEAD_COMMAND = "/qt_robot/head_position/command"
ENGAGE = "/vr_teleop/control/engage"


@pytest.fixture(scope="module")
def dc_server(module_servers) -> RunningServer:
    return module_servers(backend="sim", bystander_interval=0, camera_fps=10)


def head_pose(yaw_left: float, stamp: float | None = None) -> dict:
    msg = pose_msg((0.0, 1.6, 0.0), unity_yaw_pitch(yaw_left) if yaw_left else IDENTITY)
    t = time.time() if stamp is None else stamp
    msg["header"]["stamp"] = {"secs": int(t), "nsecs": int((t % 1) * 1e9)}
    return msg


def joy(stamp: float, grip: float = 0.0) -> dict:
    return {"header": {"stamp": {"secs": int(stamp), "nsecs": int((stamp % 1) * 1e9)}, "frame_id": ""},
            "axes": [0.0, 0.0, 0.0, grip], "buttons": [0, 0, 0, 0]}


async def connect_with_poses(url: str, extra_channel: str = "", **peer: bool) -> tuple[Rosbridge, MediaPeer]:
    ros = await Rosbridge.open(url)
    client = MediaPeer(poses=True, **({"audio": False} | peer))
    if extra_channel:
        client.extra = client.pc.createDataChannel(extra_channel, ordered=False, maxRetransmits=0)
    reply = await client.negotiate(ros)
    assert reply["result"] and reply["values"]["success"], reply
    await client.poses.wait_open()
    return ros, client


async def engage_over_websocket(ros: Rosbridge) -> None:
    """Engage needs a fresh head pose from this operator: poses go over the WebSocket until it succeeds (the
    channel refuses them before)."""
    await ros.send({"op": "advertise", "topic": HEAD_POSE, "type": "geometry_msgs/PoseStamped"})
    deadline = time.monotonic() + 20
    pace = Pace(30)
    while True:
        await ros.send({"op": "publish", "topic": HEAD_POSE, "msg": head_pose(0.0)})
        await pace.tick()
        reply = await ros.call(ENGAGE, {"data": True})
        if reply.get("values", {}).get("success"):
            return
        assert time.monotonic() < deadline, reply


async def release(ros: Rosbridge) -> None:
    reply = await ros.call(ENGAGE, {"data": False})
    assert reply["values"]["success"], reply


async def stream(client: MediaPeer, yaw: float, seconds: float, rate: float = 90.0) -> None:
    end = time.monotonic() + seconds
    pace = Pace(rate)
    while time.monotonic() < end:
        client.poses.send(HEAD_POSE, head_pose(yaw))
        await pace.tick()


async def newest(queue: asyncio.Queue, predicate, timeout: float = 20.0) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        msg = await asyncio.wait_for(queue.get(), max(0.1, deadline - time.monotonic()))
        if predicate(msg):
            return msg


def drain(queue: asyncio.Queue) -> list[dict]:
    out = []
    while not queue.empty():
        out.append(queue.get_nowait())
    return out


async def my_telemetry(ros: Rosbridge, client: str, predicate, timeout: float = 20.0) -> dict:
    queue = ros.topics.get("/vr_teleop/telemetry") or await ros.subscribe("/vr_teleop/telemetry",
                                                                           "vr_teleop_msgs/Telemetry")
    last = None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        msg = await asyncio.wait_for(queue.get(), timeout)
        for entry in msg["clients"]:
            if entry["client"] == client:
                last = entry
                if predicate(entry):
                    return entry
    raise AssertionError(f"no telemetry entry of {client} matched; last: {last}")


async def whoami(ros: Rosbridge) -> str:
    reply = await ros.call("/vr_teleop/whoami", {})
    return reply["values"]["connection"]


async def test_head_poses_over_the_channel_move_the_robot_and_stale_ones_are_dropped(dc_server) -> None:
    ros, client = await connect_with_poses(dc_server.url)
    watcher = await Rosbridge.open(dc_server.url)
    try:
        name = await whoami(ros)
        commands = await watcher.subscribe(HEAD_COMMAND, "std_msgs/Float64MultiArray", queue_length=10_000)
        on_bus = await watcher.subscribe(HEAD_POSE, "geometry_msgs/PoseStamped", queue_length=10_000)
        await engage_over_websocket(ros)
        await stream(client, 30.0, 0.2)
        # The head follows poses that come over the channel only.
        mover = asyncio.ensure_future(stream(client, 30.0, 30.0))
        try:
            await newest(commands, lambda m: abs(m["data"][0] - 30.0) < 1.0)
            entry = await my_telemetry(ros, name, lambda e: e["dc_received"] >= 50)
            assert entry["dc_refused"] == 0, entry
            assert entry["pose_rate"] > 10, entry  # the channel's poses are this client's poses
        finally:
            mover.cancel()
        # An older pose after newer ones (unordered delivery): dropped, never on the bus, the robot stays. Its stamp
        # is older than every pose sent from here on, and it goes after some of them (stamped 0.5 s before its own
        # send, it was newer than the mover's last pose when the telemetry wait above took longer than that).
        old = time.time() - 0.5
        drain(on_bus)
        await stream(client, 30.0, 0.3)
        client.poses.send(HEAD_POSE, head_pose(-30.0, old))
        await stream(client, 30.0, 0.5)
        entry = await my_telemetry(ros, name, lambda e: e["dc_stale_dropped"] >= 1)
        assert entry["dc_refused"] == 0, entry
        await stream(client, 30.0, 0.3)
        stale = head_pose(-30.0, old)["header"]["stamp"]
        stamps = [m["header"]["stamp"] for m in drain(on_bus)]
        assert len(stamps) > 20 and stale not in stamps
        assert all(m["data"][0] > 25.0 for m in drain(commands)), "the head moved back towards a stale pose"
        # Joy: the same rule, per topic.
        t = time.time()
        client.poses.send("/vr/left_controller/joy", joy(t))
        assert await until(lambda: not client.poses._pending, 30)  # out, in a frame of its own
        client.poses.send("/vr/left_controller/joy", joy(t - 0.3, grip=1.0))
        entry = await my_telemetry(ros, name, lambda e: e["dc_stale_dropped"] >= 2)
        assert entry["dc_refused"] == 0, entry
        await release(ros)
    finally:
        await client.close()
        await ros.close()
        await watcher.close()


async def test_a_data_channel_only_offer_is_answered(dc_server) -> None:
    ros, client = await connect_with_poses(dc_server.url, video=False)
    try:
        assert not any(t.kind in ("audio", "video") for t in client.pc.getTransceivers())
        assert client.pc.sctp is not None and client.poses.open
    finally:
        await client.close()
        await ros.close()


async def test_a_video_section_without_a_common_codec_is_rejected_and_the_channel_kept(dc_server) -> None:
    pc = RTCPeerConnection()
    pc.addTransceiver("video", direction="recvonly")
    pc.createDataChannel("poses", ordered=False, maxRetransmits=0)
    await pc.setLocalDescription(await pc.createOffer())
    sdp = re.sub(r"VP8/90000", "VP9/90000", pc.localDescription.sdp)
    sdp = re.sub(r"H264/90000", "AV1/90000", sdp)
    await pc.close()
    ros = await Rosbridge.open(dc_server.url)
    try:
        reply = await ros.call("/vr_teleop/media/offer", {"sdp": sdp, "type": "offer"})
        values = reply["values"]
        assert values["success"], values
        assert "no common codec" in values["message"] and "VP9" in values["message"], values["message"]
        assert "JPEG" in values["message"] and "poses" in values["message"], values["message"]
        media = [line for line in values["sdp"].splitlines() if line.startswith("m=")]
        assert [m.split()[:2] for m in media] == [["m=video", "0"], ["m=application", media[1].split()[1]]], media
        assert media[1].split()[1] != "0"
        peer = dc_server.call(lambda: next(iter(dc_server.server.media.peers.values()), None))
        assert peer is not None and peer.video is None
    finally:
        await ros.close()


async def test_bad_input_on_the_channel_is_refused_counted_and_never_reaches_the_robot(dc_server) -> None:
    ros, client = await connect_with_poses(dc_server.url, extra_channel="chat")
    other_ros, other = await connect_with_poses(dc_server.url)
    watcher = await Rosbridge.open(dc_server.url)
    try:
        name, other_name = await whoami(ros), await whoami(other_ros)
        commands = await watcher.subscribe(HEAD_COMMAND, "std_msgs/Float64MultiArray", queue_length=10_000)
        joints = await watcher.subscribe("/qt_robot/joints/state", "sensor_msgs/JointState", queue_length=10_000)
        # Nobody holds control yet: the channel takes no poses, not even for engaging.
        client.poses.send(HEAD_POSE, head_pose(40.0))
        entry = await my_telemetry(ros, name, lambda e: e["dc_refused"] >= 1)
        assert "does not hold control" in entry["dc_last_refusal"] and entry["dc_received"] == 1, entry
        await engage_over_websocket(ros)
        mover = asyncio.ensure_future(stream(client, 0.0, 60.0))  # the holder's own poses keep the robot active
        try:
            await newest(commands, lambda m: abs(m["data"][0]) < 1.0)
            await newest(joints, lambda m: abs(dict(zip(m["name"], m["position"]))["HeadYaw"]) < 1.0)
            drain(commands), drain(joints)  # from here on, the robot is where the holder's poses put it
            bad = [
                ("this is not JSON", "not JSON"),
                (b"\x00\x01binary", "binary"),
                (json.dumps(["publish", HEAD_POSE]), "is not 'publish'"),
                (json.dumps({"op": "subscribe", "topic": HEAD_COMMAND}), "is not 'publish'"),
                (json.dumps({"op": "call_service", "service": ENGAGE, "args": {"data": False}}), "is not 'publish'"),
                # straight to the robot's command topic: not an operator stream
                (json.dumps({"op": "publish", "topic": HEAD_COMMAND, "msg": {"data": [60.0, 0.0]}}),
                 "not one of the operator's streams"),
                (json.dumps({"op": "publish", "topic": "/vr_teleop/control/estop", "msg": {}}),
                 "not one of the operator's streams"),
                # an operator stream the session's own checks refuse: a zero quaternion, a mistyped message
                (json.dumps({"op": "publish", "topic": HEAD_POSE, "msg": head_pose(0.0) | {"pose": {
                    "position": {"x": 0, "y": 1.6, "z": 0}, "orientation": {"x": 0, "y": 0, "z": 0, "w": 0}}}}),
                 HEAD_POSE),
                (json.dumps({"op": "publish", "topic": HEAD_POSE, "msg": {"pose": "far left"}}), HEAD_POSE),
            ]
            before = await my_telemetry(ros, name, lambda e: True)
            pose = json.dumps({"op": "publish", "topic": HEAD_POSE, "msg": head_pose(0.0)})
            for data, reason in [(None, "'chat' is not one this server reads"), *bad]:
                if data is None:  # a channel of another label: refused however good its message
                    client.extra.send(pose)
                else:
                    client.poses.send_raw(data)
                entry = await my_telemetry(ros, name, lambda e, n=before["dc_refused"]: e["dc_refused"] > n)
                assert entry["dc_refused"] == before["dc_refused"] + 1, (data, entry)
                assert reason in entry["dc_last_refusal"], (data, entry["dc_last_refusal"])
                before = entry
            # Another client's channel while this one holds control: refused, counted for it.
            pace = Pace(100)
            for _ in range(20):
                other.poses.send(HEAD_POSE, head_pose(-40.0))
                await pace.tick()
            entry = await my_telemetry(other_ros, other_name, lambda e: e["dc_refused"] >= 20)
            assert entry["dc_received"] == entry["dc_refused"], entry
            assert "does not hold control" in entry["dc_last_refusal"], entry
            # Every refused pose is counted: half a second more of the robot's joint states (its steady 30 Hz)
            # shows whether any of them moved it.
            seen = joints.qsize()
            assert await until(lambda: joints.qsize() >= seen + 15, 30)
        finally:
            mover.cancel()
        # The robot did none of it: every command and measured yaw stayed at the holder's 0.
        seen = drain(commands)
        assert seen and all(abs(m["data"][0]) < 1.0 for m in seen), [m["data"] for m in seen if abs(m["data"][0]) >= 1]
        yaws = [dict(zip(m["name"], m["position"]))["HeadYaw"] for m in drain(joints)]
        assert yaws and max(abs(y) for y in yaws) < 2.0, max(yaws, key=abs)
        # The clients heard why over their WebSocket, and only now and then, not once per message.
        mine = [s["msg"] for s in ros.statuses if "poses data channel: refused" in s["msg"]]
        theirs = [s["msg"] for s in other_ros.statuses if "poses data channel: refused" in s["msg"]]
        assert mine and theirs and len(theirs) < 20, theirs
        assert any("zero" in s["msg"] or "quaternion" in s["msg"] for s in ros.statuses), ros.statuses
        # Both connections and both channels still work.
        assert client.poses.open and other.poses.open
        assert (await ros.call("/vr_teleop/clock", {"client_send": 1.0}))["result"]
        await release(ros)
    finally:
        for c in (client, other):
            await c.close()
        for r in (ros, other_ros, watcher):
            await r.close()
