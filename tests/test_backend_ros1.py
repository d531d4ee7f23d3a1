"""The ros backend against a robot-side rosbridge with ROS 1's semantics (testbed/ros1_rosbridge.py): LuxAI's real types,
a type string required on subscribe, every service call answered from its own thread. Each of issue 26's three
defects has a test here that fails on the backend as it was (an untyped motor-state subscription, a stop sent
without waiting before every say, speech settings kept local)."""

from __future__ import annotations

import base64
import json
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
import roslibpy
from operator_voice import VoiceSender, logged, pitch, tone
from testbed.ros1_rosbridge import Ros1QTrobot
from support import RawClient, RunningServer, Watch, call, refused, wait_for, wait_subscribed

from client_protocol import names
from vr_teleop_server.robot.interface import VoiceActivity

pytestmark = pytest.mark.slow  # a ROS 1 robot-side rosbridge

SAY = names.SPEECH_SAY_SERVICE
STOP = names.SPEECH_STOP_SERVICE
WAIT = 30.0  # a failure bound on a loaded machine, never a measure


def set_level(ros: roslibpy.Ros, level: str) -> dict:
    return call(ros, names.AUTONOMY_LEVEL_SERVICE, "vr_teleop_msgs/SetAutonomy", {"level": level})


@pytest.fixture(scope="module")
def robot() -> Iterator[Ros1QTrobot]:
    fake = Ros1QTrobot()
    yield fake
    fake.stop()


@pytest.fixture(scope="module")
def server(robot: Ros1QTrobot, module_servers) -> RunningServer:
    return module_servers(backend="ros", robot_url=robot.url)


@pytest.fixture
def ros(server: RunningServer, robot: Ros1QTrobot) -> Iterator[roslibpy.Ros]:
    robot.stop_holds_for_next_call = False
    robot.seconds_per_word = 0.05
    client = roslibpy.Ros(host="127.0.0.1", port=server.port)
    client.run(timeout=10)
    yield client
    client.close()
    assert wait_for(lambda: robot.speaking is None, 30)  # the next test starts with a quiet robot


def test_the_robot_side_refuses_a_subscription_without_a_type():
    """What rosbridge 0.11 answers the subscription the backend used to make."""
    robot = Ros1QTrobot()
    raw = RawClient(robot.url)
    try:
        raw.send({"op": "subscribe", "id": "s1", "topic": names.MOTOR_STATES_TOPIC, "type": ""})
        status = raw.expect("status", level="error")
        assert status["msg"] == "subscribe:  is not a valid type string", status
    finally:
        raw.close()
        robot.stop()


def test_motor_temperatures_and_voltages_arrive(server: RunningServer, robot: Ros1QTrobot, ros: roslibpy.Ros):
    motors = Watch(ros, names.MOTORS_STATUS_TOPIC, "vr_teleop_msgs/MotorsStatus")
    try:
        def reported() -> dict[str, tuple[float, float]]:
            robot.publish(names.MOTOR_STATES_TOPIC, {"name": ["HeadYaw", "RightElbowRoll"],
                                                     "temperature": [41.5, 38.0], "voltage": [12.1, 11.9]})
            latest = motors.latest
            return dict(zip(latest.get("name", []), zip(latest.get("temperature", []), latest.get("voltage", []))))

        assert wait_for(lambda: reported().get("HeadYaw") == (41.5, pytest.approx(12.1)), 30), motors.latest
        assert reported()["RightElbowRoll"] == (38.0, pytest.approx(11.9))
        backend = {m.name: m for m in server.server.robot.motor_status()}
        assert (backend["HeadPitch"].temperature_c, backend["HeadPitch"].voltage_v) == (None, None)  # unknown, not 0
        assert not [r for r in robot.refusals if r.startswith("subscribe")], robot.refusals
    finally:
        motors.close()


