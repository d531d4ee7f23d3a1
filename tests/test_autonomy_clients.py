"""Autonomy around a LuxAI API client (issue 39), over roslibpy on the stand-in at the default level (supervised)
with pupils speaking: a client's head command is held against a speaking pupil and given back after the grace; a
client's sentences are never cut by a proposal; proposals go only to an audience that can decide them; and face
detection never holds a camera frame back from a client.

What the server does is read from inside it in bus order (a tap, as the recorder taps the bus): who owned the head
or the voice when autonomy commanded it, when each proposal went out and ended.
"""

from __future__ import annotations

import os
import threading
import time

import pytest
import roslibpy
from support import Watch, call, joints, wait_for

from client_protocol import names
from sim.pupils import pupil
from vr_teleop_server.features.autonomy import AUTONOMY_NODE

RULES = """
timeout_s: 1.0
on_timeout: execute
rules:
  - {id: praise, when: speech_ended, min_speech_s: 0.2, action: speech.sentences.well_done, reason: a pupil spoke}
"""
WAIT = 60.0  # a failure bound on a loaded machine, never a measure
GRACE = 5.0  # the packaged client_grace_s
CLIENT_SENTENCE = "Hello class, today we count to ten."
PUPIL_SENTENCE = "I think the answer is four, because two and two make four."


class Log:
    """What the bus carries that these tests judge, in bus order, each with the server's clock and the owners of
    the head and the voice at that moment."""

    def __init__(self, server) -> None:
        self.server = server
        self.lock = threading.Lock()
        self.entries: list[dict] = []
        server.call(lambda: server.server.bus.taps.append(self._tap))

    def _tap(self, published) -> None:
        topic = published.topic
        if topic not in (names.HEAD_COMMAND_TOPIC, names.AUTONOMY_PROPOSALS_TOPIC, names.AUTONOMY_OUTCOMES_TOPIC,
                         names.CAMERA_TOPIC, names.FACES_TOPIC):
            return
        owners = self.server.server.owners
        entry = {"topic": topic, "sender": published.sender, "at": time.monotonic(), "head": owners.owner("head"),
                 "voice": owners.owner("voice"), "msg": published.data}
        with self.lock:
            self.entries.append(entry)

    def mark(self) -> int:
        with self.lock:
            return len(self.entries)

    def since(self, mark: int = 0, topic: str | None = None) -> list[dict]:
        with self.lock:
            return [e for e in self.entries[mark:] if topic is None or e["topic"] == topic]


@pytest.fixture(scope="module")
def server(module_servers, tmp_path_factory):
    rules = tmp_path_factory.mktemp("rules") / "rules.yaml"
    rules.write_text(RULES)
    running = module_servers(backend="sim", autonomy="supervised", bystander_interval=0, camera_fps=10,
                             autonomy_rules=rules)
    running.log = Log(running)
    return running


def client(server) -> roslibpy.Ros:
    ros = roslibpy.Ros(host="127.0.0.1", port=server.port)
    ros.run(timeout=10)
    return ros


@pytest.fixture
def api(server):
    """A client that uses LuxAI's API only (a QTrobot script): it watches no proposal and no autonomy state."""
    ros = client(server)
    yield ros
    ros.close()


def speak(ros, who: str, text: str = PUPIL_SENTENCE) -> None:
    reply = call(ros, names.SIM_BYSTANDERS_SPEAK_SERVICE, "vr_teleop_msgs/BystanderSpeak", {"who": who, "text": text})
    assert reply["success"], reply


def quiet(server) -> bool:
    return server.call(lambda: not server.server.bystanders.speaking)


def heard_end(server) -> object:
    """The last speech's end autonomy has taken (its situation, set whether or not it proposes), or None."""
    situation = server.call(lambda: server.server.autonomy._situation)
    return situation if situation is not None and situation[0].name == "speech_ended" else None


