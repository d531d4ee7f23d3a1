"""Issue 36: every camera frame carries the robot's head pose at the moment it was taken, and the operator page
hangs its camera panel by it. The interpolation helper on its own (robot/head_history.py, no I/O); the stand-in's
frames on both roads, the JPEG topic's companion /vr_teleop/camera/capture_pose to roslibpy and the capture_poses
data channel to an aiortc peer; the page in Chromium with IWER. The real backends' poses are tested against their
fakes in test_backend_ros1.py and test_backend_luxai.py."""

from __future__ import annotations

import asyncio
import json
import math
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
import roslibpy
from testbed.media_client import MediaPeer, Rosbridge
from testbed.server import until
from support import RunningServer, Watch, wait_for, wait_subscribed

from client_protocol import names
from vr_teleop_server.robot.head_history import HeadHistory

CAMERA_JS = Path(__file__).resolve().parent.parent / "vr_teleop_server" / "web" / "operator" / "camera.js"

WAIT = 30.0  # a failure bound on a loaded machine, never a measure
HEAD = names.HEAD_COMMAND_TOPIC


# ---- the interpolation helper ------------------------------------------------------------------------------------
def test_the_history_interpolates_between_the_joint_states_around_a_stamp():
    history = HeadHistory()
    assert history.at(10.0) is None  # nothing heard yet
    history.add(10.0, 0.0, 0.0)
    history.add(10.1, 10.0, -4.0)
    history.add(10.2, 10.0, -4.0)
    pose = history.at(10.025)
    assert (pose.yaw, pose.pitch) == (pytest.approx(2.5), pytest.approx(-1.0))
    assert pose.gap_s == pytest.approx(0.025) and pose.source == "joint_states"
    assert history.at(10.1).yaw == pytest.approx(10.0) and history.at(10.1).gap_s == pytest.approx(0.0)
    late = history.at(10.5)  # past the newest: the newest, never extrapolated, and how far it is
    assert (late.yaw, late.gap_s) == (10.0, pytest.approx(0.3))
    early = history.at(9.0)  # before the oldest kept: the oldest
    assert (early.yaw, early.gap_s) == (0.0, pytest.approx(1.0))


def test_the_history_ignores_what_is_out_of_order_or_not_finite_and_keeps_the_newest():
    history = HeadHistory(keep=4)
    history.add(1.0, 1.0, 0.0)
    history.add(0.5, 50.0, 0.0)  # older than the newest: a late message, ignored
    history.add(1.0, 60.0, 0.0)  # a repeat of a stamp
    history.add(2.0, math.nan, 0.0)
    history.add(math.inf, 3.0, 0.0)
    assert len(history) == 1 and history.at(1.0).yaw == 1.0
    for i in range(2, 8):
        history.add(float(i), float(i), 0.0)
    assert len(history) == 4  # the newest `keep`
    assert history.at(0.0).yaw == 4.0 and history.at(5.5).yaw == pytest.approx(5.5)
    assert history.at(math.nan) is None


