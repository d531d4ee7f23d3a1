"""Implicit control end to end: every menu command through the protocol (roslibpy) against the MuJoCo stand-in."""

from __future__ import annotations

import asyncio
import base64
import json
import threading
import time
import wave
from pathlib import Path

import numpy as np
import pytest
import roslibpy

from sim.face import draw_face
from support import Headset, RawClient, Watch, call, engage, joints, refused, still, unity_yaw_pitch, wait_for
from vr_teleop_server.robot.gestures import parse_gesture_xml
from vr_teleop_server.features.speech import TextToSpeech


def select(ros: roslibpy.Ros, item: str, args: dict | None = None) -> dict:
    return call(ros, "/vr_teleop/menu/select", "vr_teleop_msgs/MenuSelect",
                {"id": item, "args": json.dumps(args) if args else ""})


@pytest.fixture
def menus(watch):
    w = watch("/vr_teleop/menus", "vr_teleop_msgs/Menus")
    assert wait_for(lambda: w.latest, 30)
    return w


@pytest.fixture
def events(watch):
    return watch("/vr_teleop/events", "vr_teleop_msgs/Event")


def test_menu_trees_arrive_latched_with_generated_items(menus):
    msg = menus.latest
    assert {m["id"]: m["controller"] for m in msg["menus"]} == {
        "emotion": "right", "motion": "right", "speech": "left", "status": "left"}
    items = {i["id"]: i for i in msg["items"]}
    assert items["status.hardware"]["slot"] == "left" and items["status.hardware"]["command"] == "show_status"
    assert json.loads(items["status.hardware"]["args"]) == {"which": "hardware"}
    wave_item = items["motion.play.list.wave"]
    assert wave_item["parent"] == "motion.play.list" and json.loads(wave_item["args"]) == {"name": "wave"}
    assert items["speech.sentences.well_done"]["command"] == "say"
    assert items["emotion.all.with_a_cold"]["command"] == "show_emotion"
    parents = {i["parent"] for i in msg["items"]}
    assert parents <= set(items) | {m["id"] for m in msg["menus"]}  # a well-formed forest


def test_selected_emotion_changes_the_face(sim_server, ros):
    standin = sim_server.server.robot.standin
    assert standin.emotion != "happy"
    reply = select(ros, "emotion.happy")  # an emotion that says no words (sad says "Oh no.": its mouth would move)
    assert reply["success"] and standin.emotion == "happy"
    assert standin.wait_face(30)  # drawn by the render process, at a low priority on a loaded machine
    face = standin.face_image()
    np.testing.assert_array_equal(face, draw_face("happy", face.shape[1], face.shape[0]))
    topic = roslibpy.Topic(ros, "/vr_teleop/menu/selection", "std_msgs/String")
    topic.publish(roslibpy.Message({"data": "emotion.all.with_a_cold"}))  # one that says nothing: the module's
    assert wait_for(lambda: standin.emotion == "with_a_cold", 30)  # speech test measures the robot's audio


def test_unknown_items_and_bad_args_get_clear_errors(sim_server, ros, events):
    refused(select(ros, "motion.fly"), "unknown menu item 'motion.fly'")
    refused(select(ros, "motion.play.list.wave", {"speed": 99}), "bad args for play_gesture: speed")
    refused(select(ros, "motion.play.list.wave", {"name": "moonwalk"}), "unknown gesture")
    assert wait_for(lambda: events.any(lambda e: e["kind"] == "menu_failed" and "moonwalk" in e["detail"]), 30)
    raw = RawClient(sim_server.url)
    try:
        raw.send({"op": "publish", "topic": "/vr_teleop/menu/selection", "msg": {"data": "no.such.item"}})
        status = raw.expect("status", level="error")
        assert "/vr_teleop/menu/selection" in status["msg"] and "no.such.item" in status["msg"]
        raw.alive()
    finally:
        raw.close()


