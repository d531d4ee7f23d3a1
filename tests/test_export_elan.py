"""`vr-teleop export elan`: a real session recorded on the stand-in (the camera watched, a pupil speaking, a
proposal accepted, a sentence said, the autonomy level changed) and a study trial recorded by `study run`, each
exported through the command line; the .eaf read back with pympi and the MP4 decoded with PyAV, against what the
recording holds."""

from __future__ import annotations

import base64
import os
import subprocess
import sys
from pathlib import Path

import av
import cv2
import numpy as np
import pympi
import pytest
import roslibpy
from support import Watch, call, wait_for

from client_protocol import names
from vr_teleop_server.recording.format import read_recording

WAIT = 30.0  # a failure bound on a loaded machine, never a measure
ROOT = Path(__file__).resolve().parent.parent
RULES = """
timeout_s: 10.0
on_timeout: execute
rules:
  - {id: cheer, when: speech_ended, min_speech_s: 0.2, action: emotion.happy, reason: a pupil spoke, confidence: 0.7}
"""


def export(recording: Path, out: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, "-m", "vr_teleop_server.cli", "export", "elan", str(recording),
                           "--out", str(out)], capture_output=True, text=True, env=env, timeout=300)


def annotations(eaf: pympi.Elan.Eaf, tier: str) -> list[tuple[int, int, str]]:
    return sorted((a, b, v) for a, b, v, *_ in eaf.get_annotation_data_for_tier(tier))


def ms(time_ns: int, zero_ns: int) -> int:
    return round((time_ns - zero_ns) / 1e6)