def test_a_head_command_is_held_against_a_speaking_pupil_and_given_back_after_the_grace(server, api):
    log = server.log
    state = Watch(api, names.JOINT_STATE_TOPIC, "sensor_msgs/JointState")
    head = roslibpy.Topic(api, names.HEAD_COMMAND_TOPIC, "std_msgs/Float64MultiArray")
    speaker = "child_right"  # on the other side from where the client puts the head
    assert pupil(speaker).yaw_deg < -10
    try:
        mark = log.mark()
        head.publish(roslibpy.Message({"data": [30.0, 10.0]}))
        assert wait_for(lambda: abs(joints(state).get("HeadYaw", 0) - 30) < 2
                        and abs(joints(state).get("HeadPitch", 0) - 10) < 2, WAIT), joints(state)
        speak(api, speaker)

        def span(samples: list[dict]) -> float:
            stamps = [m["header"]["stamp"]["secs"] + m["header"]["stamp"]["nsecs"] * 1e-9 for m in samples]
            return stamps[-1] - stamps[0] if stamps else 0.0

        # the head stays where the client put it for 4 s of the robot's own joint states, the pupil speaking
        start = len(state.messages)
        assert wait_for(lambda: span(state.messages[start:]) >= 4.0, WAIT)
        held = [dict(zip(m["name"], m["position"])) for m in state.messages[start:]]
        assert all(abs(j["HeadYaw"] - 30) <= 2 and abs(j["HeadPitch"] - 10) <= 2 for j in held), held[-1]
        # asked beyond the limit it is clamped, and still the client's
        head.publish(roslibpy.Message({"data": [170.0, 10.0]}))
        assert wait_for(lambda: abs(joints(state).get("HeadYaw", 0) - 60) < 2, WAIT), joints(state)
        assert wait_for(lambda: quiet(server), WAIT)
        assert wait_for(lambda: server.call(lambda: server.server.owners.free("head")), WAIT)  # the grace is over
        speak(api, speaker)  # the pupil again: autonomy turns to them
        assert wait_for(lambda: any(e["sender"] == AUTONOMY_NODE for e in log.since(mark, names.HEAD_COMMAND_TOPIC)),
                        WAIT)
        commands = log.since(mark, names.HEAD_COMMAND_TOPIC)
        mine = [e for e in commands if e["sender"] != AUTONOMY_NODE]
        autonomous = [e for e in commands if e["sender"] == AUTONOMY_NODE]
        assert len(mine) == 2 and mine[1]["head"] == "client"  # (a tap sees the owner before the command's claim)
        assert all(e["head"] == "none" for e in autonomous), autonomous[:3]
        assert autonomous[0]["at"] - mine[-1]["at"] >= GRACE  # not before the grace after the last command
        assert wait_for(lambda: pupil(speaker).yaw_deg - 10 <= joints(state)["HeadYaw"] <= pupil(speaker).yaw_deg + 10,
                        WAIT), joints(state)  # given back: the head turns to the pupil
        assert wait_for(lambda: quiet(server), WAIT)
    finally:
        head.unadvertise()
        state.close()


def test_no_proposal_to_an_api_client_alone_then_one_once_someone_watches(server, api):
    log = server.log
    mark = log.mark()
    situation = heard_end(server)
    speak(api, "adult_centre")
    assert wait_for(lambda: heard_end(server) is not situation, WAIT)  # the speech's end was taken
    assert not log.since(mark, names.AUTONOMY_PROPOSALS_TOPIC)  # nobody to decide: nothing proposed
    assert wait_for(lambda: quiet(server), WAIT)
    # the dashboard opens: it watches the autonomy state (the operator page's HUD does too)
    dashboard = client(server)
    watching = Watch(dashboard, names.AUTONOMY_STATE_TOPIC, "vr_teleop_msgs/AutonomyState")
    try:
        assert wait_for(lambda: watching.latest, WAIT)
        speak(api, "adult_centre")
        assert wait_for(lambda: log.since(mark, names.AUTONOMY_PROPOSALS_TOPIC), WAIT)
        assert wait_for(lambda: watching.any(lambda m: m["pending"]), WAIT)
        shown = next(m for m in watching.messages if m["pending"])["pending"][0]
        assert 0 < shown["left"] <= shown["timeout"]
        assert wait_for(lambda: log.since(mark, names.AUTONOMY_OUTCOMES_TOPIC), WAIT)
        assert wait_for(lambda: quiet(server), WAIT)
    finally:
        watching.close()
        dashboard.close()
    # the dashboard has gone: nothing is proposed any more
    assert wait_for(lambda: not server.call(server.server.autonomy.may_decide), WAIT)
    mark = log.mark()
    situation = heard_end(server)
    speak(api, "adult_centre")
    assert wait_for(lambda: heard_end(server) is not situation, WAIT)
    assert not log.since(mark, names.AUTONOMY_PROPOSALS_TOPIC)
    assert wait_for(lambda: quiet(server), WAIT)