def test_a_sentence_on_a_quiet_robot_is_said_whole_and_no_stop_is_sent(robot: Ros1QTrobot, ros: roslibpy.Ros):
    """A stop sent before the sentence could reach the robot after it (each call on its own thread) and cut it:
    with nothing being spoken, no stop is sent at all. The robot holds any stop until a later call has begun, so
    a stop sent ahead of this sentence would cut it every time."""
    robot.stop_holds_for_next_call = True
    before = len(robot.calls)
    reply = call(ros, SAY, "qt_robot_interface/speech_say", {"message": "Hello, I am QT"})
    assert reply["status"] is True, reply
    sent = robot.calls[before:]
    assert [name for name, _ in sent] == [SAY], sent
    said = robot.utterances[-1]
    assert said.text == "Hello, I am QT" and not said.cut


def test_a_new_sentence_waits_for_the_stop_of_the_one_being_spoken(robot: Ros1QTrobot, ros: roslibpy.Ros):
    robot.stop_holds_for_next_call = True  # the stop runs late unless nothing follows it
    robot.seconds_per_word = 2.0  # the first sentence is still being spoken when the second comes
    first = "this first sentence is long enough to be interrupted by the next one"
    answers: dict[str, dict] = {}
    speaking = threading.Thread(target=lambda: answers.setdefault(
        "first", call(ros, SAY, "qt_robot_interface/speech_say", {"message": first})), daemon=True)
    speaking.start()
    assert wait_for(lambda: robot.speaking == first, 30)
    before = len(robot.calls)
    second = call(ros, SAY, "qt_robot_interface/speech_say", {"message": "Second"})
    assert second["status"] is True, second
    speaking.join(20)
    assert answers["first"]["status"] is False, answers  # cut short, and the caller hears so
    order = [name for name, _ in robot.calls[before:]]
    assert order == [STOP, SAY], order  # the stop reached the robot (and was answered) before the sentence
    by_text = {u.text: u for u in robot.utterances}
    assert by_text[first].cut and not by_text["Second"].cut


def test_stop_talking_stops_the_robot_and_the_next_sentence_is_whole(robot: Ros1QTrobot, ros: roslibpy.Ros):
    robot.seconds_per_word = 2.0
    first = "a sentence the operator stops from the menu before it ends"
    threading.Thread(target=lambda: call(ros, SAY, "qt_robot_interface/speech_say", {"message": first}),
                     daemon=True).start()
    assert wait_for(lambda: robot.speaking == first, 30)
    stopped = call(ros, "/vr_teleop/menu/select", "vr_teleop_msgs/MenuSelect", {"id": "speech.stop", "args": ""})
    assert stopped["success"], stopped
    assert wait_for(lambda: robot.speaking is None, 30)
    assert {u.text: u for u in robot.utterances}[first].cut
    robot.stop_holds_for_next_call = True
    robot.seconds_per_word = 0.05
    assert call(ros, SAY, "qt_robot_interface/speech_say", {"message": "Still here"})["status"] is True
    assert not robot.utterances[-1].cut and robot.utterances[-1].text == "Still here"


def test_speech_speed_and_voice_reach_the_robot(robot: Ros1QTrobot, ros: roslibpy.Ros):
    for item, speed in (("speech.slower", 80), ("speech.faster", 120)):
        reply = call(ros, "/vr_teleop/menu/select", "vr_teleop_msgs/MenuSelect", {"id": item, "args": ""})
        assert reply["success"], reply
        assert robot.speech_config[-1] == {"language": "", "pitch": 0, "speed": speed}, robot.speech_config
    reply = call(ros, names.SPEECH_CONFIG_SERVICE, "qt_robot_interface/speech_config",
                 {"language": "en-GB", "pitch": 0, "speed": 100})
    assert reply["status"] is True, reply
    assert robot.speech_config[-1] == {"language": "en-GB", "pitch": 0, "speed": 100}
    assert json.dumps(robot.services_called(names.SPEECH_CONFIG_SERVICE)[-1], sort_keys=True) == \
        '{"language": "en-GB", "pitch": 0, "speed": 100}'  # exactly LuxAI's three fields on the wire