def test_a_live_session_exports_as_a_video_and_tiers_aligned_to_it(servers, tmp_path):
    rules = tmp_path / "rules.yaml"
    rules.write_text(RULES)
    path = tmp_path / "session.mcap"
    server = servers(backend="sim", autonomy="supervised", bystander_interval=0, camera_fps=10, record=path,
                     record_camera_fps=5, autonomy_rules=rules, autonomy_memory=tmp_path / "memory.json",
                     gesture_dir=tmp_path / "g", audio_dir=tmp_path / "a")
    ros = roslibpy.Ros(host="127.0.0.1", port=server.port)
    ros.run(timeout=10)
    try:
        camera = Watch(ros, names.CAMERA_TOPIC, "sensor_msgs/CompressedImage")
        pupils = Watch(ros, names.SIM_BYSTANDERS_TOPIC, "vr_teleop_msgs/Bystanders")
        proposals = Watch(ros, names.AUTONOMY_PROPOSALS_TOPIC, "vr_teleop_msgs/Proposal")
        outcomes = Watch(ros, names.AUTONOMY_OUTCOMES_TOPIC, "vr_teleop_msgs/ProposalOutcome")
        assert wait_for(lambda: len(camera.messages) >= 10, WAIT)  # the recorder keeps some at 5 fps
        assert call(ros, names.SIM_BYSTANDERS_SPEAK_SERVICE, "vr_teleop_msgs/BystanderSpeak",
                    {"who": "adult_centre", "text": "I think the answer is four."})["success"]
        assert wait_for(lambda: proposals.messages, WAIT)
        assert call(ros, names.AUTONOMY_DECIDE_SERVICE, "vr_teleop_msgs/DecideProposal",
                    {"id": proposals.messages[0]["id"], "decision": "accept"})["success"]
        assert wait_for(lambda: outcomes.messages, WAIT)
        call(ros, names.SPEECH_SAY_SERVICE, "qt_robot_interface/speech_say", {"message": "Well done, everyone."})
        assert call(ros, names.AUTONOMY_LEVEL_SERVICE, "vr_teleop_msgs/SetAutonomy",
                    {"level": "teleoperated"})["success"]
        seen = len(camera.messages)
        assert wait_for(lambda: len(camera.messages) >= seen + 10, WAIT)  # the last level on video too
        for watch in (camera, pupils, proposals, outcomes):
            watch.close()
    finally:
        ros.close()
        server.stop()

    held = list(read_recording(path))
    frames = [m for m in held if m.topic == names.CAMERA_TOPIC]
    zero = frames[0].time_ns
    done = export(path, tmp_path / "coded")
    assert done.returncode == 0, done.stderr
    assert f"{len(frames)} frames" in done.stdout and "session.eaf" in done.stdout, done.stdout

    eaf = pympi.Elan.Eaf(str(tmp_path / "coded" / "session.eaf"))
    media = eaf.media_descriptors[0]
    assert (media["MEDIA_URL"], media["RELATIVE_MEDIA_URL"], media["MIME_TYPE"]) == (
        "session.mp4", "./session.mp4", "video/mp4")
    assert set(eaf.get_tier_names()) == {"labels", "human actions", "robot actions", "proposals", "decisions",
                                         "pupils' speech", "teacher's speech", "autonomy level"}
    for tier in eaf.get_tier_names():
        assert all(0 <= a < b for a, b, _ in annotations(eaf, tier)), tier

    proposal = next(m for m in held if m.topic == names.AUTONOMY_PROPOSALS_TOPIC)
    outcome = next(m for m in held if m.topic == names.AUTONOMY_OUTCOMES_TOPIC)
    assert annotations(eaf, "proposals") == [(ms(proposal.time_ns, zero), ms(outcome.time_ns, zero),
                                              "emotion.happy (a pupil spoke)")]
    (start, _end, value), = annotations(eaf, "decisions")
    assert start == ms(outcome.time_ns, zero) and value.startswith("accepted emotion.happy by ")
    spoke = [m for m in held if m.topic == names.SIM_BYSTANDERS_TOPIC
             and any(b["speaking"] for b in m.data["bystanders"])]
    (start, end, who), = annotations(eaf, "pupils' speech")
    assert who == "adult_centre" and start == max(0, ms(spoke[0].time_ns, zero)) and end > start
    said = next(m for m in held if m.topic == "/rosbridge/in" and m.data.get("service") == names.SPEECH_SAY_SERVICE)
    (start, _end, text), = annotations(eaf, "teacher's speech")
    assert (start, text) == (ms(said.time_ns, zero), "Well done, everyone.")
    levels = [v for _a, _b, v in annotations(eaf, "autonomy level")]
    assert levels == ["supervised", "teleoperated"]

    with av.open(str(tmp_path / "coded" / "session.mp4")) as video:
        stream = video.streams.video[0]
        decoded = list(video.decode(stream))
    assert len(decoded) == len(frames)
    assert stream.codec_context.name == "h264"
    # each frame at its recorded time: the last one's timestamp is the recording's span of frames
    assert abs(float(decoded[-1].pts * decoded[-1].time_base) - (frames[-1].time_ns - zero) / 1e9) < 0.002
    # the first frame is the recorded JPEG's picture (H.264 is lossy: close, not equal)
    jpeg = cv2.imdecode(np.frombuffer(base64.b64decode(frames[0].data["data"]), np.uint8), cv2.IMREAD_COLOR)
    first = decoded[0].to_ndarray(format="bgr24")
    assert first.shape == (jpeg.shape[0] // 2 * 2, jpeg.shape[1] // 2 * 2, 3)
    assert np.abs(first.astype(float) - jpeg[:first.shape[0], :first.shape[1]]).mean() < 12 and first.std() > 5


def test_a_study_trial_without_camera_exports_its_actions_and_says_there_is_no_video(tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
           "MUJOCO_GL": "egl"}
    ran = subprocess.run([sys.executable, "-m", "vr_teleop_server.cli", "study", "run",
                          str(ROOT / "examples" / "toolbox.yaml"), "--trial", "teleoperated", "--speed", "max",
                          "--record-dir", str(tmp_path)], capture_output=True, text=True, env=env, timeout=600)
    assert ran.returncode == 0, ran.stderr
    path = tmp_path / "teleoperated.mcap"
    done = export(path, tmp_path / "coded")
    assert done.returncode == 0, done.stderr
    assert "no camera in this recording" in done.stdout
    assert not (tmp_path / "coded" / "teleoperated.mp4").exists()
    eaf = pympi.Elan.Eaf(str(tmp_path / "coded" / "teleoperated.eaf"))
    assert eaf.media_descriptors == []
    held = list(read_recording(path))
    zero = held[0].time_ns
    updates = [m for m in held if m.topic == names.STUDY_STATE_UPDATES_TOPIC]
    for agent, tier in (("human", "human actions"), ("robot", "robot actions")):
        began = {(m.data["trial"], m.data["id"]): m for m in reversed(updates) if m.data["agent"] == agent}
        got = annotations(eaf, tier)
        assert len(got) == len(began) > 0, tier
        assert sorted(a for a, _b, _v in got) == sorted(ms(m.time_ns, zero) for m in began.values())
        assert {v for _a, _b, v in got} == {m.data["action"] for m in began.values()}
        assert f"{tier:<18} {len(got)}" in done.stdout


@pytest.mark.parametrize("content, problem", [
    (None, "no such file"),
    (b"trial,agent\n1,human\n", "not an MCAP recording"),
    (b"\x89MCAP0\r\n", "holds no messages"),
])
def test_a_missing_foreign_or_cut_off_file_is_refused_with_the_reason(tmp_path, content, problem):
    path = tmp_path / "input.mcap"
    if content is not None:
        path.write_bytes(content)
    done = export(path, tmp_path / "coded")
    assert done.returncode == 2 and problem in done.stderr and str(path) in done.stderr, done.stderr
    assert "Traceback" not in done.stderr


def test_a_live_study_trial_exports_the_experimenters_labels(servers, tmp_path):
    import asyncio

    from vr_teleop_server.client.rosbridge import connect

    folder = tmp_path / "study"
    server = servers(backend="sim", study=ROOT / "examples" / "classroom.yaml", study_dir=folder,
                     record_camera_fps=5.0, camera_fps=10, supervisor_token="sup-token-elan", bystander_interval=0.0)

    async def main() -> str:
        sup = await connect(f"{server.url}/?token=sup-token-elan")
        added = await sup.call(names.STUDY_PARTICIPANT_ADD_SERVICE,
                               {"consent": True, "consent_form": "classroom v1 2026-11", "group": ""})
        await sup.call(names.STUDY_TRIAL_START_SERVICE, {"participant": added["participant"], "condition": "",
                                                          "reason": ""})
        camera = await sup.subscribe(names.CAMERA_TOPIC, "sensor_msgs/CompressedImage")
        for _ in range(10):  # frames, so that the recorder keeps some at its 5 fps before the labels
            await camera.next()
        await sup.call(names.STUDY_LABEL_START_SERVICE, {"action": "explain"})
        for _ in range(10):
            await camera.next()
        await sup.call(names.STUDY_LABEL_STOP_SERVICE, {"action": "explain"})
        await sup.call(names.STUDY_TRIAL_END_SERVICE, {"outcome": "completed", "note": ""})
        await sup.close()
        return f"{added['participant']}/{added['order'][0]}.mcap"

    recording = folder / asyncio.run(main())
    server.stop()
    held = list(read_recording(recording))
    frames = [m for m in held if m.topic == names.CAMERA_TOPIC]
    # the label services mark the human's action in the trial: its start and stop updates, from the experimenter
    labels = [m for m in held if m.topic == names.STUDY_STATE_UPDATES_TOPIC and m.data["source"] == "label"]
    assert frames and [m.data["finished"] for m in labels] == [False, True]
    done = export(recording, tmp_path / "coded")
    assert done.returncode == 0, done.stderr
    eaf = pympi.Elan.Eaf(str(tmp_path / "coded" / recording.with_suffix(".eaf").name))
    zero = frames[0].time_ns
    assert annotations(eaf, "labels") == [(ms(labels[0].time_ns, zero), ms(labels[1].time_ns, zero), "explain")]
    assert (ms(labels[0].time_ns, zero), ms(labels[1].time_ns, zero), "explain") in annotations(eaf, "human actions")
    levels = [v for _a, _b, v in annotations(eaf, "autonomy level")]
    assert levels and levels[0] == recording.stem  # the classroom's condition is its autonomy level