@pytest.mark.slow  # ten sentences said one after another, in real time
def test_ten_sentences_in_a_row_are_never_cut_while_proposals_time_out(server, api):
    log = server.log
    teacher = client(server)  # an audience: proposals are made, and left alone they time out
    proposals = Watch(teacher, names.AUTONOMY_PROPOSALS_TOPIC, "vr_teleop_msgs/Proposal")
    state = Watch(teacher, names.AUTONOMY_STATE_TOPIC, "vr_teleop_msgs/AutonomyState")
    results: list[dict] = []

    def sentences() -> None:
        api_client = client(server)
        try:
            for _ in range(10):
                results.append(call(api_client, names.SPEECH_SAY_SERVICE, "qt_robot_interface/speech_say",
                                    {"message": CLIENT_SENTENCE}))
        finally:
            api_client.close()

    try:
        assert wait_for(lambda: server.call(server.server.autonomy.may_decide), WAIT)
        mark = log.mark()
        saying = threading.Thread(target=sentences)
        saying.start()
        assert wait_for(lambda: server.call(lambda: server.server.owners.owner("voice")) == "client", WAIT)
        for who in ("child_left", "child_right"):  # pupils speak while the client does: proposals come and wait
            speak(teacher, who, "Yes.")
            assert wait_for(lambda: quiet(server), WAIT)
        saying.join(300)
        assert not saying.is_alive()
        assert [r["status"] for r in results] == [True] * 10, results
        assert proposals.messages  # proposals were made meanwhile
        # a proposal's time-out came while the client spoke: it waited (left 0), it did not speak over the client
        assert state.any(lambda m: any(p["left"] == 0 for p in m["pending"]))
        ends = log.since(mark, names.AUTONOMY_OUTCOMES_TOPIC)
        assert not [e for e in ends if e["msg"]["outcome"] == "timed_out_executed" and e["voice"] != "none"], ends
        assert all(e["msg"]["seconds"] >= 1.0 for e in ends if e["msg"]["outcome"] == "superseded"), ends
        # once the client is done (and its grace), the waiting proposal is done
        assert wait_for(lambda: any(e["msg"]["outcome"] == "timed_out_executed"
                                    for e in log.since(mark, names.AUTONOMY_OUTCOMES_TOPIC)), WAIT)
    finally:
        proposals.close()
        state.close()
        teacher.close()


@pytest.mark.slow  # rendered frames searched for faces in a thread at the lowest priority, five of them
def test_face_detection_never_holds_a_camera_frame_back(server, api):
    """Attention's face detection takes the frames the camera makes for the client, in a thread of its own at the
    lowest priority: every frame it searched had already gone to the client's topic, and frames kept going out
    while it searched (the bench measures the rate: bench/autonomy.py --camera)."""
    log = server.log
    mark = log.mark()
    camera = roslibpy.Topic(api, names.CAMERA_TOPIC, "sensor_msgs/CompressedImage")
    got: list[int] = []
    camera.subscribe(lambda m: got.append(m["header"]["seq"]))
    try:
        def searched() -> list[dict]:
            return log.since(mark, names.FACES_TOPIC)
        assert wait_for(lambda: len([e for e in searched() if e["msg"]["frame_seq"] >= min(got, default=1e12)]) >= 5,
                        WAIT)
        entries = log.since(mark)
        published = {}  # frame seq -> where in bus order it went to the camera topic
        for i, e in enumerate(entries):
            if e["topic"] == names.CAMERA_TOPIC:
                published.setdefault(e["msg"]["header"]["seq"], i)
        judged = overlapped = 0
        for i, e in enumerate(entries):
            seq = e["msg"]["frame_seq"] if e["topic"] == names.FACES_TOPIC else None
            if seq not in published:  # searched before the client watched, or a frame a loaded loop skipped
                continue
            assert published[seq] < i, seq  # the frame went to the client before its search ended, not after
            judged += 1
            overlapped += any(s > seq for s, j in published.items() if published[seq] < j < i)
        assert judged >= 3, (judged, len(searched()))
        assert overlapped, "no frame went to the client while a search ran"
    finally:
        camera.unsubscribe()
    # the thread detection runs in is at the lowest priority
    threads = [t for t in threading.enumerate() if t.name.startswith("faces")]
    assert threads and all(os.getpriority(os.PRIO_PROCESS, t.native_id) == 19 for t in threads)
