"""The real-robot backend, for real: a second server runs the stand-in and plays the robot's rosbridge (it serves
LuxAI's API), and the server under test reaches it with backend "ros". The robot side is killed and restarted."""

from __future__ import annotations

import asyncio
import base64
import threading
import time

import numpy as np
import pytest
import roslibpy
from testbed.media_client import MediaPeer, Rosbridge, Tone
from testbed.server import Pace, until
from testbed.processes import free_port
from support import (
    Headset,
    RunningServer,
    ServerFactory,
    Watch,
    call,
    refused,
    engage,
    joints,
    still,
    unity_yaw_pitch,
    wait_for,
)

from client_protocol import names

pytestmark = pytest.mark.slow  # a robot-side server, dropped and back
WAIT = 30.0  # a failure bound on a loaded machine, never a measure


def robot_side(servers: ServerFactory, port: int) -> RunningServer:
    return servers(port=port, backend="sim")


@pytest.fixture
def robot_and_server(servers):
    port = free_port()
    robot = robot_side(servers, port)
    server = servers(backend="ros", robot_url=f"ws://127.0.0.1:{port}")
    state = {"robot": robot}
    yield state, server, port
    server.stop()
    state["robot"].stop()


def test_commands_camera_and_services_reach_the_robot(robot_and_server):
    state, server, _port = robot_and_server
    robot = state["robot"]
    ros = roslibpy.Ros(host="127.0.0.1", port=server.port)
    ros.run(timeout=10)
    try:
        js = Watch(ros, "/qt_robot/joints/state", "sensor_msgs/JointState")  # relayed from the robot
        assert wait_for(lambda: "HeadYaw" in joints(js), 30)
        roslibpy.Topic(ros, "/qt_robot/head_position/command", "std_msgs/Float64MultiArray").publish(
            roslibpy.Message({"data": [25.0, 5.0]}))
        standin = robot.server.robot.standin
        assert wait_for(lambda: abs(standin.joint_positions()["HeadYaw"] - 25.0) < 1.5, 30)
        assert wait_for(lambda: abs(joints(js)["HeadYaw"] - 25.0) < 1.5, WAIT)
        assert call(ros, "/qt_robot/emotion/show", "qt_robot_interface/emotion_show", {"name": "QT/happy"})["status"]
        assert wait_for(lambda: standin.emotion == "happy", WAIT)
        camera = Watch(ros, "/camera/color/image_raw/compressed", "sensor_msgs/CompressedImage")
        assert wait_for(lambda: len(camera.messages) >= 5, 30)
        assert camera.latest["format"] == "jpeg"
        assert server.server.robot.latest_frame().width == 640
    finally:
        ros.close()


def test_the_backend_reconnects_when_the_robot_comes_back(robot_and_server, servers):
    state, server, port = robot_and_server

    def head_yaw() -> float:
        return state["robot"].server.robot.standin.joint_positions()["HeadYaw"]

    ros = roslibpy.Ros(host="127.0.0.1", port=server.port)
    ros.run(timeout=10)
    try:
        teleop = Watch(ros, "/vr_teleop/teleop_state", "vr_teleop_msgs/TeleopState")
        events = Watch(ros, "/vr_teleop/events", "vr_teleop_msgs/Event")
        headset = Headset(ros).start()
        engage(ros)
        headset.head_orientation = unity_yaw_pitch(20)
        assert wait_for(lambda: abs(state["robot"].server.robot.standin.joint_positions()["HeadYaw"] - 20) < 2, WAIT)
        state["robot"].stop()  # the robot's rosbridge goes away
        assert wait_for(lambda: teleop.latest.get("state") == "robot_lost"
                        and not teleop.latest["robot_connected"], WAIT), teleop.latest
        assert wait_for(lambda: events.any(lambda e: e["kind"] == "robot_lost" and e["level"] == "danger"), WAIT)
        assert wait_for(lambda: events.any(lambda e: e["source"] == "backend" and e["kind"] == "disconnected"), WAIT)
        refused(call(ros, "/vr_teleop/control/engage", "std_srvs/SetBool", {"data": True}), "disconnected")
        # refused, not queued (emotion_show has only `status`)
        refused(call(ros, "/qt_robot/emotion/show", "qt_robot_interface/emotion_show", {"name": "QT/sad"}))
        state["robot"] = robot_side(servers, port)  # back, on the same port
        assert wait_for(lambda: teleop.latest.get("robot_connected"), WAIT), teleop.latest
        assert wait_for(lambda: events.any(lambda e: e["kind"] == "robot_back"), WAIT)
        assert wait_for(lambda: events.any(lambda e: e["source"] == "backend" and e["kind"] == "reconnected"), WAIT)
        engage(ros)  # resuming needs a fresh engage; the headset's orientation now (20 deg left) is the new zero...
        headset.head_orientation = unity_yaw_pitch(-10)  # ...so turning to 10 deg right is 30 deg right
        assert wait_for(lambda: abs(head_yaw() + 30) < 2, WAIT), head_yaw()
        assert still(lambda: abs(head_yaw() + 30) < 2, teleop), head_yaw()  # there, not passing through
        headset.stop()
        assert state["robot"].server.robot.standin.emotion != "sad"  # the refused emotion did not burst out later
    finally:
        ros.close()


