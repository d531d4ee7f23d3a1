"""The QTrobot v3 backend (`--backend luxai`) for real: LuxAI's SDK in the server under test talks to a fake v3
service hub built from luxai-magpie's own server classes and the SDK's interface definition (testbed/luxai_hub.py),
over ZeroMQ, and through a real mosquitto broker. The hub's limits are narrower than the URDF's on HeadYaw."""

from __future__ import annotations

import getpass
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import roslibpy
from testbed.luxai_hub import NARROW, FakeQtrobotV3
from testbed.processes import free_port
from testbed.server import until
from testbed.media_client import MediaPeer, Rosbridge, Tone
from operator_voice import VoiceSender, logged, pitch, tone
from support import (
    Headset,
    RunningServer,
    ServerFactory,
    Watch,
    call,
    engage,
    joints,
    refused,
    still,
    unity_yaw_pitch,
    wait_for,
    wait_subscribed,
)

from client_protocol import names
from vr_teleop_server.robot.interface import VoiceActivity

WAIT = 30.0  # a failure bound on a loaded machine, never a measure
pytestmark = pytest.mark.slow  # a fake QTrobot v3 hub, over ZeroMQ and MQTT

ROOT = Path(__file__).resolve().parent.parent


def luxai_server(servers: ServerFactory, **settings) -> RunningServer:
    return servers(backend="luxai", bystander_interval=0, **settings)


@pytest.fixture(scope="module")
def zmq_robot(module_servers):
    """One fake hub (with its camera plugin) and one server on it, over ZeroMQ, for the module."""
    hub = FakeQtrobotV3().start()
    server = luxai_server(module_servers, robot_url=f"tcp://127.0.0.1:{hub.hub_port}",
                          camera_url=f"tcp://127.0.0.1:{hub.camera_port}")
    ros = roslibpy.Ros(host="127.0.0.1", port=server.port)
    ros.run(timeout=10)
    yield hub, server, ros
    ros.close()
    server.stop()
    hub.stop()


def description(ros: roslibpy.Ros) -> dict:
    watch = Watch(ros, names.DESCRIPTION_TOPIC, "std_msgs/String")
    assert wait_for(lambda: watch.latest.get("data"), 30)
    watch.close()
    return json.loads(watch.latest["data"])


def test_head_and_arms_reach_their_targets_within_the_robots_own_limits(zmq_robot):
    hub, server, ros = zmq_robot
    js = Watch(ros, names.JOINT_STATE_TOPIC, "sensor_msgs/JointState")
    clamps = Watch(ros, names.CLAMP_TOPIC, "vr_teleop_msgs/Clamp")
    try:
        assert wait_for(lambda: "HeadYaw" in joints(js), 30)
        # HeadYaw: the URDF allows 60, the robot 45: the robot's limit wins, and the clamp is reported
        roslibpy.Topic(ros, "/qt_robot/head_position/command", "std_msgs/Float64MultiArray").publish(
            roslibpy.Message({"data": [55.0, 10.0]}))
        roslibpy.Topic(ros, "/qt_robot/right_arm_position/command", "std_msgs/Float64MultiArray").publish(
            roslibpy.Message({"data": [-60.0, -30.0, -50.0]}))
        assert wait_for(lambda: abs(hub.positions["HeadYaw"] - 45.0) < 0.5 and abs(hub.positions["HeadPitch"] - 10)
                        < 0.5, 30), hub.positions
        assert wait_for(lambda: abs(hub.positions["RightShoulderPitch"] + 60) < 0.5
                        and abs(hub.positions["RightElbowRoll"] + 50) < 0.5, 30), hub.positions
        assert wait_for(lambda: abs(joints(js)["HeadYaw"] - 45.0) < 0.5, WAIT)  # the robot's state, relayed
        assert wait_for(lambda: clamps.any(lambda m: "HeadYaw" in m["joints"] and m["applied"][0] == 45.0), WAIT)
        assert max(c["HeadYaw"]["position"] for c in hub.commands if "HeadYaw" in c) == 45.0  # never sent beyond
        # each joint moves at its velocity cap, the smaller of the model's and the robot's
        elbow = [c["RightElbowRoll"]["velocity"] for c in hub.commands if "RightElbowRoll" in c]
        assert elbow and set(elbow) == {NARROW["RightElbowRoll"]["velocity_max"]}
        # the limits in force are reported: the robot description (with what the backend knows of the robot)
        info = description(ros)
        yaw = next(j for j in info["joints"] if j["name"] == "HeadYaw")
        assert (yaw["lower"], yaw["upper"]) == (-40.0, 45.0)
        assert info["backend"]["robot_type"] == "qtrobot-v3" and info["backend"]["robot_id"] == hub.robot_id
        assert info["backend"]["camera"]["available"]
    finally:
        js.close()
        clamps.close()


