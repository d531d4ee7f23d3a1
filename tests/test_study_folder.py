"""The study folder as the study's whole state: enrolment under pseudonyms, consent before a first trial, orders,
trials and their outcomes, deviations with reasons, questionnaires due and answered, the event log, a crash
(kill -9 of the process holding the folder) and the carrying on after it, and withdrawal."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

from vr_teleop_server.cli import main
from vr_teleop_server.questionnaires.instrument import PREFER_NOT, load_instrument
from vr_teleop_server.study.design import williams_rows
from vr_teleop_server.study.folder import LOG_FILE, FolderError, Refused, StudyFolder
from vr_teleop_server.study.protocol import ProtocolFields, StudyPlan

ROOT = Path(__file__).resolve().parent.parent
CONDITIONS = ("teleoperated", "supervised", "autonomous")
PROTOCOL = {
    "design": "within", "order": "latin", "consent_form": "v2 2026-11-01",
    "demographics": [{"id": "age_group", "question": "Your age", "choices": ["18-29", "30-44", "45+"]}],
    "questionnaires": {"before_first": [{"name": "qam", "phase": "expected"}],
                       "after_each": ["sus", {"name": "ssq", "who": "whoever wore the headset"}],
                       "after_last": [{"name": "qam", "phase": "perceived"}]},
}
FORM = PROTOCOL["consent_form"]


def plan(**changes) -> StudyPlan:
    return StudyPlan("classroom", CONDITIONS, 1, ProtocolFields.model_validate({**PROTOCOL, **changes}))


class Clock:
    """Each reading a second after the last: the log's times are checked exactly."""

    def __init__(self):
        self.t = datetime(2026, 11, 29, 9, 0, tzinfo=UTC)

    def __call__(self) -> datetime:
        self.t += timedelta(seconds=1)
        return self.t


@pytest.fixture
def folder(tmp_path):
    with StudyFolder.open(tmp_path / "study", plan(), clock=Clock()) as opened:
        yield opened


def sus_answers(value=3):
    return {f"Q{i}": value for i in range(1, 11)}


def log_of(folder) -> list[dict]:
    return [json.loads(line) for line in (folder.path / LOG_FILE).read_text().splitlines()]


def refused_and_unchanged(folder, call, match: str) -> None:
    before = (folder.path / LOG_FILE).read_bytes() if (folder.path / LOG_FILE).exists() else b""
    with pytest.raises(Refused, match=match):
        call()
    after = (folder.path / LOG_FILE).read_bytes() if (folder.path / LOG_FILE).exists() else b""
    assert after == before


def test_enrolment_gives_pseudonyms_and_latin_orders(folder):
    rows = williams_rows(3)
    people = [folder.enrol("experimenter", consent=True, consent_form=FORM) for _ in range(7)]
    assert [p.id for p in people] == [f"P0{i}" for i in range(1, 8)]
    assert [p.order for p in people] == [[CONDITIONS[c] for c in rows[i % 6]] for i in range(7)]
    assert people[0].consent == {"time": "2026-11-29T09:00:02.000+00:00", "form": FORM}
    assert folder.balance().startswith("unbalanced: 7 participants is not a multiple of the 6 rows")
    events = log_of(folder)
    assert [e["what"] for e in events[:2]] == ["enrol", "consent"]
    assert events[0] == {"seq": 1, "time": "2026-11-29T09:00:01.000+00:00", "who": "experimenter",
                         "what": "enrol", "participant": "P01", "index": 0, "group": "",
                         "order": ["teleoperated", "supervised", "autonomous"]}


def test_consent_is_needed_before_a_first_trial_on_the_studys_form(folder):
    p = folder.enrol("experimenter", consent=False)
    assert p.consent is None
    refused_and_unchanged(folder, lambda: folder.start_trial("experimenter", "P01"),
                          r"P01 has not consented: record their consent \(form v2 2026-11-01\)")
    refused_and_unchanged(folder, lambda: folder.give_consent("experimenter", "P01", "v1"),
                          r"consent form 'v1' is not the study's \('v2 2026-11-01'\)")
    refused_and_unchanged(folder, lambda: folder.enrol("experimenter", consent=True, consent_form=""),
                          "consent form '' is not the study's")
    folder.give_consent("experimenter", "P01", FORM)
    refused_and_unchanged(folder, lambda: folder.give_consent("experimenter", "P01", FORM), "consented already")
    trial = folder.start_trial("experimenter", "P01")
    assert (trial.condition, trial.position, trial.recording) == ("teleoperated", 1, "P01/teleoperated.mcap")