def test_the_respeakers_voice_activity_reaches_the_server_in_the_base_frame(server: RunningServer, robot: Ros1QTrobot,
                                                                         ros: roslibpy.Ros):
    """qt_respeaker_app's latched is_speaking and sound_direction become VoiceActivity (the array's angle turned
    into the base frame with the head's yaw: respeaker_to_base) and voice_activity events (the array's angle)."""
    backend = server.server.robot
    heard: list[VoiceActivity] = []
    remove = server.call(lambda: backend.on_voice_activity(heard.append))
    events = Watch(ros, names.EVENT_TOPIC, "vr_teleop_msgs/Event")
    assert wait_subscribed(server, names.EVENT_TOPIC)
    try:
        roslibpy.Topic(ros, "/qt_robot/head_position/command", "std_msgs/Float64MultiArray").publish(
            roslibpy.Message({"data": [30.0, 0.0]}))
        assert wait_for(lambda: server.call(lambda: backend.joint_state().as_dict()["HeadYaw"]) == 30.0, 30)
        robot.publish(names.RESPEAKER_DIRECTION_TOPIC, {"data": 90}, latch=True)  # to the array's right
        robot.publish(names.RESPEAKER_SPEAKING_TOPIC, {"data": True}, latch=True)
        assert wait_for(lambda: any(a.speaking for a in heard), 30), heard
        start = next(a for a in heard if a.speaking)
        assert start.direction_deg == pytest.approx(30.0 - 90.0) and start.who == ""
        robot.publish(names.RESPEAKER_DIRECTION_TOPIC, {"data": 95}, latch=True)  # wanders: no news
        robot.publish(names.RESPEAKER_DIRECTION_TOPIC, {"data": 300}, latch=True)  # to the left now
        assert wait_for(lambda: heard[-1].direction_deg == pytest.approx(30.0 + 60.0), 30), heard
        robot.publish(names.RESPEAKER_SPEAKING_TOPIC, {"data": False}, latch=True)
        assert wait_for(lambda: not heard[-1].speaking, 30), heard
        spoken = [a.direction_deg for a in heard if a.speaking]
        assert spoken == [pytest.approx(-60.0), pytest.approx(90.0)], heard
        assert all(a.stamp <= b.stamp for a, b in zip(heard, heard[1:]))
        assert wait_for(lambda: [json.loads(e["detail"]) for e in events.messages if e["kind"] == "voice_activity"
                                 and e["source"] == "backend"][-1:] == [{"activity": False, "direction_deg": 300}], 30)
    finally:
        server.call(remove)
        events.close()
        robot.publish(names.RESPEAKER_SPEAKING_TOPIC, {"data": False}, latch=True)


def test_a_robot_whose_joint_states_stop_is_lost_though_its_socket_is_up(server: RunningServer, robot: Ros1QTrobot,
                                                                       ros: roslibpy.Ros):
    """The link's one rule: the joint states are the heartbeat. A hung robot (socket up, nothing published) is
    lost: commands ignored, services refused; when they flow again it is back."""
    events = Watch(ros, names.EVENT_TOPIC, "vr_teleop_msgs/Event")
    assert wait_subscribed(server, names.EVENT_TOPIC)
    backend = server.server.robot
    try:
        robot.beating = False
        assert wait_for(lambda: events.any(lambda e: e["source"] == "backend" and e["kind"] == "disconnected"
                                           and e["level"] == "danger"), 30)
        assert not server.call(lambda: backend.connected)
        before = len(robot.published.get("/qt_robot/head_position/command", []))
        report = server.call(lambda: backend.set_joint_targets({"HeadYaw": 10.0}))
        assert report.ignored == ("HeadYaw",)
        refused(call(ros, SAY, "qt_robot_interface/speech_say", {"message": "Nobody hears this"}), "disconnected")
        robot.beating = True
        assert wait_for(lambda: events.any(lambda e: e["source"] == "backend" and e["kind"] == "reconnected"), 30)
        assert len(robot.published.get("/qt_robot/head_position/command", [])) == before  # nothing queued
        assert server.call(lambda: backend.set_joint_targets({"HeadYaw": 10.0})).ok
        assert wait_for(lambda: robot.positions["HeadYaw"] == 10.0, 30)
    finally:
        robot.beating = True
        events.close()