def test_emotions_speech_with_stop_and_voice_config(zmq_robot):
    hub, server, ros = zmq_robot
    assert call(ros, names.EMOTION_SHOW_SERVICE, "qt_robot_interface/emotion_show", {"name": "QT/happy"})["status"]
    assert wait_for(lambda: "QT/happy" in hub.emotions, WAIT)
    refused(call(ros, names.EMOTION_SHOW_SERVICE, "qt_robot_interface/emotion_show", {"name": "QT/nope"}))
    assert "QT/nope" not in hub.emotions

    assert call(ros, names.SPEECH_CONFIG_SERVICE, "qt_robot_interface/speech_config",
                {"language": "", "pitch": 0, "speed": 150})["status"]
    assert hub.tts_config == {"rate": 1.5}  # the engine's config, as a rate multiplier
    assert call(ros, names.SPEECH_SAY_SERVICE, "qt_robot_interface/speech_say", {"message": "hello there"})["status"]
    assert hub.spoken[-1] == "hello there" and hub.said[-1]["rate"] == 1.5

    long = "this sentence is long enough to be stopped before the robot has said all of it"
    say = roslibpy.Service(ros, names.SPEECH_SAY_SERVICE, "qt_robot_interface/speech_say")
    answers: list = []
    say.call(roslibpy.ServiceRequest({"message": long}), answers.append)
    assert wait_for(lambda: hub.said and hub.said[-1]["text"] == long, 30)
    assert call(ros, names.SPEECH_STOP_SERVICE, "qt_robot_interface/speech_stop")["status"]
    assert wait_for(lambda: answers, 30)
    assert answers[0]["status"] is False  # not completed
    assert hub.cancelled == [long] and long not in hub.spoken


def test_the_robots_own_gestures_play_there_the_servers_stream(zmq_robot):
    hub, server, ros = zmq_robot
    listed = call(ros, names.GESTURE_LIST_SERVICE, "qt_gesture_controller/gesture_list")["gestures"]
    assert {"nod", "wave", "QT/bye"} <= set(listed)  # the server's files, then the robot's own
    assert "QT/nod" not in listed  # the library's "nod" is also "QT/nod": the robot's is shadowed
    assert call(ros, names.GESTURE_PLAY_SERVICE, "qt_gesture_controller/gesture_play",
                {"name": "QT/bye", "speed": 2.0})["status"]
    assert hub.gestures[-1] == ("QT/bye", 2.0)  # the robot's own gesture file, at the speed asked
    # the server's gesture is streamed as joint commands, even where the robot holds one of that name
    before, played = len(hub.commands), len(hub.gestures)
    assert call(ros, names.GESTURE_PLAY_SERVICE, "qt_gesture_controller/gesture_play",
                {"name": "QT/nod", "speed": 4.0})["status"]
    assert len(hub.commands) > before + 3 and len(hub.gestures) == played
    # stopped: the robot's cancel call, and the play answers not completed
    play = roslibpy.Service(ros, names.GESTURE_PLAY_SERVICE, "qt_gesture_controller/gesture_play")
    answers: list = []
    play.call(roslibpy.ServiceRequest({"name": "QT/bye", "speed": 0.1}), answers.append)  # 10 s long
    assert wait_for(lambda: len(hub.gestures) > played, 30)
    assert call(ros, names.GESTURE_STOP_SERVICE, "qt_gesture_controller/gesture_stop")["status"]
    assert wait_for(lambda: answers, 30) and answers[0]["status"] is False
    assert "/gesture/cancel" in hub.rpc_names
    # the gesture menu offers the robot's own too
    menu = Watch(ros, names.MENUS_TOPIC, "vr_teleop_msgs/Menus")
    try:
        assert wait_for(lambda: "QT/bye" in json.dumps(menu.latest), 30)
    finally:
        menu.close()