def test_trials_follow_the_order_and_a_deviation_needs_a_reason(folder):
    folder.enrol("experimenter", consent=True, consent_form=FORM)
    folder.enrol("experimenter", consent=True, consent_form=FORM)
    refused_and_unchanged(folder, lambda: folder.start_trial("experimenter", "P09"),
                          r"unknown participant 'P09' \(enrolled: P01, P02\)")
    folder.start_trial("experimenter", "P01")
    refused_and_unchanged(folder, lambda: folder.start_trial("experimenter", "P02"),
                          r"a trial is already running \(P01, teleoperated\): end it first")
    refused_and_unchanged(folder, lambda: folder.end_trial("experimenter", "finished"),
                          "outcome 'finished' is not one of completed, aborted")
    folder.end_trial("experimenter", "completed", note="went well")
    refused_and_unchanged(folder, lambda: folder.end_trial("experimenter", "completed"), "no trial is running")
    refused_and_unchanged(folder, lambda: folder.start_trial("experimenter", "P01", "autonomous"),
                          r"running autonomous now is a deviation \(the next in P01's order is supervised\): "
                          "give a reason")
    refused_and_unchanged(folder, lambda: folder.start_trial("experimenter", "P01", "lecture", reason="x"),
                          "'lecture' is not one of the study's conditions for P01")
    trial = folder.start_trial("experimenter", "P01", "autonomous", reason="the supervised menu was broken")
    assert trial.deviation == "the supervised menu was broken" and trial.position == 3
    start = log_of(folder)[-1]
    assert (start["what"], start["reason"], start["expected"]) == \
        ("trial_start", "the supervised menu was broken", "supervised")
    folder.end_trial("experimenter", "aborted", note="participant felt unwell")
    p1 = folder.participants["P01"]
    assert [(t.condition, t.outcome, t.note) for t in p1.trials] == [
        ("teleoperated", "completed", "went well"), ("autonomous", "aborted", "participant felt unwell")]
    assert p1.next_condition() == "supervised"
    folder.start_trial("experimenter", "P01")
    folder.note("experimenter", "pupil left the room")
    folder.end_trial("experimenter", "completed")
    refused_and_unchanged(folder, lambda: folder.start_trial("experimenter", "P01"),
                          "P01 has done every condition of their order")
    refused_and_unchanged(folder, lambda: folder.start_trial("experimenter", "P01", "teleoperated"),
                          r"a deviation \(already done \(completed\)\)")
    again = folder.start_trial("experimenter", "P01", "teleoperated", reason="the recording failed")
    assert again.recording == "P01/teleoperated-2.mcap"
    note = [e for e in log_of(folder) if e["what"] == "note"][0]
    assert (note["participant"], note["trial"], note["text"]) == ("P01", 3, "pupil left the room")


def test_questionnaires_are_due_by_the_plan_and_answers_checked(folder):
    folder.enrol("experimenter", consent=True, consent_form=FORM)
    assert [d.text() for d in folder.due("P01")] == ["qam (expected)"]
    qam = {f"P{i}": 3 for i in range(1, 34)} | {"P4": 80.5, "P5": 12, "P6": PREFER_NOT}
    assert folder.submit("participant", "P01", "qam", "", qam) == {}
    refused_and_unchanged(folder, lambda: folder.submit("participant", "P01", "sus", "teleoperated", sus_answers()),
                          r"sus after teleoperated is not due for P01 \(due now: nothing\)")
    folder.start_trial("experimenter", "P01")
    folder.end_trial("experimenter", "completed")
    assert [d.text() for d in folder.due("P01")] == ["sus after teleoperated",
                                                      "ssq after teleoperated [whoever wore the headset]"]
    refused_and_unchanged(folder, lambda: folder.submit("participant", "P01", "sus", "teleoperated",
                                                        sus_answers() | {"Q3": 9, "Q7": 0}),
                          "sus: Q3: 9 is outside its scale 1-5; Q7: 0 is outside its scale 1-5")
    assert folder.submit("participant", "P01", "sus", "teleoperated", sus_answers(4)) == {"sus": 50.0}
    ssq = {i.id: 0 for i in load_instrument("ssq").all_items} | {"nausea": 1}
    scores = folder.submit("participant", "P01", "ssq", "teleoperated", ssq)
    assert scores["ssq.nausea"] == pytest.approx(9.54) and scores["ssq"] == pytest.approx(2 * 3.74)
    assert folder.due("P01") == []
    for _ in range(2):
        folder.start_trial("experimenter", "P01")
        folder.end_trial("experimenter", "completed")
    assert [d.text() for d in folder.due("P01")][-1] == "qam (perceived)"
    answers = folder.participants["P01"].answers
    assert [(a.questionnaire, a.condition, a.phase) for a in answers] == [
        ("qam", None, "expected"), ("sus", "teleoperated", None), ("ssq", "teleoperated", None)]
    assert answers[0].answers["P6"] is None  # preferred not to answer, kept as such