def test_speech_sends_audio_whose_duration_matches_the_wav(sim_server, ros):
    text = "Well done!"
    tts = TextToSpeech()
    try:
        expected = asyncio.run(tts.render(text)).duration_s
    finally:
        tts.close()
    chunks = Watch(ros, "/vr_teleop/audio/robot", "audio_common_msgs/AudioData")
    info = Watch(ros, "/vr_teleop/audio/robot/info", "audio_common_msgs/AudioInfo")
    standin = sim_server.server.robot.standin
    talked = []
    t0 = time.monotonic()
    watcher = threading.Thread(target=lambda: talked.append(wait_for(standin.is_talking, 5)))
    watcher.start()
    reply = select(ros, "speech.sentences.well_done")
    elapsed = time.monotonic() - t0
    watcher.join()
    assert reply["success"] and talked == [True]
    assert elapsed >= expected * 0.9  # the reply comes once the robot has finished saying it
    assert wait_for(lambda: info.latest, 30)
    rate, width = info.latest["sample_rate"], int(info.latest["sample_format"][1:3]) // 8
    assert info.latest["sample_format"] == "S16LE" and info.latest["channels"] == 1
    def total() -> int:
        with chunks.lock:
            return sum(len(base64.b64decode(c["data"])) for c in chunks.messages)
    said = Path(sim_server.settings.audio_dir)
    with wave.open(str(sorted(said.glob("robot-*Well_done.wav"))[-1])) as w:  # the WAV the robot said
        pcm, wav_rate = w.readframes(w.getnframes()), w.getframerate()
    assert wav_rate == rate
    assert wait_for(lambda: total() == len(pcm), 30), (total(), len(pcm))
    with chunks.lock:
        assert b"".join(base64.b64decode(c["data"]) for c in chunks.messages) == pcm
    assert abs(len(pcm) / (rate * width) - expected) < 0.005  # espeak varies by a few samples between renders
    chunks.close()
    info.close()


def test_speech_can_be_stopped_and_configured(sim_server, ros):
    chunks = Watch(ros, "/vr_teleop/audio/robot", "audio_common_msgs/AudioData")
    js = Watch(ros, "/qt_robot/joints/state", "sensor_msgs/JointState")  # the robot's steady 30 Hz
    say = roslibpy.Topic(ros, "/qt_robot/speech/say", "std_msgs/String")
    say.publish(roslibpy.Message({"data": "This is a rather long sentence that the teacher will cut short, "
                                          "because the class already knows the answer to the question."}))
    standin = sim_server.server.robot.standin
    assert wait_for(standin.is_talking, 30)
    assert wait_for(lambda: len(chunks.messages) >= 3, 30)  # it has begun to speak
    assert select(ros, "speech.stop")["success"]
    assert wait_for(lambda: not standin.is_talking(), 30)
    still(lambda: True, js, 10)  # a chunk already on its way lands
    count = len(chunks.messages)
    # no audio after the stop, over a second of the robot's joint states (its steady stream), not a time window
    assert still(lambda: len(chunks.messages) == count, js, 30)
    js.close()
    assert count < 40  # the whole sentence is several seconds: 100 ms chunks
    assert select(ros, "speech.slower")["success"]
    assert call(ros, "/qt_robot/speech/config", "qt_robot_interface/speech_config",
                {"language": "fr", "pitch": 60, "speed": 100})["status"]
    # speech_config's response has only `status`: the reason goes to the caller as a status warning
    refused(call(ros, "/qt_robot/speech/config", "qt_robot_interface/speech_config", {"language": "klingon"}))
    call(ros, "/qt_robot/speech/config", "qt_robot_interface/speech_config", {"language": "en"})
    chunks.close()