def test_motors_off_ignore_commands_and_home_uses_the_robots_own(zmq_robot):
    hub, server, ros = zmq_robot
    clamps = Watch(ros, names.CLAMP_TOPIC, "vr_teleop_msgs/Clamp")
    head = roslibpy.Topic(ros, "/qt_robot/head_position/command", "std_msgs/Float64MultiArray")
    try:
        assert call(ros, names.MOTORS_CONTROL_MODE_SERVICE, "qt_motors_controller/set_control_mode",
                    {"parts": ["head"], "mode": 1})["status"]
        assert wait_for(lambda: not hub.torque["HeadYaw"] and not hub.torque["HeadPitch"], WAIT)
        sent = len(hub.commands)
        head.publish(roslibpy.Message({"data": [-20.0, 0.0]}))
        assert wait_for(lambda: clamps.any(lambda m: "HeadYaw" in m["ignored"]), WAIT)
        assert not any("HeadYaw" in c for c in hub.commands[sent:])  # never sent to the robot
        assert call(ros, names.MOTORS_CONTROL_MODE_SERVICE, "qt_motors_controller/set_control_mode",
                    {"parts": ["head"], "mode": 0})["status"]
        assert wait_for(lambda: hub.torque["HeadYaw"], WAIT)
        assert call(ros, names.MOTORS_HOME_SERVICE, "qt_motors_controller/home", {"parts": ["head"]})["status"]
        assert wait_for(lambda: {"HeadYaw", "HeadPitch"} <= set(hub.homed), WAIT)
        assert wait_for(lambda: abs(hub.positions["HeadYaw"]) < 0.5, 30)
    finally:
        clamps.close()


def test_motor_errors_and_voice_activity_become_events(zmq_robot):
    hub, server, ros = zmq_robot
    events = Watch(ros, names.EVENT_TOPIC, "vr_teleop_msgs/Event")
    motors = Watch(ros, names.MOTORS_STATUS_TOPIC, "vr_teleop_msgs/MotorsStatus")
    assert wait_subscribed(server, names.EVENT_TOPIC)  # an event is sent once: be there before it happens
    try:
        hub.faults = {"RightElbowRoll": {"overload_limit": True}}
        assert wait_for(lambda: events.any(lambda e: e["kind"] == "motor_error" and e["level"] == "danger"
                                           and json.loads(e["detail"]) == {"motor": "RightElbowRoll",
                                                                           "faults": ["overload_limit"]}), 30)
        # the motors' status panel says which motor and what
        assert wait_for(lambda: dict(zip(motors.latest.get("name", []), motors.latest.get("fault", [])))
                        .get("RightElbowRoll") == "overload_limit", 30), motors.latest
        assert set(motors.latest["fault"]) == {"", "overload_limit"}
        assert motors.latest["temperature"][motors.latest["name"].index("HeadYaw")] == 35.0  # measured, not modelled
        hub.faults = {"RightElbowRoll": {}}
        assert wait_for(lambda: events.any(lambda e: e["kind"] == "motor_ok"), 30)
        assert wait_for(lambda: set(motors.latest["fault"]) == {""}, 30)
        hub.mic_event = {"activity": True, "direction": 75}
        assert wait_for(lambda: events.any(lambda e: e["kind"] == "voice_activity"
                                           and json.loads(e["detail"]) == {"activity": True, "direction_deg": 75}),30)
        hub.mic_event = {"activity": True, "direction": 85}  # the array's estimate wanders: no news
        hub.mic_event = {"activity": True, "direction": 160}  # the voice moved
        assert wait_for(lambda: events.any(lambda e: e["kind"] == "voice_activity"
                                           and json.loads(e["detail"])["direction_deg"] == 160), 30)
        hub.mic_event = {"activity": False, "direction": 160}
        assert wait_for(lambda: events.any(lambda e: e["kind"] == "voice_activity"
                                           and not json.loads(e["detail"])["activity"]), 30)
        told = [json.loads(e["detail"]) for e in events.messages if e["kind"] == "voice_activity"]
        assert [t["direction_deg"] for t in told if t["activity"]] == [75, 160]
    finally:
        hub.faults, hub.mic_event = {}, {"activity": False, "direction": 0}
        events.close()
        motors.close()


