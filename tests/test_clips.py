"""Voices from home (features/clips.py, `serve --clips DIR`) over the real protocol: a supervisor uploads a WAV,
an Ogg and an MP3 clip, they are listed on /vr_teleop/clips and in the speech menu, a clip played from the menu moves
the stand-in's mouth and reaches the headset's audio, "stop talking" stops it, and a clip too long, too loud or not
decodable is refused with the reason. The same clip reaches the ROS 1 robot's speaker topic and the v3 robot's media
stream."""

from __future__ import annotations

import base64
import io
import json
import re
import wave

import av
import numpy as np
import pytest
import roslibpy
from operator_voice import VoiceSender, logged, pitch, tone
from testbed.luxai_hub import FakeQtrobotV3
from testbed.ros1_rosbridge import Ros1QTrobot
from support import Watch, call, refused, wait_for

from client_protocol import names

TOKENS = {"operator": "op-token-123", "supervisor": "sup-token-456"}


def samples(seconds: float, rate: int, amplitude: float = 0.1, freq: float = 440.0) -> np.ndarray:
    t = np.arange(int(seconds * rate)) / rate
    return (np.sin(2 * np.pi * freq * t) * amplitude * 32767).astype("<i2")


def wav(seconds: float = 1.5, rate: int = 22050, amplitude: float = 0.1) -> bytes:
    buf = io.BytesIO()
    with wave.open(buf, "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(samples(seconds, rate, amplitude).tobytes())
    return buf.getvalue()


def encoded(container: str, codec: str, seconds: float = 1.0, rate: int = 48000) -> bytes:
    """A clip as a phone would make it: Ogg (Opus) or MP3, through FFmpeg's encoders."""
    buf = io.BytesIO()
    x = samples(seconds, rate)
    with av.open(buf, "w", format=container) as out:
        stream = out.add_stream(codec, rate=rate, layout="mono")
        for i in range(0, x.size, 960):
            frame = av.AudioFrame.from_ndarray(x[None, i:i + 960], format="s16", layout="mono")
            frame.sample_rate = rate
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode(None):
            out.mux(packet)
    return buf.getvalue()


def add(ros: roslibpy.Ros, name: str, data: bytes) -> dict:
    return roslibpy.Service(ros, names.CLIP_ADD_SERVICE, "vr_teleop_msgs/AddClip").call(
        roslibpy.ServiceRequest({"name": name, "data": base64.b64encode(data).decode()}), timeout=30)


def select(ros: roslibpy.Ros, item: str) -> dict:
    return roslibpy.Service(ros, names.MENU_SELECT_SERVICE, "vr_teleop_msgs/MenuSelect").call(
        roslibpy.ServiceRequest({"id": item, "args": ""}), timeout=60)


def connect(port: int, token: str = "") -> roslibpy.Ros:
    url = f"ws://127.0.0.1:{port}" + (f"/?token={token}" if token else "")
    ros = roslibpy.Ros(host=url, port=None)  # a whole URL: the token in its query, as the pages send it
    ros.run(timeout=10)
    return ros


def clip_items(ros: roslibpy.Ros) -> dict[str, dict]:
    watch = Watch(ros, names.MENUS_TOPIC, "vr_teleop_msgs/Menus")
    try:
        assert wait_for(lambda: watch.latest, 30)
        return {i["id"]: i for i in watch.latest["items"] if i["parent"] == "speech.clips"}
    finally:
        watch.close()


@pytest.fixture
def sim(servers, tmp_path):
    server = servers(backend="sim", bystander_interval=0, clips=tmp_path / "clips")
    ros = connect(server.port)
    yield server, ros
    ros.close()


def test_clips_uploaded_are_listed_and_one_played_moves_the_mouth_until_stopped(sim):
    server, ros = sim
    library = Watch(ros, names.CLIPS_TOPIC, "vr_teleop_msgs/Clips")
    assert wait_for(lambda: library.latest.get("enabled") is True, 30) and library.latest["clips"] == []
    for name, data in (("grandma_hello", wav(1.5)), ("dad_well_done", encoded("ogg", "libopus")),
                       ("friend_bravo", encoded("mp3", "libmp3lame"))):
        reply = add(ros, name, data)
        assert reply["success"], reply
    assert wait_for(lambda: [c["name"] for c in library.latest["clips"]] ==
                    ["dad_well_done", "friend_bravo", "grandma_hello"], 30), library.latest
    durations = {c["name"]: c["duration"] for c in library.latest["clips"]}
    assert abs(durations["grandma_hello"] - 1.5) < 0.01 and abs(durations["friend_bravo"] - 1.0) < 0.1
    assert sorted(p.name for p in (server.settings.clips).iterdir()) == \
        ["dad_well_done.ogg", "friend_bravo.mp3", "grandma_hello.wav"]
    items = clip_items(ros)
    assert items["speech.clips.grandma_hello"]["command"] == "play_clip"
    assert json.loads(items["speech.clips.grandma_hello"]["args"]) == {"name": "grandma_hello"}

    robot = server.server.robot
    heard = Watch(ros, names.ROBOT_AUDIO_TOPIC, "audio_common_msgs/AudioData")
    reply = select(ros, "speech.clips.grandma_hello")
    assert reply == {"success": True, "message": "playing 'grandma_hello' (1.5 s)"}, reply
    owners = server.server.owners
    talking = []  # the voice's and the face's owners read on the server's loop at the moment the mouth is open

    def mouth_open() -> bool:
        level, owned = server.call(lambda: (robot.voice_level, (owners.owner("voice"), owners.owner("face"))))
        if level > 0.3:
            talking.append(owned)
        return level > 0.3 or library.latest["playing"] == ""

    assert wait_for(mouth_open, 30)
    assert library.latest["playing"] == "grandma_hello", "the mouth did not move while the clip played"
    # whoever played it owns the voice and the face while it plays: autonomy neither talks over it nor cuts it
    assert talking == [("client", "client")], talking
    assert server.call(lambda: robot.standin.emotion) == "talking"  # the talking face while it plays
    assert wait_for(lambda: library.latest["playing"] == "", 30)
    with heard.lock:
        pcm = np.concatenate([np.frombuffer(base64.b64decode(m["data"]), "<i2") for m in heard.messages])
    assert abs(pcm.size / 16000 - 1.5) < 0.05 and abs(pitch(pcm, 16000) - 440) < 10  # the headset heard it whole
    assert wait_for(lambda: server.call(lambda: robot.standin.emotion) == "neutral", 30)

    assert add(ros, "long_story", wav(60.0, rate=8000))["success"]  # as long as a clip may be
    assert select(ros, "speech.clips.long_story")["success"]
    assert wait_for(lambda: library.latest["playing"] == "long_story", 30)
    assert wait_for(lambda: server.call(lambda: robot.voice_level) > 0.3, 30)
    assert select(ros, "speech.stop")["success"]
    # ended long before its 60 s: stopped (the backstop is only a bound on a loaded machine)
    assert wait_for(lambda: library.latest["playing"] == "", 30), "stop talking did not stop the clip"
    assert wait_for(lambda: server.call(lambda: robot.voice_level) == 0.0, 30)

    assert call(ros, names.CLIP_REMOVE_SERVICE, "vr_teleop_msgs/ClipName", {"name": "long_story"})["success"]
    assert not (server.settings.clips / "long_story.wav").exists()  # a family's withdrawal deletes the file
    assert wait_for(lambda: "long_story" not in [c["name"] for c in library.latest["clips"]], 30)
    refused(call(ros, names.CLIP_PLAY_SERVICE, "vr_teleop_msgs/ClipName", {"name": "long_story"}),
            "no clip named 'long_story'; the clips are: dad_well_done, friend_bravo, grandma_hello")


BAD_CLIPS = [
    ("too_long", lambda: wav(61.0, rate=8000), r"longer than 60 s"),
    ("too_loud", lambda: wav(1.0, amplitude=1.0), r"too loud \(-3\.\d dBFS RMS"),
    ("silent", lambda: wav(1.0, amplitude=0.0), r"silent"),
    ("garbage", lambda: b"\x00\x01this is not audio at all" * 100, r"cannot be decoded as WAV, Ogg or MP3"),
    ("a_png", lambda: bytes.fromhex("89504e470d0a1a0a") + b"\x00" * 200, r"cannot be decoded|not WAV, Ogg or MP3"),
    ("flac", lambda: encoded("flac", "flac"), r"raw FLAC, not WAV, Ogg or MP3"),
    ("bad name!", lambda: wav(1.0), r"use 1 to 64 letters, digits, - and _"),
]


@pytest.mark.parametrize("name, data, reason", BAD_CLIPS, ids=[c[0] for c in BAD_CLIPS])
def test_a_bad_clip_is_refused_with_the_reason_and_not_kept(sim, name, data, reason):
    server, ros = sim
    reply = refused(add(ros, name, data()), reason)
    assert reply["message"].startswith(f"clip {name!r} refused: "), reply
    assert list(server.settings.clips.iterdir()) == []
    assert clip_items(ros) == {}
    assert add(ros, "fine", wav(0.5))["success"]  # the connection and the library still work


def test_only_a_supervisor_adds_and_removes_clips_and_a_server_without_a_library_says_how(servers, tmp_path):
    server = servers(backend="sim", bystander_interval=0, clips=tmp_path / "clips",
                     operator_token=TOKENS["operator"], supervisor_token=TOKENS["supervisor"])
    operator, supervisor = connect(server.port, TOKENS["operator"]), connect(server.port, TOKENS["supervisor"])
    try:
        refused(add(operator, "x", wav(0.5)), "only a supervisor may")
        assert add(supervisor, "x", wav(0.5))["success"]
        reply = call(operator, names.CLIP_PLAY_SERVICE, "vr_teleop_msgs/ClipName", {"name": "x"})
        assert reply == {"success": True, "message": "playing 'x' (0.5 s)"}  # the teacher plays them
    finally:
        operator.close()
        supervisor.close()
    bare = servers(backend="sim", bystander_interval=0)
    ros = connect(bare.port)
    try:
        refused(add(ros, "x", wav(0.5)), r"keeps no clips: start it with `serve --clips DIR`")
    finally:
        ros.close()


@pytest.mark.slow
def test_a_clip_reaches_the_ros1_robots_speaker_topic(servers, tmp_path):
    robot = Ros1QTrobot()
    try:
        server = servers(backend="ros", robot_url=robot.url, clips=tmp_path / "clips")
        ros = connect(server.port)
        try:
            assert add(ros, "hello", wav(1.0))["success"]
            reply = call(ros, names.CLIP_PLAY_SERVICE, "vr_teleop_msgs/ClipName", {"name": "hello"})
            assert reply == {"success": True, "message": "playing 'hello' (1.0 s)"}, reply

            def played() -> np.ndarray:
                chunks = [np.frombuffer(base64.b64decode(m["data"]), "<i2")
                          for m in robot.published.get(names.ROBOT_SPEAKER_TOPIC, [])]
                return np.concatenate(chunks) if chunks else np.zeros(0, "<i2")

            assert wait_for(lambda: played().size >= 0.95 * 16000, 30), played().size
            heard = played()
            assert abs(pitch(heard, 16000) - 440) < 10 and np.sqrt(np.mean(heard.astype(np.float32) ** 2)) > 1000
            shown = lambda: [c["name"] for c in robot.services_called(names.EMOTION_SHOW_SERVICE)]  # noqa: E731
            assert wait_for(lambda: shown()[-2:] == ["QT/talking", "QT/neutral"], 30), shown()
        finally:
            ros.close()
    finally:
        robot.stop()


@pytest.mark.slow
def test_a_clip_reaches_the_v3_robots_media_stream(servers, tmp_path):
    hub = FakeQtrobotV3().start()
    try:
        server = servers(backend="luxai", bystander_interval=0, robot_url=f"tcp://127.0.0.1:{hub.hub_port}",
                         camera_url=f"tcp://127.0.0.1:{hub.camera_port}", clips=tmp_path / "clips")
        ros = connect(server.port)
        try:
            assert add(ros, "hello", encoded("mp3", "libmp3lame"))["success"]
            reply = call(ros, names.CLIP_PLAY_SERVICE, "vr_teleop_msgs/ClipName", {"name": "hello"})
            assert reply["success"] and reply["message"].startswith("playing 'hello'"), reply
            assert wait_for(lambda: len(hub.audio) >= 0.9 * 16000 * 2, 30), len(hub.audio)
            assert set(hub.audio_frames) == {(1, 16000, 16)}
            heard = np.frombuffer(bytes(hub.audio), "<i2")
            assert abs(pitch(heard, 16000) - 440) < 10
            assert wait_for(lambda: hub.emotions[-2:] == ["QT/talking", "QT/neutral"], 30), hub.emotions
        finally:
            ros.close()
    finally:
        hub.stop()


def test_the_teacher_records_a_clip_from_her_voice_and_the_robot_does_not_play_it(sim):
    """The operator voice road (a client's AudioData at 48 kHz stereo, as its AudioInfo says) recorded from the
    speech menu's Record a clip: the first selection starts, the second keeps the clip, checked as any upload."""
    server, ros = sim
    robot = server.server.robot
    levels: list[float] = []
    reply = select(ros, "speech.record_clip")
    assert reply["success"] and reply["message"].startswith("recording your voice"), reply
    sender = VoiceSender(ros, tone(1.5, 48000, 2, amplitude=0.1), 48000, 2).start()
    while not sender.done.is_set():  # sampled while the voice comes: the mouth must stay shut
        levels.append(server.call(lambda: robot.voice_level))
    assert sender.done.wait(30)
    audio_dir = server.settings.audio_dir
    assert wait_for(lambda: len(logged(audio_dir)[2]) >= 1.5 * 48000 * 4, 30)  # every chunk has come
    reply = select(ros, "speech.record_clip")
    assert reply["success"], reply
    name = re.fullmatch(r"kept your 1\.5 s as clip '(recorded-\d{8}-\d{6})'", reply["message"])
    assert name, reply
    assert max(levels) == 0.0, "the robot played the voice being recorded"
    assert (server.settings.clips / f"{name[1]}.wav").exists()
    assert f"speech.clips.{name[1].replace('-', '_')}" in clip_items(ros)

    assert select(ros, "speech.record_clip")["success"]  # started again, and stopped with nothing said
    refused(select(ros, "speech.record_clip"), r"no voice came while recording")