def test_recorded_motion_saves_as_luxai_xml_and_replays_the_trajectory(sim_server, ros, menus):
    js = Watch(ros, "/qt_robot/joints/state", "sensor_msgs/JointState")
    recorder = sim_server.server.luxai.recorder
    headset = Headset(ros).start()
    try:
        engage(ros)
        assert select(ros, "motion.record", {"parts": ["head"], "name": "look_around"})["success"]
        for yaw in (0, 10, 20, 30, 20, 0, -15, -30, -15, 0):
            headset.head_orientation = unity_yaw_pitch(yaw)
            # Each pose held until the robot's head is there (not for a fixed time: a loaded machine is slower),
            # then for two of the recording's samples (20 a second), so that the recording holds the turn.
            assert wait_for(lambda yaw=yaw: abs(joints(js).get("HeadYaw", 99) - yaw) < 2.0, 30), yaw
            samples = recorder.sample_count
            assert wait_for(lambda: recorder.sample_count >= samples + 2, 30)
        reply = select(ros, "motion.record", {"parts": ["head"], "name": "look_around"})
        assert reply["message"] == "saved as look_around"
    finally:
        headset.stop()
    call(ros, "/vr_teleop/control/engage", "std_srvs/SetBool", {"data": False})
    path = Path(sim_server.settings.gesture_dir) / "look_around.xml"
    gesture = parse_gesture_xml(path, sim_server.server.model)  # LuxAI's format, read back
    recorded = np.array([[wp.time_s, wp.targets["HeadYaw"]] for wp in gesture.waypoints])
    assert recorded[:, 1].max() > 20 and recorded[:, 1].min() < -20
    assert wait_for(lambda: any(i["id"] == "motion.play.list.look_around" for i in menus.latest["items"]), 30)
    # Play it back from where the recording started, and compare the trajectory the robot follows.
    roslibpy.Topic(ros, "/qt_robot/head_position/command", "std_msgs/Float64MultiArray").publish(
        roslibpy.Message({"data": [float(recorded[0, 1]), 0.0]}))
    assert wait_for(lambda: abs(joints(js).get("HeadYaw", 99) - recorded[0, 1]) < 1.0, 30)
    # The joint states' own stamps (when the server sampled them), not their arrival: a loaded machine delays
    # the client, not the robot.
    with js.lock:
        first = len(js.messages)
    t0 = time.time()
    assert select(ros, "motion.play.list.look_around")["message"] == "played look_around"
    with js.lock:
        messages = js.messages[first:]
    played = np.array([(m["header"]["stamp"]["secs"] + m["header"]["stamp"]["nsecs"] * 1e-9 - t0,
                        dict(zip(m["name"], m["position"]))["HeadYaw"]) for m in messages])
    # The replay is the recording after a start delay (the menu call, the first command, the joint-state rate, and
    # whatever a loaded machine adds, unbounded): measured where the head first leaves its start, in both, then
    # refined around that. It never leads.
    def onset(track: np.ndarray) -> float:
        moving = np.abs(track[:, 1] - recorded[0, 1]) > 2.0
        assert moving.any(), "the head never left its start"
        return float(track[np.argmax(moving), 0])

    start_delay = onset(played) - onset(recorded)
    assert start_delay > -0.05, start_delay
    errors = []
    for lag in np.arange(max(0.0, start_delay - 0.5), start_delay + 0.5, 0.01):
        want = np.interp(played[:, 0] - lag, recorded[:, 0], recorded[:, 1])
        inside = (played[:, 0] - lag >= 0) & (played[:, 0] - lag <= recorded[-1, 0])
        errors.append(float(np.sqrt(np.mean((played[inside, 1] - want[inside]) ** 2))))
    assert min(errors) < 2.0, min(errors)  # degrees RMS: the trajectory's shape, whatever the delay
    js.close()