def test_voice_activity_in_the_base_frame(zmq_robot):
    """The microphone's events are the link's VoiceActivity, their direction turned with the head's yaw into the
    base frame (luxai.py's _to_base); a wandering estimate is no news."""
    hub, server, ros = zmq_robot
    backend = server.server.robot
    heard: list[VoiceActivity] = []
    remove = server.call(lambda: backend.on_voice_activity(heard.append))
    try:
        yaw = server.call(lambda: backend.joint_state().as_dict()["HeadYaw"])
        hub.mic_event = {"activity": True, "direction": 75}
        assert wait_for(lambda: any(a.speaking for a in heard), 30), heard
        assert heard[-1].direction_deg == pytest.approx(75 + yaw, abs=1.0) and heard[-1].who == ""
        hub.mic_event = {"activity": True, "direction": 80}
        hub.mic_event = {"activity": True, "direction": 330}  # past 180: to the right, negative
        assert wait_for(lambda: heard[-1].direction_deg == pytest.approx(-30 + yaw, abs=1.0), 30), heard
        hub.mic_event = {"activity": False, "direction": 330}
        assert wait_for(lambda: not heard[-1].speaking, 30), heard
        assert [round(a.direction_deg - yaw) for a in heard if a.speaking] == [75, -30]
    finally:
        server.call(remove)
        hub.mic_event = {"activity": False, "direction": 0}


def test_supervised_attention_turns_the_head_to_the_microphones_voice_within_its_limits(zmq_robot):
    """Issue 34 on a v3 robot: a voice in the microphone's events is, in the base frame (the array's angle plus the
    head's yaw), where supervised autonomy turns the head, through the hub's motor commands and never past the
    robot's own limits (HeadYaw -40..45); the attention target says voice."""
    hub, server, ros = zmq_robot
    autonomy, backend = server.server.autonomy, server.server.robot
    attention = Watch(ros, names.AUTONOMY_ATTENTION_TOPIC, "vr_teleop_msgs/AttentionTarget")
    lower, upper = NARROW["HeadYaw"]["position_min"], NARROW["HeadYaw"]["position_max"]

    def level(name: str) -> None:
        reply = call(ros, names.AUTONOMY_LEVEL_SERVICE, "vr_teleop_msgs/SetAutonomy", {"level": name})
        assert reply["success"], reply

    try:
        for direction in (30.0, -70.0):  # a voice to the left, then one to the right beyond the head's reach
            level("teleoperated")  # no glance moves the head while the voice starts
            assert wait_for(lambda: abs(hub.positions["HeadYaw"] - hub.targets.get("HeadYaw", 0.0)) < 0.1, 30)
            yaw = hub.positions["HeadYaw"]
            assert wait_for(lambda: abs(server.call(lambda: backend.joint_state().as_dict()["HeadYaw"]) - yaw) < 0.5,
                            30)  # the server knows where the head is
            hub.mic_event = {"activity": True, "direction": round(direction - yaw) % 360}
            assert wait_for(lambda: server.call(lambda: autonomy.voice is not None
                                                and autonomy.voice.direction is not None), 30)
            assert server.call(lambda: autonomy.voice.direction) == pytest.approx(direction, abs=1.5)
            before = len(hub.commands)
            level("supervised")
            expected = min(max(direction, lower), upper)
            assert wait_for(lambda: abs(hub.positions["HeadYaw"] - expected) <= 10.0, 30), hub.positions
            assert wait_for(lambda: attention.any(lambda m: m["source"] == "voice"
                                                  and abs(m["yaw"] - expected) <= 10.0), 30), attention.latest
            sent = [c["HeadYaw"]["position"] for c in hub.commands[before:] if "HeadYaw" in c]
            assert sent and all(lower <= y <= upper for y in sent), sent
            hub.mic_event = {"activity": False, "direction": 0}
            assert wait_for(lambda: server.call(lambda: autonomy.voice is None), 30)
    finally:
        hub.mic_event = {"activity": False, "direction": 0}
        level("supervised")  # the module's level, as the server started
        attention.close()


def test_the_operators_voice_over_rosbridge_reaches_the_speaker_stream(zmq_robot):
    """A client's voice on /vr_teleop/audio/operator (48 kHz stereo, as its AudioInfo says) reaches the media
    foreground audio stream as 16 kHz mono PCM at its pitch, and is logged."""
    hub, server, ros = zmq_robot
    start = len(hub.audio)
    pcm = tone(1.0, 48000, 2)
    sender = VoiceSender(ros, pcm, 48000, 2).start()
    assert sender.done.wait(30)
    assert wait_for(lambda: len(hub.audio) - start >= 0.9 * 16000 * 2, 30), len(hub.audio) - start
    assert set(hub.audio_frames[-10:]) == {(1, 16000, 16)}
    heard = np.frombuffer(bytes(hub.audio[start:]), "<i2")
    assert np.sqrt(np.mean(heard.astype(np.float32) ** 2)) > 5000
    assert abs(pitch(heard, 16000) - 440) < 10
    assert wait_for(lambda: logged(server.settings.audio_dir) == (48000, 2, pcm), 30)