def test_demographics_only_as_declared_in_bands(folder):
    folder.enrol("experimenter", consent=True, consent_form=FORM)
    refused_and_unchanged(folder, lambda: folder.set_demographics("participant", "P01", {"birth_date": "1990"}),
                          "birth_date: not a question of this study")
    refused_and_unchanged(folder, lambda: folder.set_demographics("participant", "P01", {"age_group": "33"}),
                          r"age_group: '33' is not one of its choices \(18-29, 30-44, 45\+\)")
    refused_and_unchanged(folder, lambda: folder.set_demographics("participant", "P01", {}),
                          'age_group: no answer .choose one, or "prefer_not_to_answer"')
    folder.set_demographics("participant", "P01", {"age_group": "30-44"})
    assert folder.participants["P01"].demographics == {"age_group": "30-44"}
    folder.enrol("experimenter", consent=True, consent_form=FORM)
    folder.set_demographics("participant", "P02", {"age_group": "prefer_not_to_answer"})  # declined, explicitly
    assert folder.participants["P02"].demographics == {"age_group": "prefer_not_to_answer"}


CRASHING = textwrap.dedent("""
    import sys
    from vr_teleop_server.study.folder import StudyFolder
    from vr_teleop_server.study.protocol import ProtocolFields, StudyPlan
    import json
    plan = StudyPlan("classroom", ("teleoperated", "supervised", "autonomous"), 1,
                     ProtocolFields.model_validate(json.loads(sys.argv[2])))
    folder = StudyFolder.open(sys.argv[1], plan)
    for _ in range(2):
        folder.enrol("experimenter", consent=True, consent_form=plan.protocol.consent_form)
    folder.start_trial("experimenter", "P02")
    folder.end_trial("experimenter", "completed")
    folder.start_trial("experimenter", "P02")
    (folder.path / "P02" / "autonomous.mcap").write_bytes(b"recorded so far")
    print("running", flush=True)
    sys.stdin.read()  # held here until killed
""")