def test_serve_says_when_the_robot_cannot_be_reached():
    import subprocess
    import sys
    from pathlib import Path

    port = free_port()
    proc = subprocess.run([sys.executable, "-m", "vr_teleop_server.cli", "serve", "--port", "0", "--backend", "ros",
                           "--robot-url", f"ws://127.0.0.1:{port}"], capture_output=True, text=True, timeout=60,
                          check=False, cwd=Path(__file__).resolve().parent.parent)
    assert proc.returncode == 1 and f"cannot reach the robot's rosbridge at ws://127.0.0.1:{port}" in proc.stderr, \
        proc.stderr


class RespeakerApp:
    """Plays LuxAI's qt_respeaker_app on the robot's rosbridge: channel 0 as AudioData, mono S16LE at 16 kHz, in
    64 ms messages paced in real time (uint8[] as base64, as ROS 1's rosbridge sends it); a tone while `loud`."""

    def __init__(self, ros: roslibpy.Ros, frequency: float = 440.0) -> None:
        self.topic = roslibpy.Topic(ros, names.ROBOT_MICROPHONE_TOPIC, "audio_common_msgs/AudioData")
        self.topic.advertise()  # there before the backend subscribes, as on a robot
        self.frequency = frequency
        self.loud = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> RespeakerApp:
        self._thread.start()
        return self

    def _run(self) -> None:
        n, sample = 1024, 0
        pace = Pace(16000 / n)  # a live microphone's rate
        while not self._stop.is_set():
            t = (sample + np.arange(n)) / 16000
            pcm = (np.sin(2 * np.pi * self.frequency * t) * (0.4 * 32767 if self.loud else 0)).astype("<i2")
            self.topic.publish(roslibpy.Message({"data": base64.b64encode(pcm.tobytes()).decode()}))
            sample += n
            pace.wait()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)


def mono(frame: np.ndarray) -> np.ndarray:
    """aiortc decodes Opus as interleaved stereo: the left channel."""
    return frame.reshape(-1, 2)[:, 0] if frame.size == 1920 else frame


def rms(frame: np.ndarray) -> float:
    return float(np.sqrt(np.mean(mono(frame).astype(np.float32) ** 2)))


