"""The compact pose frame (client_protocol/pose_frame.py, issue 30): its layout, its refusals by name, and the poses
channel decoding it into the same publish frames as the JSON ones, under the same checks."""

from __future__ import annotations

import asyncio
import json
import struct

import pytest

from client_protocol import interface, names, pose_frame
from client_protocol.registry import TypeRegistry
from testbed.media_client import MediaPeer, Rosbridge
from testbed.server import until
from test_datachannel import (HEAD_COMMAND, dc_server, engage_over_websocket, my_telemetry, newest,  # noqa: F401
                              head_pose, release, stream, whoami)
from test_pose_channel import HEAD, JOY, FakeSession, deliver, publish
from vr_teleop_server.media.poses import PoseChannel

LEFT = names.CONTROLLER_POSE_TOPICS["left"]
HEAD_POSE = (0.0, 1.62, 0.0, 0.0, -0.2588, 0.0, 0.9659)


def test_the_layout_is_the_documented_one() -> None:
    data = pose_frame.encode(1_700_000_000.25, {HEAD: HEAD_POSE}, {JOY: ((0.1, -0.3, 0.0, 0.85), (1, 0, 0, 1))})
    # magic, version, flags (head bit 0, right Joy bit 4, Unity bit 5), float64 stamp; 7 float32; 4 float32 + uint8
    assert data[:4] == b"VP\x01" + bytes([0b110001])
    assert struct.unpack_from("<d", data, 4)[0] == 1_700_000_000.25
    assert struct.unpack_from("<7f", data, 12) == pytest.approx(HEAD_POSE, abs=1e-6)
    assert struct.unpack_from("<4fB", data, 40)[4] == 0b1001 and len(data) == 12 + 28 + 17
    as_json = [json.dumps({"op": "publish", "topic": t, "msg": m}) for t, m in pose_frame.decode(data)]
    assert len(data) < sum(map(len, as_json)) / 5  # the point of it: a fifth of the bytes, one message


def test_decoding_gives_the_messages_the_json_frames_carry() -> None:
    data = pose_frame.encode(1_700_000_000.5, {HEAD: HEAD_POSE, LEFT: (-0.2, 1.35, 0.45, 0, 0, 0, 1)},
                             {JOY: ((0.1, -0.3, 0.0, 0.85), (1, 0, 0, 0))})
    decoded = pose_frame.decode(data)
    assert [t for t, _m in decoded] == [HEAD, LEFT, JOY]
    head = decoded[0][1]
    assert head["header"]["frame_id"] == "unity_left_handed"
    assert head["header"]["stamp"] == {"secs": 1_700_000_000, "nsecs": 500_000_000}
    assert decoded[2][1]["buttons"] == [1, 0, 0, 0]
    registry = TypeRegistry()
    types = {e.name: e.type for e in interface.ENDPOINTS}
    for topic, msg in decoded:  # valid messages of the topics' documented types
        registry.validate(types[topic], msg)
    assert pose_frame.decode(pose_frame.encode(5.0, {HEAD: HEAD_POSE}, unity=False))[0][1]["header"]["frame_id"] == ""


@pytest.mark.parametrize("data, says", [
    (b"VP\x01", "at least 12 bytes"),
    (b"XX\x01\x01" + bytes(8 + 28), "not a pose frame"),
    (b"VP\x02\x01" + bytes(8 + 28), "version 2; this server reads version 1"),
    (b"VP\x01\xc1" + bytes(8 + 28), "unknown flag bits"),
    (b"VP\x01\x01" + bytes(8 + 20), "has 40 bytes, this one 32"),
    (b"VP\x01\x01" + struct.pack("<d", float("nan")) + bytes(28), "the stamp must be"),
])
def test_bad_frames_are_refused_by_name(data: bytes, says: str) -> None:
    with pytest.raises(pose_frame.PoseFrameError, match=says):
        pose_frame.decode(data)


def test_the_channel_hands_a_binary_frames_messages_over_under_the_same_checks() -> None:
    session = FakeSession()
    channel = PoseChannel(session, lambda name: True)
    frame = pose_frame.encode(100.2, {HEAD: HEAD_POSE}, {JOY: ((0, 0, 0, 1), (0, 0, 0, 0))})
    older = pose_frame.encode(100.1, {HEAD: HEAD_POSE})
    deliver(channel, frame, older, b"nonsense, not a frame", json.dumps(publish(HEAD, 100.3)))
    assert [f["topic"] for f in session.frames] == [HEAD, JOY, HEAD]  # JSON still accepted
    assert channel.counts.stale_dropped == 1  # the older frame's head pose: newest wins, as for JSON
    assert channel.counts.refused == 1 and "not a pose frame" in channel.counts.last_refusal
    # not holding control: every message of the frame refused, as its JSON frames would be
    refused = PoseChannel(FakeSession(), lambda name: False)
    deliver(refused, frame)
    assert refused.session.frames == [] and "does not hold control" in refused.counts.last_refusal


async def test_binary_frames_from_an_aiortc_sender_move_the_robot(dc_server) -> None:  # noqa: F811
    """End to end: the tests' sender packs its pending poses into one binary frame per send; the server's channel
    decodes them into the holder's publishes, which move the head as JSON frames do."""
    ros = await Rosbridge.open(dc_server.url)
    client = MediaPeer(poses=True, audio=False, compact=True)
    watcher = await Rosbridge.open(dc_server.url)
    try:
        reply = await client.negotiate(ros)
        assert reply["values"]["success"], reply
        await client.poses.wait_open()
        name = await whoami(ros)
        commands = await watcher.subscribe(HEAD_COMMAND, "std_msgs/Float64MultiArray", queue_length=10_000)
        await engage_over_websocket(ros)
        mover = asyncio.ensure_future(stream(client, 25.0, 30.0))
        try:
            await newest(commands, lambda m: abs(m["data"][0] - 25.0) < 1.0)
            entry = await my_telemetry(ros, name, lambda e: e["dc_received"] >= 30)
            assert entry["dc_refused"] == 0, entry
        finally:
            mover.cancel()
        # one XR frame's messages, sent without yielding, leave as ONE binary frame (as the page flushes its frame)
        sender = client.poses
        assert await until(lambda: sender.channel.bufferedAmount == 0 and not sender._pending, 30)
        before = sender.sent
        sender.send(HEAD, head_pose(25.0))
        sender.send("/vr/left_controller/pose", head_pose(10.0))
        assert sender.sent == before  # not before the frame is over
        assert await until(lambda: not sender._pending, 30)
        assert sender.sent == before + 1 and sender.head_sent > 0
        await release(ros)
    finally:
        await client.close()
        await ros.close()
        await watcher.close()