def test_the_operators_voice_over_rosbridge_reaches_the_speaker_topic(server: RunningServer, robot: Ros1QTrobot,
                                                                     ros: roslibpy.Ros):
    """A client's voice on /vr_teleop/audio/operator at 48 kHz stereo (its AudioInfo says so) goes out on the
    robot's speaker topic as audio_play takes it (16 kHz mono, 40 ms a message) at its pitch, and is logged."""
    before = len(robot.published.get(names.ROBOT_SPEAKER_TOPIC, []))
    pcm = tone(1.0, 48000, 2)
    sender = VoiceSender(ros, pcm, 48000, 2).start()
    assert sender.done.wait(30)

    def played() -> list[np.ndarray]:
        return [np.frombuffer(base64.b64decode(m["data"]), "<i2")
                for m in robot.published.get(names.ROBOT_SPEAKER_TOPIC, [])[before:]]

    assert wait_for(lambda: sum(c.size for c in played()) >= 0.9 * 16000, 30), sum(c.size for c in played())
    assert {c.size for c in played()} == {640}
    heard = np.concatenate(played())
    assert np.sqrt(np.mean(heard.astype(np.float32) ** 2)) > 5000
    assert abs(pitch(heard, 16000) - 440) < 10
    assert wait_for(lambda: logged(server.settings.audio_dir) == (48000, 2, pcm), 30)


def test_supervised_attention_turns_the_head_to_the_respeakers_voice_within_its_limits(server: RunningServer,
                                                                                       robot: Ros1QTrobot,
                                                                                       ros: roslibpy.Ros):
    """Issue 34 on a ROS 1 robot: a voice the ReSpeaker hears (latched is_speaking and sound_direction) is, in the
    base frame (the head's yaw less the array's angle), where supervised autonomy turns the head, through the
    robot-side head command topic and never past the head's limits; the attention target says voice."""
    head_topic = "/qt_robot/head_position/command"
    autonomy = server.server.autonomy
    attention = Watch(ros, names.AUTONOMY_ATTENTION_TOPIC, "vr_teleop_msgs/AttentionTarget")
    lower, upper = -60.0, 60.0  # qtrobot.yaml's HeadYaw
    try:
        for direction in (35.0, -100.0):  # a voice to the left, then one to the right beyond the head's reach
            # teleoperated while the voice starts: no glance moves the head between reading it and the news
            assert set_level(ros, "teleoperated")["success"]
            yaw = robot.positions["HeadYaw"]
            assert wait_for(lambda: server.call(lambda: server.server.robot.joint_state().as_dict()["HeadYaw"])
                            == yaw, WAIT)  # the server knows where the head is
            robot.publish(names.RESPEAKER_DIRECTION_TOPIC, {"data": round(yaw - direction) % 360}, latch=True)
            robot.publish(names.RESPEAKER_SPEAKING_TOPIC, {"data": True}, latch=True)
            heard = yaw - round(yaw - direction)  # the direction as the array's whole degrees give it
            assert wait_for(lambda: server.call(lambda: autonomy.voice is not None
                                                and autonomy.voice.direction is not None), WAIT)
            assert server.call(lambda: autonomy.voice.direction) == pytest.approx(heard)
            before = len(robot.published.get(head_topic, []))
            assert set_level(ros, "supervised")["success"]
            expected = min(max(heard, lower), upper)
            assert wait_for(lambda: abs(robot.positions["HeadYaw"] - expected) <= 10.0, WAIT), robot.positions
            assert wait_for(lambda: attention.any(lambda m: m["source"] == "voice"
                                                  and abs(m["yaw"] - expected) <= 10.0), WAIT), attention.latest
            sent = [m["data"][0] for m in robot.published[head_topic][before:]]
            assert sent and all(lower <= y <= upper for y in sent), sent
            robot.publish(names.RESPEAKER_SPEAKING_TOPIC, {"data": False}, latch=True)
            assert wait_for(lambda: server.call(lambda: autonomy.voice is None), WAIT)
    finally:
        robot.publish(names.RESPEAKER_SPEAKING_TOPIC, {"data": False}, latch=True)
        set_level(ros, "supervised")  # the module's level, as the server started
        attention.close()