async def test_the_robots_microphone_reaches_a_webrtc_peer(servers):
    """qt_respeaker_app's channel 0 on the robot's rosbridge is mixed into the robot's WebRTC audio: a peer on our
    server hears the tone the robot's microphone hears, at its pitch, only while it sounds; the backend reads the
    microphone only while a peer listens."""
    port = free_port()
    robot = robot_side(servers, port)
    firmware = roslibpy.Ros(host="127.0.0.1", port=port)
    await asyncio.to_thread(firmware.run, 10)
    respeaker = RespeakerApp(firmware).start()
    server = peer = ros = None
    try:
        server = await asyncio.to_thread(servers, backend="ros", robot_url=f"ws://127.0.0.1:{port}")
        backend = server.server.robot
        assert not backend.microphone_read  # nobody listens yet
        ros = await Rosbridge.open(server.url)
        peer = MediaPeer(video=False)
        reply = await peer.negotiate(ros)
        assert reply["values"]["success"], reply
        assert await until(lambda: len(peer.audio_frames) >= 25, 30)
        assert backend.microphone_read
        assert max(rms(f) for _, f in peer.audio_frames[-25:]) < 100  # the classroom is quiet

        respeaker.loud = True
        assert await until(lambda: sum(rms(f) > 1000 for _, f in peer.audio_frames[-50:]) >= 25, 30), \
            "the robot's microphone was not heard"
        heard = np.concatenate([mono(f) for _, f in peer.audio_frames[-50:] if rms(f) > 1000]).astype(np.float32)
        spectrum = np.abs(np.fft.rfft(heard * np.hanning(heard.size)))
        assert abs(np.fft.rfftfreq(heard.size, 1 / 48000)[np.argmax(spectrum)] - 440) < 10

        respeaker.loud = False
        assert await until(lambda: max(rms(f) for _, f in peer.audio_frames[-25:]) < 100, 30), \
            "the robot's microphone went quiet, its audio did not"
        await peer.close()
        peer = None
        assert await until(lambda: not server.call(lambda: backend.microphone_read), 30)
    finally:
        if peer is not None:
            await peer.close()
        if ros is not None:
            await ros.close()
        respeaker.stop()
        if server is not None:
            await asyncio.to_thread(server.stop)
        firmware.close()
        await asyncio.to_thread(robot.stop)


async def test_the_operators_voice_goes_to_the_robots_speaker_topic(servers):
    """A tone from an aiortc peer on our server reaches the robot's rosbridge as 16 kHz mono S16LE AudioData on the
    speaker topic (what audio_play on a QTrobot plays), at its pitch; the telemetry reports the level the robot
    plays, and a silenced tone is silence there too."""
    port = free_port()
    robot = robot_side(servers, port)
    listener = roslibpy.Ros(host="127.0.0.1", port=port)
    await asyncio.to_thread(listener.run, 10)
    chunks: list[np.ndarray] = []
    speaker = roslibpy.Topic(listener, names.ROBOT_SPEAKER_TOPIC, "audio_common_msgs/AudioData")
    speaker.subscribe(lambda m: chunks.append(np.frombuffer(base64.b64decode(m["data"]), "<i2")))
    server = peer = ros = None
    tone = Tone(440.0, 0.5)
    try:
        server = await asyncio.to_thread(servers, backend="ros", robot_url=f"ws://127.0.0.1:{port}")
        ros = await Rosbridge.open(server.url)
        peer = MediaPeer(video=False, mic=tone)
        reply = await peer.negotiate(ros)
        assert reply["values"]["success"], reply
        assert await until(lambda: len(chunks) >= 50, 30), len(chunks)  # 2 s of voice
        assert {c.size for c in chunks} == {640}  # 40 ms at 16 kHz a message
        heard = np.concatenate(chunks[-25:]).astype(np.float32)
        assert np.sqrt(np.mean(heard ** 2)) > 5000
        spectrum = np.abs(np.fft.rfft(heard * np.hanning(heard.size)))
        assert abs(np.fft.rfftfreq(heard.size, 1 / 16000)[np.argmax(spectrum)] - 440) < 10
        telemetry = await ros.subscribe("/vr_teleop/telemetry", "vr_teleop_msgs/Telemetry")
        assert await until_message(telemetry, lambda m: any(c["operator_voice_level"] > 0.5 for c in m["clients"]))

        tone.amplitude = 0.0
        assert await until(lambda: len(chunks) > 10 and max(np.abs(c).max() for c in chunks[-5:]) < 100, 30)
        assert await until_message(telemetry, lambda m: all(c["operator_voice_level"] == 0.0 for c in m["clients"]))
    finally:
        if peer is not None:
            await peer.close()
        if ros is not None:
            await ros.close()
        if server is not None:
            await asyncio.to_thread(server.stop)
        listener.close()
        await asyncio.to_thread(robot.stop)


async def until_message(queue: asyncio.Queue, predicate, timeout: float = 30.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            if predicate(await asyncio.wait_for(queue.get(), max(0.1, deadline - time.monotonic()))):
                return True
        except asyncio.TimeoutError:
            break
    return False