def test_the_pages_pose_lookup_under_node(tmp_path):
    """camera.js's CapturePoses, run by Node: a frame's own pose, else the nearest frame's taken within 0.2 s (RTP
    timestamps across a wrap), else none; and the URL's placement option."""
    script = tmp_path / "check.mjs"
    script.write_text(f"""
import {{CapturePoses, placementMode}} from {json.dumps(str(CAMERA_JS))};
import {{rtpDelta}} from {json.dumps(str(CAMERA_JS.parent.parent / "webrtc.js"))};
const poses = new CapturePoses((a, b) => Math.abs(rtpDelta(a, b)) / 90000, 3);
poses.add(4294967000, {{head_yaw: 1, head_pitch: 0, stamp_gap: 0, source: "render"}});
poses.add(2704, {{head_yaw: 3, head_pitch: -1, stamp_gap: 0, source: "render"}});  // 3000 ticks later, wrapped
poses.add(null, {{head_yaw: 9, head_pitch: 0}});
poses.add(9000, {{head_yaw: NaN, head_pitch: 0}});
const out = {{
  own: poses.get(2704), near: poses.nearest(4294967100), far: poses.nearest(2704 + 90000) ?? null,
  none: poses.nearest(null) ?? null, received: poses.received,
  modes: [placementMode("#token=x&placement=newest"), placementMode("#camera=jpeg"), placementMode("")],
}};
for (let i = 0; i < 5; i++) poses.add(100000 + i, {{head_yaw: i, head_pitch: 0}});
out.kept = poses.poses.size;
console.log(JSON.stringify(out));
""")
    result = subprocess.run(["node", str(script)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout.splitlines()[-1])
    assert out["own"] == {"yaw": 3, "pitch": -1, "gap": 0, "source": "render"}
    assert out["near"]["yaw"] == 1  # 100 ticks from the first, 3000 from the second (across the wrap)
    assert out["far"] is None and out["none"] is None  # a second away: no neighbour's pose stands in
    assert out["received"] == 2 and out["kept"] == 3
    assert out["modes"] == ["newest", "capture", "capture"]


# ---- the stand-in ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def standin(module_servers) -> RunningServer:
    # the tests put the head and expect it to stay while they watch frames: a client that wants that asks for it by
    # name (at the default level, attention takes the head back once a client's grace has passed)
    return module_servers(backend="sim", bystander_interval=0, autonomy="teleoperated")


@pytest.fixture
def ros(standin: RunningServer) -> Iterator[roslibpy.Ros]:
    client = roslibpy.Ros(host="127.0.0.1", port=standin.port)
    client.run(timeout=10)
    yield client
    # the head back home, and there before the next test's client commands it: a command still on its way on this
    # connection would otherwise undo the next test's
    roslibpy.Topic(client, HEAD, "std_msgs/Float64MultiArray").publish(roslibpy.Message({"data": [0.0, 0.0]}))
    assert wait_for(lambda: all(abs(head(client)[j]) < 0.2 for j in ("HeadYaw", "HeadPitch")), WAIT)
    client.close()


def stamp(header: dict) -> tuple[int, int]:
    return header["stamp"]["secs"], header["stamp"]["nsecs"]


def head(ros: roslibpy.Ros) -> dict[str, float]:
    watch = Watch(ros, names.JOINT_STATE_TOPIC, "sensor_msgs/JointState")
    try:
        assert wait_for(lambda: watch.latest, 30)
        return dict(zip(watch.latest["name"], watch.latest["position"]))
    finally:
        watch.close()


@pytest.mark.slow
def test_the_standins_frames_carry_the_pose_they_were_drawn_at(standin: RunningServer, ros: roslibpy.Ros):
    """A held head's frames carry its pose; during a turn the frames' poses lie between its start and its end, in
    order, as the head passes; each pose comes before its frame, with the frame's own header, for a client that
    matches them (roslibpy here, the JPEG road); and a client of the camera topic alone sees the frames as
    before."""
    command = roslibpy.Topic(ros, HEAD, "std_msgs/Float64MultiArray")
    command.publish(roslibpy.Message({"data": [-20.0, 5.0]}))
    assert wait_for(lambda: abs(head(ros)["HeadYaw"] + 20.0) < 0.2 and abs(head(ros)["HeadPitch"] - 5.0) < 0.2,
                    WAIT)
    order: list[tuple[str, dict]] = []  # both topics in arrival order, on one connection
    poses = roslibpy.Topic(ros, names.CAPTURE_POSE_TOPIC, "vr_teleop_msgs/CapturePose", queue_length=100)
    camera = roslibpy.Topic(ros, names.CAMERA_TOPIC, "sensor_msgs/CompressedImage", queue_length=100)
    poses.subscribe(lambda m: order.append(("pose", m)))
    camera.subscribe(lambda m: order.append(("frame", m)))
    try:
        assert wait_subscribed(standin, names.CAMERA_TOPIC) and wait_subscribed(standin, names.CAPTURE_POSE_TOPIC)
        assert wait_for(lambda: sum(kind == "frame" for kind, _ in order) >= 5, WAIT)
        held = [m for kind, m in list(order) if kind == "pose"]
        assert held and all(m["source"] == "render" and m["stamp_gap"] == 0.0 for m in held)
        assert all(abs(m["head_yaw"] + 20.0) < 0.3 and abs(m["head_pitch"] - 5.0) < 0.3 for m in held), held
        start = len(order)
        command.publish(roslibpy.Message({"data": [25.0, 5.0]}))  # 45 degrees at the head's velocity cap
        assert wait_for(lambda: any(kind == "pose" and abs(m["head_yaw"] - 25.0) < 0.2 for kind, m in order[start:]),
                        WAIT)
        seen = list(order)
    finally:
        poses.unsubscribe()
        camera.unsubscribe()
    turn = [m["head_yaw"] for kind, m in seen[start:] if kind == "pose"]
    assert all(-20.3 <= y <= 25.3 for y in turn), turn
    assert all(b >= a - 0.05 for a, b in zip(turn, turn[1:])), f"poses out of order during the turn: {turn}"
    assert sum(-19.0 < y < 24.0 for y in turn) >= 2, f"no frame drawn during the turn: {turn}"
    # each frame has its pose just before it, with the same header
    frames = [(i, m) for i, (kind, m) in enumerate(seen) if kind == "frame"]
    matched = 0
    for i, frame in frames:
        before = [m for kind, m in seen[:i] if kind == "pose" and stamp(m["header"]) == stamp(frame["header"])]
        assert before, f"frame {frame['header']} came without its pose before it"
        assert before[-1]["header"]["seq"] == frame["header"]["seq"]
        assert before[-1]["header"]["frame_id"] == frame["header"]["frame_id"] == names.CAMERA_FRAME_ID
        assert frame["format"] == "jpeg" and frame["data"]
        matched += 1
    assert matched >= 5


async def _webrtc_poses(url: str) -> tuple[list[int], dict[int, dict], float]:
    """An aiortc peer with the capture_poses channel: the RTP timestamps of the frames it decoded, the poses by
    RTP timestamp, and the head's yaw."""
    ros = await Rosbridge.open(url)
    peer = MediaPeer(audio=False)
    peer.keep_frames = 200
    poses: dict[int, dict] = {}
    channel = peer.pc.createDataChannel(names.CAPTURE_POSES_CHANNEL, ordered=False, maxRetransmits=0)
    channel.on("message", lambda text: poses.__setitem__(json.loads(text)["rtp_timestamp"], json.loads(text)))
    try:
        reply = await peer.negotiate(ros)
        assert reply["values"]["success"], reply
        await peer.wait_video(15, WAIT)
        assert await until(lambda: poses, WAIT)  # the channel is open and carrying poses
        await peer.wait_video(12, WAIT)  # and frames after that
        rtps = [peer.rtp_timestamp(frame) for _, frame in peer.frames]
        await until(lambda: all(r in poses for r in rtps[2:]), WAIT)  # the frames' poses went first: those on
        # the way arrive (what is missing after that is judged below)
        joints = await ros.subscribe(names.JOINT_STATE_TOPIC, "sensor_msgs/JointState")
        state = await asyncio.wait_for(joints.get(), WAIT)
        return rtps, poses, dict(zip(state["name"], state["position"]))["HeadYaw"]
    finally:
        await peer.close()
        await ros.close()


@pytest.mark.slow
def test_webrtc_frames_get_their_pose_on_the_data_channel_by_rtp_timestamp(standin: RunningServer,
                                                                           ros: roslibpy.Ros):
    """Every frame after the first (whose RTP origin the server learns from it) has its pose on the capture_poses
    channel, keyed by the RTP timestamp the peer decodes it with."""
    roslibpy.Topic(ros, HEAD, "std_msgs/Float64MultiArray").publish(roslibpy.Message({"data": [15.0, 0.0]}))
    yaws: list[float] = []
    assert wait_for(lambda: abs((yaws.append(head(ros)["HeadYaw"]) or yaws[-1]) - 15.0) < 0.2, WAIT), \
        (yaws[:5], yaws[-5:], standin.call(lambda: standin.server.owners.owners()))
    rtps, poses, yaw = asyncio.run(_webrtc_poses(standin.url))
    assert len(rtps) >= 15
    # From the first pose on (the channel may open a few frames after the video starts on a busy machine), the
    # frames have theirs; the channel is unordered without retransmits and skips a pose while it is backed up,
    # so a rare one may be missing, never a wrong one.
    shown = [r for r in rtps if r in poses]
    assert shown, f"none of {len(rtps)} frames came with its pose"
    after = rtps[rtps.index(shown[0]):]
    missing = [r for r in after if r not in poses]
    assert len(after) >= 10 and len(missing) <= len(after) // 10, \
        f"{len(missing)} of {len(after)} frames after the first pose came without theirs"
    for r in shown:
        assert abs(poses[r]["head_yaw"] - yaw) < 0.3 and poses[r]["source"] == "render", poses[r]


# ---- the page ----------------------------------------------------------------------------------------------------
PLACED = """() => { const o = window.operator, p = o.camera.placed;
  return p && {key: p.key, by: p.by, yaw: p.yaw, pitch: p.pitch, rotY: o.panel.rotation.y, rotX: o.panel.rotation.x,
               zeroYaw: o.state.zero.yaw, zeroPitch: o.state.zero.pitch, robotYaw: o.state.robotHead.yaw,
               path: o.camera.path}; }"""


CAMERA_STATE = """() => { const c = window.operator.camera, v = c.video;
  return {path: c.path, placed: c.placed, placement: c.placement, posesReceived: c.rtpPoses.received,
          poseKeys: [...c.rtpPoses.poses.keys()].slice(-5), latestRtp: v?.latestRtp ?? null,
          shownRtp: v?.shownRtp ?? null, framesReceived: v?.received ?? null}; }"""


def _placed_by(page, by: str) -> dict:
    from playwright.sync_api import TimeoutError as PlaywrightTimeout

    try:
        page.wait_for_function(f"() => window.operator.camera.placed?.by === {by!r} "
                               "&& window.operator.camera.placed.key !== null", timeout=int(WAIT * 1000))
    except PlaywrightTimeout:  # what the page held instead: which of the frames, the poses or the match was missing
        raise AssertionError(f"the panel was never placed by {by!r}: {page.evaluate(CAMERA_STATE)}") from None
    return page.evaluate(PLACED)


@pytest.mark.browser
def test_the_page_hangs_the_panel_by_the_shown_frames_capture_pose(browser, standin: RunningServer,
                                                                   ros: roslibpy.Ros):
    """JPEG road: the panel's rotation is the capture pose the server published for the frame the page shows (read
    here from the topic, by the frame's stamp), while the robot's head is away from where the frame was taken;
    #placement=newest hangs it by the newest joint state instead."""
    from test_operator_page import IWER, close_page, enter_vr, open_page

    truth: dict[float, tuple[float, float]] = {}
    poses = Watch(ros, names.CAPTURE_POSE_TOPIC, "vr_teleop_msgs/CapturePose")
    command = roslibpy.Topic(ros, HEAD, "std_msgs/Float64MultiArray")
    command.publish(roslibpy.Message({"data": [30.0, -8.0]}))
    page = open_page(browser, standin, headset=IWER, camera="jpeg")
    try:
        enter_vr(page)
        placed = _placed_by(page, "capture")
        assert placed["path"] == "JPEG"
        for m in list(poses.messages):
            truth[m["header"]["stamp"]["secs"] + m["header"]["stamp"]["nsecs"] / 1e9] = (m["head_yaw"],
                                                                                         m["head_pitch"])
        key = min(truth, key=lambda s: abs(s - placed["key"]))
        assert abs(key - placed["key"]) < 1e-6, "the shown frame's pose is not among the server's"
        yaw, pitch = truth[key]
        assert placed["rotY"] == pytest.approx(placed["zeroYaw"] + math.radians(yaw), abs=1e-6)
        assert placed["rotX"] == pytest.approx(placed["zeroPitch"] - math.radians(pitch), abs=1e-6)
        # held at 30/-8: once there, the shown frames were taken there
        assert wait_for(lambda: abs(page.evaluate(PLACED)["yaw"] - 30.0) < 0.3, WAIT)
        assert abs(page.evaluate(PLACED)["pitch"] + 8.0) < 0.3
    finally:
        close_page(page)
        poses.close()
    page = open_page(browser, standin, headset=IWER, camera="jpeg")
    try:
        page.evaluate("window.operator.camera.placement = 'newest'")
        enter_vr(page)
        placed = _placed_by(page, "newest")
        assert placed["rotY"] == pytest.approx(placed["zeroYaw"] + math.radians(placed["robotYaw"]), abs=1e-6)
    finally:
        close_page(page)


@pytest.mark.browser
def test_the_page_takes_webrtc_frames_poses_from_the_data_channel(browser, standin: RunningServer):
    """WebRTC road: the page opens the capture_poses channel, and the panel hangs by the pose of the frame the video
    presents (its RTP timestamp)."""
    from test_operator_page import IWER, close_page, enter_vr, open_page

    page = open_page(browser, standin, headset=IWER, camera="webrtc")
    try:
        enter_vr(page)
        placed = _placed_by(page, "capture")
        assert placed["path"] == "WebRTC" and isinstance(placed["key"], int)
        pose = page.evaluate(f"window.operator.camera.rtpPoses.get({placed['key']})")
        assert pose and pose["source"] == "render"
        assert placed["rotY"] == pytest.approx(placed["zeroYaw"] + math.radians(placed["yaw"]), abs=1e-6)
        assert placed["yaw"] == pytest.approx(pose["yaw"]) and placed["pitch"] == pytest.approx(pose["pitch"])
    finally:
        close_page(page)