def test_motivation_crossing_its_limit_sends_the_event(ros, events):
    state = Watch(ros, "/vr_teleop/status/motivation", "vr_teleop_msgs/Motivation")
    call(ros, "/vr_teleop/motivation/reset", "vr_teleop_msgs/MotivationChange", {"name": ""})
    reply = call(ros, "/vr_teleop/motivation/set", "vr_teleop_msgs/MotivationChange",
                 {"name": "frustration", "value": 75})
    assert reply["value"] == 75
    assert select(ros, "status.motivation")["success"]
    call(ros, "/vr_teleop/motivation/increment", "vr_teleop_msgs/MotivationChange",
         {"name": "frustration", "value": 10})
    def frustration(kind: str, level: str | None = None) -> list[dict]:
        """The kind names the variable, as it always has (`frustration_high`); the detail's `variable` too."""
        return [e for e in events.messages if e["source"] == "motivation" and e["kind"] == kind
                and json.loads(e["detail"])["variable"] == "frustration" and level in (None, e["level"])]

    assert wait_for(lambda: frustration("frustration_high", "warning"), 30)
    detail = json.loads(frustration("frustration_high")[0]["detail"])
    assert detail["limit"] == 80 and detail["value"] >= 80 and detail["side"] == "high"
    assert wait_for(lambda: dict(zip(state.latest.get("name", []), state.latest.get("level", []))).get(
        "frustration") == "high", 30)
    reply = call(ros, "/vr_teleop/motivation/increment", "vr_teleop_msgs/MotivationChange",
                 {"name": "frustration", "value": 100})
    assert reply["value"] == 90 and "clamped" in reply["message"]
    assert wait_for(lambda: frustration("frustration_high", "danger"), 30)
    refused(call(ros, "/vr_teleop/motivation/set", "vr_teleop_msgs/MotivationChange",
                 {"name": "boredom", "value": 1}),
            "unknown motivation variable 'boredom'")
    call(ros, "/vr_teleop/motivation/reset", "vr_teleop_msgs/MotivationChange", {"name": "frustration"})
    assert wait_for(lambda: frustration("frustration_ok"), 30)
    state.close()


def test_status_panels_at_2_hz(sim_server, ros):
    motors = Watch(ros, "/vr_teleop/status/motors", "vr_teleop_msgs/MotorsStatus")
    hardware = Watch(ros, "/vr_teleop/status/hardware", "vr_teleop_msgs/HardwareStatus")
    dialog = Watch(ros, "/vr_teleop/status/dialog", "vr_teleop_msgs/DialogState")
    assert wait_for(lambda: len(motors.messages) >= 5, 30)
    with motors.lock:  # 2 Hz by the server's own stamps (what a loaded machine does to delivery does not count)
        stamps = [m["header"]["stamp"]["secs"] + m["header"]["stamp"]["nsecs"] / 1e9 for m in motors.messages]
    assert 0.35 <= float(np.median(np.diff(stamps))) <= 0.7, np.diff(stamps)
    m = motors.latest
    model = sim_server.server.model
    assert sorted(m["name"]) == sorted(model.names) and len(set(m["name"])) == len(m["name"])  # each motor once
    for name, pos, norm in zip(m["name"], m["position"], m["position_normalized"]):
        joint = model.joint(name)
        assert joint.lower < joint.upper and 0.0 <= norm <= 1.0
        assert abs(joint.lower + norm * (joint.upper - joint.lower) - pos) < 0.5
    assert set(m["mode"]) <= {"on", "off", "brake"}
    assert 0 <= hardware.latest["cpu_percent"] <= 100 * 64 and hardware.latest["memory_used_mb"] > 0
    roslibpy.Topic(ros, "/vr_teleop/dialog/update", "vr_teleop_msgs/DialogState").publish(roslibpy.Message({
        "question": "What colour is the sky?", "mode": "quiz", "answer": "blue", "candidates": ["blue", "green"],
        "optionals": [], "chosen": "blue"}))
    assert wait_for(lambda: dialog.latest.get("question") == "What colour is the sky?", 30)
    assert json.loads(select(ros, "status.dialog")["message"])["chosen"] == "blue"
    for w in (motors, hardware, dialog):
        w.close()