def test_the_cameras_color_stream_reaches_the_jpeg_topic(zmq_robot):
    hub, server, ros = zmq_robot
    camera = Watch(ros, names.CAMERA_TOPIC, "sensor_msgs/CompressedImage")
    try:
        assert wait_for(lambda: len(camera.messages) >= 3, 30)
        import base64
        image = cv2.imdecode(np.frombuffer(base64.b64decode(camera.latest["data"]), np.uint8), cv2.IMREAD_COLOR)
        assert image.shape == (120, 160, 3)
        assert image[:, :, 2].mean() > 150  # the fake camera sees red (BGR kept as BGR)
    finally:
        camera.close()


def rms(frame: np.ndarray) -> float:
    mono = frame.reshape(-1, 2)[:, 0] if frame.size == 1920 else frame
    return float(np.sqrt(np.mean(mono.astype(np.float32) ** 2)))


async def test_voice_in_and_the_microphone_out_through_webrtc(zmq_robot):
    """An aiortc peer's tone reaches the robot's speaker stream as 16 kHz mono PCM at its pitch; the robot's
    microphone (channel 0, a 440 Hz tone) reaches the peer's audio, read only while someone listens."""
    hub, server, _ = zmq_robot
    backend = server.server.robot
    assert not backend.microphone_read
    ros = await Rosbridge.open(server.url)
    tone = Tone(660.0, 0.5)
    peer = MediaPeer(video=False, mic=tone)
    try:
        reply = await peer.negotiate(ros)
        assert reply["values"]["success"], reply
        start = len(hub.audio)
        assert await until(lambda: len(hub.audio) - start > 16000 * 2, 30)  # a second of voice
        assert set(hub.audio_frames[-10:]) == {(1, 16000, 16)}
        heard = np.frombuffer(bytes(hub.audio[-16000:]), "<i2").astype(np.float32)
        spectrum = np.abs(np.fft.rfft(heard * np.hanning(heard.size)))
        assert abs(np.fft.rfftfreq(heard.size, 1 / 16000)[np.argmax(spectrum)] - 660) < 10
        assert await until(lambda: sum(rms(f) > 1000 for _, f in peer.audio_frames[-50:]) >= 25, 30), \
            "the robot's microphone was not heard"
        heard = np.concatenate([f.reshape(-1, 2)[:, 0] if f.size == 1920 else f
                                for _, f in peer.audio_frames[-50:] if rms(f) > 1000]).astype(np.float32)
        spectrum = np.abs(np.fft.rfft(heard * np.hanning(heard.size)))
        assert abs(np.fft.rfftfreq(heard.size, 1 / 48000)[np.argmax(spectrum)] - 440) < 10
        await peer.close()
        peer = None
        assert await until(lambda: server.call(lambda: not backend.microphone_read), 30)
    finally:
        if peer is not None:
            await peer.close()
        await ros.close()