def test_camera_frames_carry_the_head_pose_interpolated_at_their_stamp(server: RunningServer, robot: Ros1QTrobot,
                                                                      ros: roslibpy.Ros):
    """Issue 36: a frame stamped between two stamped joint states carries the head interpolated between them (the
    robot's own stamps, not arrival times), with the gap to the nearest, on /vr_teleop/camera/capture_pose beside
    the frame, under the frame's own header; a frame past the newest carries the newest."""
    import cv2

    t0 = float(int(time.time()) - 100)  # the robot's clock: any, the frames and joint states share it
    joints = sorted(robot.positions)

    def joint_state(at: float, yaw: float, pitch: float) -> dict:
        positions = {**robot.positions, "HeadYaw": yaw, "HeadPitch": pitch}
        return {"header": {"seq": 0, "stamp": {"secs": int(at), "nsecs": round(at % 1 * 1e9)}, "frame_id": ""},
                "name": joints, "position": [positions[n] for n in joints], "velocity": [0.0] * len(joints),
                "effort": [0.0] * len(joints)}

    jpeg = base64.b64encode(cv2.imencode(".jpg", np.zeros((48, 64, 3), np.uint8))[1].tobytes()).decode()

    def frame(at: float) -> dict:
        return {"header": {"seq": 7, "stamp": {"secs": int(at), "nsecs": round(at % 1 * 1e9)},
                           "frame_id": "camera_color_optical_frame"}, "format": "jpeg", "data": jpeg}

    poses = Watch(ros, names.CAPTURE_POSE_TOPIC, "vr_teleop_msgs/CapturePose")
    camera = Watch(ros, names.CAMERA_TOPIC, "sensor_msgs/CompressedImage")
    try:
        robot.publish(names.JOINT_STATE_TOPIC, joint_state(t0, 10.0, 0.0))
        robot.publish(names.JOINT_STATE_TOPIC, joint_state(t0 + 0.1, 20.0, -4.0))

        def published(at: float) -> bool:
            robot.publish(names.CAMERA_TOPIC, frame(at))  # again until the backend reads the camera
            return wait_for(lambda: poses.messages, 0.5)

        assert wait_for(lambda: published(t0 + 0.025), WAIT)
        pose = poses.messages[-1]
        assert pose["source"] == "joint_states"
        assert (pose["head_yaw"], pose["head_pitch"]) == (pytest.approx(12.5, abs=1e-3), pytest.approx(-1.0, abs=1e-3))
        assert pose["stamp_gap"] == pytest.approx(0.025, abs=1e-5)
        assert wait_for(lambda: camera.any(lambda m: m["header"]["stamp"] == pose["header"]["stamp"]), WAIT)
        seen = len(poses.messages)
        robot.publish(names.CAMERA_TOPIC, frame(t0 + 0.4))
        assert wait_for(lambda: len(poses.messages) > seen and poses.messages[-1]["stamp_gap"] > 0.29, WAIT)
        late = poses.messages[-1]
        assert (late["head_yaw"], late["head_pitch"], late["stamp_gap"]) == (20.0, -4.0, pytest.approx(0.3, abs=1e-5))
    finally:
        poses.close()
        camera.close()