def test_operator_voice_is_logged_as_a_wav(sim_server, ros):
    topic = roslibpy.Topic(ros, "/vr_teleop/audio/operator", "audio_common_msgs/AudioData")
    tone = (np.sin(np.arange(16000) * 2 * np.pi * 440 / 16000) * 8000).astype("<i2").tobytes()
    for i in range(0, len(tone), 3200):  # 100 ms chunks at 16 kHz
        topic.publish(roslibpy.Message({"data": base64.b64encode(tone[i:i + 3200]).decode()}))
    audio_dir = Path(sim_server.settings.audio_dir)

    def logged() -> bytes:
        files = sorted(audio_dir.glob("operator-*.wav"))
        if not files:
            return b""
        try:
            with wave.open(str(files[-1])) as w:  # readable while the server still writes it
                return w.readframes(w.getnframes())
        except (EOFError, wave.Error):  # caught between the file's creation and its first header
            return b""
    assert wait_for(lambda: logged() == tone, 30)  # a generous bound: the server's loop is slow on a loaded machine


def test_head_and_arms_control_switches(ros):
    state = Watch(ros, "/vr_teleop/teleop_state", "vr_teleop_msgs/TeleopState")
    headset = Headset(ros).start()
    try:
        engage(ros)
        assert wait_for(lambda: state.latest.get("head_following"), 30)
        assert select(ros, "motion.head")["message"] == "head control off"
        assert wait_for(lambda: state.latest.get("engaged") and not state.latest.get("head_following"), 30)
        assert select(ros, "motion.head")["message"] == "head control on"
        assert wait_for(lambda: state.latest.get("head_following"), 30)
        assert select(ros, "motion.arms", {"enable": False})["message"] == "arms control off"
        headset.grips["right"] = 1.0
        headset.send_head_poses(45)  # half a second of the headset's frames with the grip held
        assert still(lambda: not state.latest["right_arm_following"], state)
        select(ros, "motion.arms", {"enable": True})
        assert select(ros, "motion.robot.release")["success"]
        assert wait_for(lambda: not state.latest.get("engaged"), 30)
    finally:
        headset.stop()
        state.close()


def test_one_voices_speed_and_pitch_do_not_leak_into_another():
    """espeak-ng's library keeps one set of parameters per process: each render runs its own espeak-ng with its own."""
    async def durations() -> tuple[float, float, float]:
        plain, configured = TextToSpeech(), TextToSpeech()
        try:
            before = (await plain.render("Well done!")).duration_s
            await configured.configure(speed=60, pitch=80)
            slow = (await configured.render("Well done!")).duration_s
            after = (await plain.render("Well done!")).duration_s
            return before, slow, after
        finally:
            plain.close()
            configured.close()

    before, slow, after = asyncio.run(durations())
    assert slow > 1.3 * before  # 60% of normal speed takes longer
    assert abs(after - before) < 0.005  # the other voice's settings did not carry over


def test_voices_render_whole_long_texts_side_by_side():
    """Each render is its own espeak-ng: a long text comes back whole, in its own voice, while another voice renders
    (pyttsx3's espeak driver, used before, could return before the WAV was written)."""
    sentence = "The class counts to ten together, and then the robot says well done to everyone."

    async def durations() -> tuple[float, list[float], list[float]]:
        plain, slow = TextToSpeech(), TextToSpeech()
        try:
            await slow.configure(speed=60)
            one = (await plain.render(sentence)).duration_s
            alone = [(await tts.render(" ".join([sentence] * 6))).duration_s for tts in (plain, slow)]
            together = await asyncio.gather(*(tts.render(" ".join([sentence] * 6)) for tts in (plain, slow)))
            return one, alone, [wav.duration_s for wav in together]
        finally:
            plain.close()
            slow.close()

    one, alone, together = asyncio.run(durations())
    assert alone[0] > 5 * one  # all six sentences were said
    assert alone[1] > 1.3 * alone[0]  # the slow voice stayed slow
    assert all(abs(a - b) < 0.005 for a, b in zip(alone, together))  # side by side as when alone