def test_the_robot_lost_and_back(zmq_robot):
    """The hub's process dies and comes back on the same ports: robot_lost (control released, commands ignored and
    never sent later, services refused), then robot_back and a fresh engage moves the head again."""
    hub, server, ros = zmq_robot
    teleop = Watch(ros, names.TELEOP_STATE_TOPIC, "vr_teleop_msgs/TeleopState")
    events = Watch(ros, names.EVENT_TOPIC, "vr_teleop_msgs/Event")
    headset = Headset(ros).start()
    assert wait_subscribed(server, names.EVENT_TOPIC)
    try:
        engage(ros)
        headset.head_orientation = unity_yaw_pitch(20)
        assert wait_for(lambda: abs(hub.positions["HeadYaw"] - 20) < 2, 30), hub.positions
        answers: list = []
        long = "a sentence long enough to be cut short when the robot dies in the middle of saying it to the class"
        roslibpy.Service(ros, names.SPEECH_SAY_SERVICE, "qt_robot_interface/speech_say").call(
            roslibpy.ServiceRequest({"message": long}), answers.append)
        assert wait_for(lambda: hub.said and hub.said[-1]["text"] == long, 30)
        hub.stop()
        assert wait_for(lambda: teleop.latest.get("state") == "robot_lost" and not teleop.latest["robot_connected"],30), teleop.latest
        assert wait_for(lambda: events.any(lambda e: e["kind"] == "robot_lost" and e["level"] == "danger"), WAIT)
        assert wait_for(lambda: events.any(lambda e: e["source"] == "backend" and e["kind"] == "disconnected"), WAIT)
        assert wait_for(lambda: answers, 30) and answers[0]["status"] is False  # ended with the robot, not completed
        refused(call(ros, "/vr_teleop/control/engage", "std_srvs/SetBool", {"data": True}), "disconnected")
        refused(call(ros, names.EMOTION_SHOW_SERVICE, "qt_robot_interface/emotion_show", {"name": "QT/sad"}))
        report = server.call(lambda: server.server.robot.set_joint_targets({"HeadPitch": 12.0}))
        assert report.ignored == ("HeadPitch",)
        hub.commands.clear()
        hub.start()  # back, on the same ports
        assert wait_for(lambda: teleop.latest.get("robot_connected"), 30), teleop.latest
        assert wait_for(lambda: events.any(lambda e: e["kind"] == "robot_back"), WAIT)
        assert wait_for(lambda: events.any(lambda e: e["source"] == "backend" and e["kind"] == "reconnected"), WAIT)
        assert not any("HeadPitch" in c and c["HeadPitch"]["position"] == 12.0 for c in hub.commands)
        assert "QT/sad" not in hub.emotions  # the refused emotion did not burst out later
        engage(ros)  # the headset's orientation now (20 deg left) is the head's new zero...
        headset.head_orientation = unity_yaw_pitch(-10)  # ...so turning to 10 deg right is 30 deg right
        assert wait_for(lambda: abs(hub.positions["HeadYaw"] + 30) < 2, 30), hub.positions
        assert still(lambda: abs(hub.positions["HeadYaw"] + 30) < 2, teleop), hub.positions  # there, not passing
    finally:
        headset.stop()
        teleop.close()
        events.close()


def test_a_robot_without_the_camera_plugin_runs_without_a_camera(servers):
    hub = FakeQtrobotV3(camera=False).start()
    server = None
    try:
        server = luxai_server(servers, robot_url=f"tcp://127.0.0.1:{hub.hub_port}",
                              camera_url=f"tcp://127.0.0.1:{free_port()}")
        ros = roslibpy.Ros(host="127.0.0.1", port=server.port)
        ros.run(timeout=10)
        try:
            camera = description(ros)["backend"]["camera"]
            assert not camera["available"] and "realsense-driver" in camera["problem"]
            assert call(ros, names.EMOTION_SHOW_SERVICE, "qt_robot_interface/emotion_show", {"name": "QT/sad"})
        finally:
            ros.close()
    finally:
        if server is not None:
            server.stop()
        hub.stop()


def serve(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "vr_teleop_server.cli", "serve", "--port", "0", "--backend", "luxai",
                           *args], capture_output=True, text=True, timeout=90, check=False, cwd=ROOT)


def test_serve_exits_1_with_the_reason_when_the_robot_cannot_be_reached():
    port = free_port()
    proc = serve("--robot-url", f"tcp://127.0.0.1:{port}")
    assert proc.returncode == 1, proc.stderr
    assert f"cannot reach the QTrobot v3 service hub at tcp://127.0.0.1:{port}" in proc.stderr, proc.stderr


@pytest.mark.parametrize("url, expected", [("mqtt://127.0.0.1:1883", "give the robot's id too (--robot-id"),
                                           ("ws2://robot:50500", "use tcp://ROBOT:50500"),
                                           ("tcp://:50500", "give the service hub as tcp://HOST:PORT")])
def test_serve_refuses_a_robot_url_it_cannot_use(url, expected, capsys):
    from vr_teleop_server.cli import main

    assert main(["serve", "--port", "0", "--backend", "luxai", "--robot-url", url]) == 2
    assert expected in capsys.readouterr().err


