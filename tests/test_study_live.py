"""The live study on a running server (`serve --study FILE --study-dir DIR`), over the real protocol with the
package's rosbridge client: the experimenter enrols with consent, starts the next trial (its condition set on the
server, its recording started), labels, notes and ends it; refused calls say why and change nothing; a participant's
token answers only their own questionnaires."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from client_protocol import names
from vr_teleop_server.client.rosbridge import Refused, RosbridgeError, connect
from vr_teleop_server.recording.format import read_recording
from vr_teleop_server.study.folder import StudyFolder

ROOT = Path(__file__).resolve().parent.parent
CLASSROOM = ROOT / "examples" / "classroom.yaml"
TOKENS = {"operator": "op-token-live-study", "supervisor": "sup-token-live-study"}
FORM = "classroom v1 2026-11"


@pytest.fixture(scope="module")
def live(module_servers, tmp_path_factory):
    folder = tmp_path_factory.mktemp("live_study") / "study"
    server = module_servers(backend="sim", study=CLASSROOM, study_dir=folder, record_camera_fps=0.0,
                            operator_token=TOKENS["operator"], supervisor_token=TOKENS["supervisor"],
                            bystander_interval=0.0)
    return server, folder


async def as_role(server, token: str):
    return await connect(f"{server.url}/?token={token}")


def events(folder: Path) -> list[dict]:
    return [json.loads(line) for line in (folder / "events.jsonl").read_text().splitlines()]


async def refused(client, service: str, args: dict) -> str:
    with pytest.raises(Refused) as caught:
        await client.call(service, args)
    return caught.value.message


def test_the_experimenter_runs_a_trial_and_refusals_change_nothing(live):
    server, folder = live

    async def main() -> None:
        sup = await as_role(server, TOKENS["supervisor"])
        op = await as_role(server, TOKENS["operator"])
        session = await sup.subscribe(names.STUDY_SESSION_TOPIC, "vr_teleop_msgs/StudySession")
        first = await session.next()
        assert first["study"] == "classroom" and first["kind"] == "classroom"
        assert first["conditions"] == ["teleoperated", "supervised", "autonomous"]
        logged = len(events(folder)) if (folder / "events.jsonl").exists() else 0

        # refusals: each names the problem, and the log does not grow
        assert "consent form 'v0'" in await refused(sup, names.STUDY_PARTICIPANT_ADD_SERVICE,
                                                    {"consent": True, "consent_form": "v0", "group": ""})
        assert "unknown participant 'P77'" in await refused(sup, names.STUDY_TRIAL_START_SERVICE,
                                                            {"participant": "P77", "condition": "", "reason": ""})
        with pytest.raises(Refused, match="only a supervisor"):  # the operator is not the experimenter
            await op.call(names.STUDY_PARTICIPANT_ADD_SERVICE, {"consent": True, "consent_form": FORM, "group": ""})
        assert (len(events(folder)) if (folder / "events.jsonl").exists() else 0) == logged

        added = await sup.call(names.STUDY_PARTICIPANT_ADD_SERVICE,
                               {"consent": True, "consent_form": FORM, "group": ""})
        pid, order = added["participant"], added["order"]
        assert pid.startswith("P") and sorted(order) == sorted(first["conditions"]) and added["token"]
        await session.next(lambda m: any(p["id"] == pid and p["consented"] for p in m["participants"]))

        other = next(c for c in order if c != order[0])
        assert "deviation" in await refused(sup, names.STUDY_TRIAL_START_SERVICE,
                                            {"participant": pid, "condition": other, "reason": ""})
        started = await sup.call(names.STUDY_TRIAL_START_SERVICE, {"participant": pid, "condition": "", "reason": ""})
        assert started["trial"] == 1
        running = await session.next(lambda m: m["running_participant"] == pid)
        assert running["running_condition"] == order[0]
        assert running["running_recording"] == f"{pid}/{order[0]}.mcap"
        # the condition is set on the live server: the classroom kind's autonomy level
        assert server.server.autonomy.level == order[0]
        assert "already running" in await refused(sup, names.STUDY_TRIAL_START_SERVICE,
                                                  {"participant": pid, "condition": "", "reason": ""})

        # the existing label services work on the live trial, and reach the event log
        await sup.call(names.STUDY_LABEL_START_SERVICE, {"action": "explain"})
        await sup.call(names.STUDY_LABEL_STOP_SERVICE, {"action": "explain"})
        await sup.call(names.STUDY_NOTE_SERVICE, {"text": "the participant asked to pause"})
        assert "empty note" in await refused(sup, names.STUDY_NOTE_SERVICE, {"text": "  "})

        assert "outcome 'done'" in await refused(sup, names.STUDY_TRIAL_END_SERVICE, {"outcome": "done", "note": ""})
        await sup.call(names.STUDY_TRIAL_END_SERVICE, {"outcome": "completed", "note": "fine"})
        ended = await session.next(lambda m: m["running_trial"] == 0)
        mine = next(p for p in ended["participants"] if p["id"] == pid)
        assert mine["done"] == [order[0]] and mine["next"] == order[1]
        assert any(d.startswith("sus after") for d in mine["due"]) and any(d.startswith("qam") for d in mine["due"])
        assert server.server.autonomy.level == "teleoperated"  # the level before the trial, back
        await sup.close()
        await op.close()

    asyncio.run(main())
    log = events(folder)
    whats = [e["what"] for e in log]
    assert whats[-7:] == ["enrol", "consent", "trial_start", "label", "label", "note", "trial_end"]
    assert all(e["who"].startswith("supervisor:") for e in log[-7:] if e["what"] != "label")
    start = next(e for e in log if e["what"] == "trial_start")
    recording = folder / start["recording"]
    topics = {m.topic for m in read_recording(recording)}
    assert names.STUDY_TRIAL_TOPIC in topics and names.STUDY_STATE_UPDATES_TOPIC in topics


def test_a_participant_token_answers_only_their_own_questionnaires(live):
    server, folder = live

    async def main() -> None:
        sup = await as_role(server, TOKENS["supervisor"])
        a = await sup.call(names.STUDY_PARTICIPANT_ADD_SERVICE, {"consent": True, "consent_form": FORM, "group": ""})
        b = await sup.call(names.STUDY_PARTICIPANT_ADD_SERVICE, {"consent": True, "consent_form": FORM, "group": ""})
        page = await as_role(server, a["token"])
        due = await page.call(names.STUDY_QUESTIONNAIRE_DUE_SERVICE, {})
        assert due["participant"] == a["participant"]
        listing = json.loads(due["due_json"])
        # the study file's demographic questions (in bands), then QAM's expected phase, before the first trial
        assert [d["questionnaire"] for d in listing] == ["demographics", "qam"]
        questions = {i["id"]: i["choices"] for i in listing[0]["blocks"][0]["items"]}
        assert "age_group" in questions
        assert "age_group: '33'" in await refused(page, names.STUDY_QUESTIONNAIRE_SUBMIT_SERVICE, {
            "questionnaire": "demographics", "condition": "", "answers_json": json.dumps(
                {**{q: c[0] for q, c in questions.items()}, "age_group": "33"})})
        await page.call(names.STUDY_QUESTIONNAIRE_SUBMIT_SERVICE, {
            "questionnaire": "demographics", "condition": "", "answers_json": json.dumps(
                {**{q: c[0] for q, c in questions.items()}, "age_group": "prefer_not_to_answer"})})
        items = [i["id"] for block in listing[1]["blocks"] for i in block["items"]]
        answers = {i: 3 for i in items}
        # out of its scale: refused naming the item, nothing taken
        message = await refused(page, names.STUDY_QUESTIONNAIRE_SUBMIT_SERVICE, {
            "questionnaire": "qam", "condition": "", "answers_json": json.dumps({**answers, items[0]: 99})})
        assert items[0] in message and "outside its scale" in message
        assert "not due" in await refused(page, names.STUDY_QUESTIONNAIRE_SUBMIT_SERVICE, {
            "questionnaire": "sus", "condition": "teleoperated", "answers_json": "{}"})
        await page.call(names.STUDY_QUESTIONNAIRE_SUBMIT_SERVICE, {
            "questionnaire": "qam", "condition": "", "answers_json": json.dumps(answers)})
        assert json.loads((await page.call(names.STUDY_QUESTIONNAIRE_DUE_SERVICE, {}))["due_json"]) == []

        # the other participant's questionnaires are untouched: a token answers for its own participant only
        other = await as_role(server, b["token"])
        theirs = await other.call(names.STUDY_QUESTIONNAIRE_DUE_SERVICE, {})
        assert theirs["participant"] == b["participant"]
        assert [d["questionnaire"] for d in json.loads(theirs["due_json"])] == ["demographics", "qam"]

        # every robot and experimenter service is refused to a participant's page
        for service, args in ((names.AUTONOMY_LEVEL_SERVICE, {"level": "autonomous"}),
                              (names.SPEECH_SAY_SERVICE, {"message": "hello"}),
                              (names.EMOTION_SHOW_SERVICE, {"name": "QT/happy"}),
                              (names.GESTURE_LIST_SERVICE, {}),
                              (names.STUDY_TRIAL_START_SERVICE, {"participant": b["participant"], "condition": "",
                                                                 "reason": ""}),
                              (names.STUDY_PARTICIPANT_ADD_SERVICE, {"consent": True, "consent_form": FORM,
                                                                     "group": ""})):
            with pytest.raises(RosbridgeError) as caught:  # in the response where its type has room for it
                await page.call(service, args)
            if caught.value.values != {"status": False}:  # QTrobot's own types: the reason is in a status op
                assert "role participant may not" in caught.value.message, caught.value
        # a supervisor's connection is nobody's page
        assert "only a participant's page" in await refused(sup, names.STUDY_QUESTIONNAIRE_SUBMIT_SERVICE, {
            "questionnaire": "qam", "condition": "", "answers_json": "{}"})
        for client in (sup, page, other):
            await client.close()

    asyncio.run(main())
    given = [e for e in events(folder) if e["what"] == "demographics"]
    assert len(given) == 1 and given[0]["values"]["age_group"] == "prefer_not_to_answer"
    answered = [e for e in events(folder) if e["what"] == "questionnaire"]
    assert len(answered) == 1 and answered[0]["who"] == f"participant:{answered[0]['participant']}"


@pytest.mark.parametrize(("settings", "problem"), [
    ({"study": CLASSROOM}, "--study FILE and --study-dir DIR go together"),
    ({"study": CLASSROOM, "study_dir": "DIR", "backend": "none"}, "give --backend sim, ros or luxai"),
    ({"study": ROOT / "nowhere.yaml", "study_dir": "DIR"}, "nowhere.yaml"),
])
def test_serve_refuses_a_study_it_cannot_host_naming_the_problem(tmp_path, settings, problem):
    from vr_teleop_server.app import TeleopServer
    from vr_teleop_server.settings import ServerSettings

    if settings.get("study_dir") == "DIR":
        settings = {**settings, "study_dir": tmp_path / "study"}
    with pytest.raises(ValueError, match=problem):
        TeleopServer(ServerSettings(port=0, **settings))
    assert not (tmp_path / "study").exists()  # nothing made


@pytest.mark.slow  # two server processes with the stand-in, one killed mid-trial
def test_a_kill_9_mid_trial_loses_nothing_and_a_restart_carries_on(tmp_path):
    """A real `vr-teleop serve --study` process killed with SIGKILL while a trial runs; the same folder again."""
    from testbed.processes import serve, stop
    from testbed.server import until

    folder = tmp_path / "study"
    args = ("--backend", "sim", "--study", str(CLASSROOM), "--study-dir", str(folder), "--record-camera-fps", "0",
            "--bystander-interval", "0", "--autonomy", "teleoperated")

    def trial_recorded(path: Path) -> bool:
        try:
            return any(m.topic == names.STUDY_TRIAL_TOPIC for m in read_recording(path))
        except Exception:  # nothing flushed yet
            return False

    async def before() -> tuple[str, list[str], Path]:
        client = await connect(proc.url)
        added = await client.call(names.STUDY_PARTICIPANT_ADD_SERVICE,
                                  {"consent": True, "consent_form": FORM, "group": ""})
        await client.call(names.STUDY_TRIAL_START_SERVICE, {"participant": added["participant"], "condition": "",
                                                            "reason": ""})
        recording = folder / added["participant"] / f"{added['order'][0]}.mcap"
        # the recorder flushes its chunks every half second: wait until the trial's start is on disk
        assert await until(lambda: trial_recorded(recording), 60)
        await client.close()
        return added["participant"], added["order"], recording

    proc = serve(*args)
    try:
        pid, order, recording = asyncio.run(before())
    finally:
        proc.kill()  # SIGKILL: no clean-up runs
        proc.wait(30)

    async def after() -> None:
        client = await connect(proc.url)
        session = await client.subscribe(names.STUDY_SESSION_TOPIC, "vr_teleop_msgs/StudySession")
        state = await session.next()
        assert state["running_trial"] == 0
        mine = next(p for p in state["participants"] if p["id"] == pid)
        assert mine["order"] == order and mine["consented"] and mine["done"] == [] and mine["next"] == order[0]
        again = await client.call(names.STUDY_TRIAL_START_SERVICE, {"participant": pid, "condition": "",
                                                                    "reason": ""})
        assert again["trial"] == 2
        running = await session.next(lambda m: m["running_trial"] == 2)
        assert running["running_recording"] == f"{pid}/{order[0]}-2.mcap"  # the interrupted one's is kept
        await client.call(names.STUDY_TRIAL_END_SERVICE, {"outcome": "completed", "note": ""})
        await client.close()

    proc = serve(*args)
    try:
        asyncio.run(after())
    finally:
        stop(proc)
    log = events(folder)
    interrupted = [e for e in log if e["what"] == "interrupted"]
    assert len(interrupted) == 1 and interrupted[0]["participant"] == pid and interrupted[0]["trial"] == 1
    assert [e["what"] for e in log if e["what"].startswith("trial")] == ["trial_start", "trial_start", "trial_end"]
    assert trial_recorded(recording)  # the cut recording is kept, readable
    assert StudyFolder.read(folder).participants[pid].trials[0].outcome == "interrupted"


def test_a_task_trial_runs_its_condition_modules_on_the_live_server(module_servers, tmp_path):
    """The task kind: the condition's perception, decision and motion modules on the server's robot; the
    Wizard-of-Oz and preempt services of /decision/* work on the live trial and reach the event log."""
    folder = tmp_path / "toolbox"
    server = module_servers(backend="sim", study=ROOT / "examples" / "toolbox.yaml", study_dir=folder,
                            record_camera_fps=0.0, bystander_interval=0.0)

    async def main() -> None:
        sup = await connect(server.url)
        added = await sup.call(names.STUDY_PARTICIPANT_ADD_SERVICE,
                               {"consent": True, "consent_form": "toolbox v1 2026-11", "group": ""})
        pid = added["participant"]
        reason = "" if added["order"][0] == "teleoperated" else "the static condition first: the markers are away"
        await sup.call(names.STUDY_TRIAL_START_SERVICE, {"participant": pid, "condition": "teleoperated",
                                                         "reason": reason})
        trial = await sup.subscribe(names.STUDY_TRIAL_TOPIC, "vr_teleop_msgs/TrialState")
        state = await trial.next(lambda m: m["state"] == "running", timeout=60)
        assert (state["trial"], state["decision"]) == ("teleoperated", "teleop")
        # a Wizard-of-Oz command the module refuses says why, in the response
        with pytest.raises(Refused, match="fly"):
            await sup.call(names.DECISION_TELEOP_SERVICE, {"object": "nothing", "action": "fly"})
        taken = await sup.call(names.DECISION_TELEOP_SERVICE, {"object": "bottom", "action": "pick"})
        assert "started" in taken["message"]
        await sup.call(names.DECISION_PREEMPT_SERVICE, {})
        await trial.next(lambda m: m["state"] == "preempted", timeout=60)
        await sup.call(names.STUDY_TRIAL_END_SERVICE, {"outcome": "aborted", "note": "preempted to test"})
        await sup.close()

    asyncio.run(main())
    log = events(folder)
    start = next(e for e in log if e["what"] == "trial_start")
    assert start["condition"] == "teleoperated"
    assert any(e["what"] == "preempt" and e["participant"] == start["participant"] for e in log)  # the fact
    commands = [(e["what"], e.get("action")) for e in log if e["who"].startswith("supervisor:")]  # who gave them
    assert ("wizard", "pick") in commands and ("preempt_command", None) in commands
    assert not any(e.get("action") == "fly" for e in log)  # a refused command is not taken
    assert log[-1]["what"] == "trial_end" and log[-1]["outcome"] == "aborted"
    topics = {m.topic for m in read_recording(folder / start["recording"])}
    assert names.STUDY_INTERVENTIONS_TOPIC in topics and names.STUDY_TRIAL_TOPIC in topics


@pytest.mark.parametrize("backend", ["ros", pytest.param("luxai", marks=pytest.mark.slow)])
def test_a_trial_is_hosted_on_a_real_robots_backend(servers, tmp_path, backend):
    """The same live trial on `--backend ros` (a ROS 1 QTrobot's rosbridge, testbed/ros1_rosbridge.py) and
    `--backend luxai` (a QTrobot v3's service hub, testbed/luxai_hub.py): the condition set, recorded, ended."""
    if backend == "ros":
        from testbed.ros1_rosbridge import Ros1QTrobot

        robot = Ros1QTrobot()
        settings = {"robot_url": robot.url}
    else:
        from testbed.luxai_hub import FakeQtrobotV3

        robot = FakeQtrobotV3().start()
        settings = {"robot_url": f"tcp://127.0.0.1:{robot.hub_port}",
                    "camera_url": f"tcp://127.0.0.1:{robot.camera_port}"}
    folder = tmp_path / "study"
    try:
        server = servers(backend=backend, study=CLASSROOM, study_dir=folder, record_camera_fps=0.0,
                         bystander_interval=0.0, **settings)

        async def main() -> None:
            sup = await connect(server.url)
            added = await sup.call(names.STUDY_PARTICIPANT_ADD_SERVICE,
                                   {"consent": True, "consent_form": FORM, "group": ""})
            await sup.call(names.STUDY_TRIAL_START_SERVICE, {"participant": added["participant"], "condition": "",
                                                             "reason": ""})
            assert server.server.autonomy.level == added["order"][0]
            await sup.call(names.STUDY_LABEL_ADD_SERVICE, {"agent": "human", "action": "answer", "start": 0.0,
                                                           "stop": 0.5})
            await sup.call(names.STUDY_TRIAL_END_SERVICE, {"outcome": "completed", "note": ""})
            await sup.close()

        asyncio.run(main())
        server.stop()
    finally:
        robot.stop()
    start = next(e for e in events(folder) if e["what"] == "trial_start")
    updates = [m for m in read_recording(folder / start["recording"]) if m.topic == names.STUDY_STATE_UPDATES_TOPIC]
    assert updates  # the label reached the trial's recording
    assert events(folder)[-1]["what"] == "trial_end"