def test_a_crash_mid_trial_loses_nothing_and_the_study_carries_on(tmp_path):
    path = tmp_path / "study"
    env = dict(os.environ, PYTHONPATH=f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    proc = subprocess.Popen([sys.executable, "-c", CRASHING, str(path), json.dumps(PROTOCOL)], env=env,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline() == "running\n"
        with pytest.raises(FolderError, match="open in another process"):
            StudyFolder.open(path, plan())  # the running process holds the folder
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=60)
    with (path / LOG_FILE).open("a") as handle:
        handle.write('{"seq": 99, "what": "enr')  # a line the crash cut in half
    with StudyFolder.open(path, plan(), who="server") as folder:
        p2 = folder.participants["P02"]
        assert p2.order == ["supervised", "autonomous", "teleoperated"]  # the order kept (row 2)
        assert [(t.condition, t.outcome) for t in p2.trials] == [("supervised", "completed"),
                                                                 ("autonomous", "interrupted")]
        assert folder.running is None
        assert (path / "P02" / "autonomous.mcap").read_bytes() == b"recorded so far"  # kept
        last = log_of(folder)[-1]
        assert (last["what"], last["who"], last["participant"], last["seq"]) == ("interrupted", "server", "P02", 8)
        again = folder.start_trial("experimenter", "P02")  # the interrupted condition is due again
        assert (again.condition, again.recording) == ("autonomous", "P02/autonomous-2.mcap")
        assert folder.enrol("experimenter", consent=False).id == "P03"


def test_a_folder_refuses_another_plan_and_a_log_edited_by_hand(tmp_path):
    StudyFolder.open(tmp_path / "s", plan()).close()
    with (tmp_path / "s" / LOG_FILE).open("a") as handle:
        handle.write('{"seq": 1, "what": "trial_end", "participant": "P01", "trial": 1}\n')
    with pytest.raises(FolderError, match=r"events.jsonl, line 1: not an event this tool wrote \(KeyError"):
        StudyFolder.open(tmp_path / "s", plan())
    (tmp_path / "s" / LOG_FILE).unlink()
    with pytest.raises(FolderError, match=r"another plan \(order latin, not random\)"):
        StudyFolder.open(tmp_path / "s", plan(order="random"))
    with pytest.raises(FolderError, match="declares no consent_form"):
        StudyFolder.open(tmp_path / "t", plan(consent_form=None))


def test_withdraw_deletes_the_data_and_keeps_the_fact(tmp_path, capsys):
    path = tmp_path / "study"
    with StudyFolder.open(path, plan(), clock=Clock()) as folder:
        for _ in range(3):
            folder.enrol("experimenter", consent=True, consent_form=FORM)
        folder.start_trial("experimenter", "P02")
        folder.note("experimenter", "P02 said something personal")
        folder.end_trial("experimenter", "completed")
        folder.submit("participant", "P02", "sus", CONDITIONS[1], sus_answers())
        (path / "P02" / "supervised.mcap").write_bytes(b"video")
    assert main(["study", "withdraw", str(path), "P02"]) == 0
    assert "P02 withdrawn" in capsys.readouterr().out
    assert not (path / "P02").exists()
    text = (path / LOG_FILE).read_text()
    events = [json.loads(line) for line in text.splitlines()]
    assert [e for e in events if e.get("participant") == "P02"] == [events[-1]]
    assert set(events[-1]) == {"seq", "time", "who", "what", "participant", "index"}
    assert events[-1]["what"] == "withdraw" and "personal" not in text
    assert main(["study", "withdraw", str(path), "P02"]) == 2
    assert "P02 withdrew at" in capsys.readouterr().err
    with StudyFolder.open(path, plan()) as folder:
        assert list(folder.participants) == ["P01", "P03"]
        assert folder.enrol("experimenter", consent=False).id == "P04"  # a pseudonym is never reused
        refused_and_unchanged(folder, lambda: folder.start_trial("experimenter", "P02"), "P02 withdrew at")
    assert main(["study", "withdraw", str(tmp_path / "nothing"), "P01"]) == 2
    assert "not a study folder" in capsys.readouterr().err


@pytest.mark.parametrize("order", ["random", "fixed"])
def test_between_subject_participants_get_one_condition_each_in_balance(tmp_path, order):
    with StudyFolder.open(tmp_path / "b", plan(design="between", order=order)) as folder:
        people = [folder.enrol("experimenter", consent=True, consent_form=FORM) for _ in range(6)]
        assert all(len(p.order) == 1 for p in people)
        assert sorted(p.order[0] for p in people) == sorted(CONDITIONS * 2)
        refused_and_unchanged(folder, lambda: folder.start_trial(
            "experimenter", "P01", next(c for c in CONDITIONS if c != people[0].order[0]), reason="r"),
            "is not one of their group's conditions for P01")


def test_the_session_shows_each_participants_order_progress_and_what_is_due(folder):
    folder.enrol("experimenter", consent=True, consent_form=FORM, group="teachers")
    folder.enrol("experimenter", consent=False)
    folder.start_trial("experimenter", "P01")
    session = folder.session()
    assert session["running"] == {"participant": "P01", "trial": 1, "condition": "teleoperated",
                                  "started": "2026-11-29T09:00:04.000+00:00", "recording": "P01/teleoperated.mcap"}
    folder.end_trial("experimenter", "completed")
    session = folder.session()
    assert session["running"] is None and session["conditions"] == list(CONDITIONS)
    assert session["participants"] == [
        {"id": "P01", "group": "teachers", "order": ["teleoperated", "supervised", "autonomous"], "consented": True,
         "done": ["teleoperated"], "next": "supervised",
         "due": ["qam (expected)", "sus after teleoperated", "ssq after teleoperated [whoever wore the headset]"]},
        {"id": "P02", "group": "", "order": ["supervised", "autonomous", "teleoperated"], "consented": False,
         "done": [], "next": "supervised", "due": ["qam (expected)"]}]
    assert session["balance"].startswith("unbalanced: 2 participants")