# ---- through a broker ---------------------------------------------------------------------------------------------
class Mosquitto:
    """Debian's mosquitto on a free loopback port, started and stopped by its process id."""

    def __init__(self, tmp: Path, extra: str = "allow_anonymous true\n") -> None:
        self.port = free_port()
        self.config = tmp / "mosquitto.conf"
        # user: started as root, mosquitto would switch to its own account, which cannot read the test's key files
        self.config.write_text(f"listener {self.port} 127.0.0.1\npersistence false\nuser {getpass.getuser()}\n"
                               f"{extra}")
        self.proc: subprocess.Popen | None = None

    def start(self) -> Mosquitto:
        binary = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
        self.proc = subprocess.Popen([binary, "-c", str(self.config)], stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL)
        import socket

        def listening() -> bool:
            with socket.socket() as s:
                return s.connect_ex(("127.0.0.1", self.port)) == 0

        if not wait_for(listening, 10):
            raise RuntimeError("mosquitto did not start")
        return self

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.terminate()
            self.proc.wait(10)
            self.proc = None


@pytest.fixture(scope="module")
def mqtt_robot(module_servers, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("mqtt")
    broker = Mosquitto(tmp).start()
    hub = FakeQtrobotV3(broker=f"mqtt://127.0.0.1:{broker.port}", zmq=False).start()
    server = luxai_server(module_servers, robot_url=f"mqtt://127.0.0.1:{broker.port}", robot_id=hub.robot_id)
    ros = roslibpy.Ros(host="127.0.0.1", port=server.port)
    ros.run(timeout=10)
    yield broker, hub, server, ros
    ros.close()
    server.stop()
    hub.stop()
    broker.stop()


def test_through_mosquitto_joints_face_speech_and_camera(mqtt_robot):
    broker, hub, server, ros = mqtt_robot
    roslibpy.Topic(ros, "/qt_robot/head_position/command", "std_msgs/Float64MultiArray").publish(
        roslibpy.Message({"data": [-50.0, 5.0]}))  # the robot's HeadYaw stops at -40
    assert wait_for(lambda: abs(hub.positions["HeadYaw"] + 40) < 0.5 and abs(hub.positions["HeadPitch"] - 5) < 0.5,30), hub.positions
    assert call(ros, names.EMOTION_SHOW_SERVICE, "qt_robot_interface/emotion_show", {"name": "QT/surprise"})["status"]
    assert wait_for(lambda: "QT/surprise" in hub.emotions, WAIT)
    assert call(ros, names.SPEECH_SAY_SERVICE, "qt_robot_interface/speech_say", {"message": "hi"})["status"]
    assert hub.spoken[-1] == "hi"
    # the operator's voice, written on the stream's bare topic (SDK 0.6.9), reaches the gateway
    start = len(hub.audio)
    server.call(lambda: server.server.robot.play_voice(b"\x00\x10" * 1600, 16000, 1))
    assert wait_for(lambda: len(hub.audio) - start >= 1280, WAIT)
    camera = Watch(ros, names.CAMERA_TOPIC, "sensor_msgs/CompressedImage")  # the plugin under its node id
    try:
        assert wait_for(lambda: len(camera.messages) >= 3, 30)
    finally:
        camera.close()
    assert description(ros)["backend"]["camera"]["source"].endswith("qtrobot-realsense-driver")


def test_a_broker_restart_is_the_robot_lost_and_back(mqtt_robot):
    broker, hub, server, ros = mqtt_robot
    backend = server.server.robot
    events = Watch(ros, names.EVENT_TOPIC, "vr_teleop_msgs/Event")
    assert wait_subscribed(server, names.EVENT_TOPIC)
    try:
        broker.stop()
        assert wait_for(lambda: not backend.connected, 30)
        assert wait_for(lambda: events.any(lambda e: e["kind"] == "robot_lost"), WAIT)
        report = server.call(lambda: backend.set_joint_targets({"HeadYaw": 10.0}))
        assert report.ignored == ("HeadYaw",)
        hub.commands.clear()
        broker.start()  # the same port; both clients reconnect with their back-off
        assert wait_for(lambda: backend.connected, 30)
        assert wait_for(lambda: events.any(lambda e: e["kind"] == "robot_back"), WAIT)
        roslibpy.Topic(ros, "/qt_robot/head_position/command", "std_msgs/Float64MultiArray").publish(
            roslibpy.Message({"data": [30.0, 0.0]}))
        assert wait_for(lambda: abs(hub.positions["HeadYaw"] - 30) < 0.5, 30), hub.positions
        # what arrived after the restart: the new command, never the one ignored while the broker was down
        assert all(c.get("HeadYaw", {}).get("position") != 10.0 for c in hub.commands)
    finally:
        events.close()


def test_a_tls_broker_with_a_login(servers, tmp_path, monkeypatch):
    """mqtts:// with a CA file and a username and password (as a school's or a cloud broker wants): the robot is
    reached and moves; the gateway of the fake robot logs in the same way."""
    from luxai.robot import MqttAuthOptions, MqttOptions, MqttTlsOptions

    from vr_teleop_server.core.certs import make_certificate

    cert = make_certificate(tmp_path / "tls", ["localhost"], [__import__("ipaddress").ip_address("127.0.0.1")])
    passwords = tmp_path / "passwords"
    subprocess.run([shutil.which("mosquitto_passwd") or "/usr/bin/mosquitto_passwd", "-b", "-c", str(passwords),
                    "teacher", "s3cret"], check=True, capture_output=True)
    broker = Mosquitto(tmp_path, f"allow_anonymous false\npassword_file {passwords}\ncafile {cert.certfile}\n"
                                 f"certfile {cert.certfile}\nkeyfile {cert.keyfile}\n").start()
    url = f"mqtts://127.0.0.1:{broker.port}"
    login = MqttOptions(tls=MqttTlsOptions(ca_file=str(cert.certfile)),
                        auth=MqttAuthOptions(mode="username_password", username="teacher", password="s3cret"))
    hub = server = None
    try:
        hub = FakeQtrobotV3(broker=url, broker_options=login, zmq=False, camera=False).start()
        server = luxai_server(servers, robot_url=url, robot_id=hub.robot_id, mqtt_ca_file=cert.certfile,
                              mqtt_username="teacher", mqtt_password="s3cret")
        assert server.call(lambda: server.server.robot.set_joint_targets({"HeadPitch": 12.0})).ok
        assert wait_for(lambda: abs(hub.positions["HeadPitch"] - 12.0) < 0.5, 30), hub.positions
    finally:
        if server is not None:
            server.stop()
        if hub is not None:
            hub.stop()
        broker.stop()



def test_camera_frames_carry_the_head_pose_from_the_joint_states(zmq_robot):
    """Issue 36 on a v3 robot: each camera frame carries the head's pose from the joint states around it (by
    arrival: the SDK's frames carry no stamp of the robot's), with the gap to the nearest, on
    /vr_teleop/camera/capture_pose under the frame's own header; during a turn the poses lie between its start and
    its end, in order."""
    hub, server, ros = zmq_robot
    command = roslibpy.Topic(ros, "/qt_robot/head_position/command", "std_msgs/Float64MultiArray")
    command.publish(roslibpy.Message({"data": [-30.0, 0.0]}))
    assert wait_for(lambda: abs(hub.positions["HeadYaw"] + 30.0) < 0.2, 30), hub.positions
    poses = Watch(ros, names.CAPTURE_POSE_TOPIC, "vr_teleop_msgs/CapturePose")
    camera = Watch(ros, names.CAMERA_TOPIC, "sensor_msgs/CompressedImage")
    try:
        assert wait_for(lambda: poses.any(lambda m: abs(m["head_yaw"] + 30.0) < 0.2), 30), poses.latest
        start = len(poses.messages)
        command.publish(roslibpy.Message({"data": [30.0, 0.0]}))
        assert wait_for(lambda: poses.any(lambda m: abs(m["head_yaw"] - 30.0) < 0.2), 30), poses.latest
        with poses.lock:
            turn = list(poses.messages[start:])
        stamps = [m["header"]["stamp"] for m in turn]
        assert wait_for(lambda: camera.any(lambda m: m["header"]["stamp"] == stamps[-1]), 30)
    finally:
        poses.close()
        camera.close()
        command.publish(roslibpy.Message({"data": [0.0, 0.0]}))
    yaws = [m["head_yaw"] for m in turn]
    assert all(m["source"] == "joint_states" and 0.0 <= m["stamp_gap"] < 1.0 for m in turn), turn  # 1 s: lost
    assert all(-30.2 <= y <= 30.2 for y in yaws) and all(b >= a - 0.01 for a, b in zip(yaws, yaws[1:])), yaws
    assert any(-29.0 < y < 29.0 for y in yaws), f"no frame during the turn: {yaws}"
