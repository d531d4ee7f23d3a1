"""QAM's objective items in `vr-teleop study report`: live trials recorded by a pilot (the live study's own road),
then the report's `qam.P1` ... `qam.P6` checked against values computed here from the same MCAP files, read with
the mcap library directly; and a recording without a topic an item needs, reported missing with the reason."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

# pilots of whole lessons in subprocesses: seconds idle, minutes on a loaded machine (the timeout only catches a hang)
pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]
ROOT = Path(__file__).resolve().parent.parent
CLI = [sys.executable, "-m", "vr_teleop_server.cli", "study"]
ITEMS = [f"qam.P{i}" for i in range(1, 7)]
OUTCOMES, BYSTANDERS, EVENTS = "/vr_teleop/autonomy/outcomes", "/sim/bystanders", "/vr_teleop/events"
JOINTS, TRIAL, UPDATES, INTERVENTIONS = "/qt_robot/joints/state", "/study/trial", "/study/state_updates", \
    "/study/interventions"


def pilot(tmp: Path, example: str, participants: int, edit=lambda text: text) -> Path:
    study = tmp / f"{example}.yaml"
    study.write_text(edit((ROOT / "examples" / f"{example}.yaml").read_text()))
    folder = tmp / "study"
    done = subprocess.run([*CLI, "pilot", str(study), "--study-dir", str(folder), "--participants", str(participants),
                           "--speed", "max", "--seed", "3"], capture_output=True, text=True, cwd=ROOT, timeout=900)
    assert done.returncode == 0, done.stderr
    return folder


def report(folder: Path, out: Path) -> tuple[pd.DataFrame, dict]:
    done = subprocess.run([*CLI, "report", str(folder), "--csv", str(out / "long.csv"), "--json", str(out / "r.json")],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "== qam.P4 == (measured from the trial recordings, not answered)" in done.stdout
    frame = pd.read_csv(out / "long.csv", keep_default_na=False, na_values=[""])
    return frame[frame["measure"].isin(ITEMS)], json.loads((out / "r.json").read_text())


def messages(path: Path):
    """(seconds, topic, message) in log order, straight from the MCAP file."""
    with path.open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=True):
            yield message.log_time * 1e-9, channel.topic, json.loads(message.data)


def classroom_expected(path: Path) -> dict[str, float | None]:
    """P1, P2, P4, P5 of a lesson: who initiated; speeches looked at within 5 s (10 degrees of the speaker)."""
    robot = teacher = 0
    level, start, last = "", None, 0.0
    heads: list[tuple[float, float]] = []
    speaking: dict[str, tuple[float, float]] = {}
    speeches: list[tuple[float, float, float]] = []
    for t, topic, m in messages(path):
        last = t
        if topic == OUTCOMES:
            robot += m["initiator"] == "robot" and m["decided_by"] != "autonomy"
            teacher += m["outcome"] == "teacher_initiated"
        elif topic == EVENTS and m["kind"] == "autonomy_level":
            detail = json.loads(m["detail"])
            level = detail["level"]
            start = t if start is None and detail["by"] not in ("", "server") else start
        elif topic == EVENTS and m["kind"] == "engage" and m["source"] == "teleop":
            teacher += start is not None and level != "teleoperated"
        elif topic == JOINTS:
            heads.append((t, m["position"][m["name"].index("HeadYaw")]))
        elif topic == BYSTANDERS:
            for b in m["bystanders"]:
                if b["speaking"] and b["name"] not in speaking:
                    speaking[b["name"]] = (t, b["yaw"])
                elif not b["speaking"] and b["name"] in speaking:
                    onset, yaw = speaking.pop(b["name"])
                    speeches.append((onset, t, yaw))
    speeches += [(onset, last, yaw) for onset, yaw in speaking.values()]
    latencies = []
    for onset, end, yaw in speeches:
        if end <= onset:
            continue
        before = [y for t, y in heads if t <= onset]
        if before and abs(before[-1] - yaw) <= 10:
            latencies.append(0.0)
            continue
        near = [t for t, y in heads if onset <= t <= onset + 5 and abs(y - yaw) <= 10]
        latencies.append(near[0] - onset if near else math.inf)
    looked = [x for x in latencies if math.isfinite(x)]
    total = robot + teacher
    return {"qam.P1": 100 * robot / total if total else None, "qam.P2": 100 * teacher / total if total else None,
            "qam.P4": 100 * len(looked) / len(latencies) if latencies else None,
            "qam.P5": sum(looked) / len(looked) if looked else None}


def task_expected(path: Path) -> dict[str, float | None]:
    """P4, P5, P6 of a task trial: the plan's robot subtasks, those intervened on, those finished, the time."""
    final, finished, intervened = None, set(), []
    for _, topic, m in messages(path):
        if topic == TRIAL and m["state"] in ("completed", "preempted", "failed"):
            final = m
        elif topic == UPDATES and m["agent"] == "robot" and m["finished"]:
            finished.add(m["id"])
        elif topic == INTERVENTIONS:  # interventions naming the same subtask count once, unnamed ones each
            intervened.append(m["subtask"] or object())
    planned = final["planned_subtasks"]
    return {"qam.P4": 100 * (1 - len(set(intervened)) / planned), "qam.P5": final["elapsed"] / len(finished),
            "qam.P6": 100 * min(len(finished), planned) / planned}


def check(rows: pd.DataFrame, folder: Path, expected_of) -> int:
    """Every row with an independent value equals it; one without is missing with a reason. The values compared."""
    compared = 0
    computed: dict[Path, dict[str, float | None]] = {}
    for row in rows.itertuples():
        assert row.source == "measured" and row.note.startswith(f"{row.participant}/{row.condition}.mcap: ")
        path = folder / row.participant / f"{row.condition}.mcap"
        expected = computed[path] = computed.get(path) or expected_of(path)
        if row.measure not in expected:
            continue
        if expected[row.measure] is None:
            assert pd.isna(row.value), row
        else:
            assert row.value == pytest.approx(expected[row.measure], abs=1e-3), row
            compared += 1
    return compared


@pytest.fixture(scope="module")
def classroom(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("classroom")
    # ten-second lessons in which the pupils speak often enough that every lesson has speeches to attend to
    return pilot(tmp, "classroom", 2, lambda text: text.replace("lesson_s: 180", "lesson_s: 10")
                 .replace("speak_per_min: 2.0", "speak_per_min: 12.0"))


def test_a_lessons_qam_items_are_those_its_recording_holds(classroom, tmp_path):
    rows, document = report(classroom, tmp_path)
    assert len(rows) == 2 * 3 * 6  # every participant, condition and item: present or missing with its reason
    assert check(rows, classroom, classroom_expected) >= 8  # not vacuous: most trials gave P1, P2, P4 and P5
    p3 = rows[rows["measure"] == "qam.P3"]
    assert p3["value"].isna().all() and p3["note"].str.contains("judgement no recording holds").all()
    measures = {m["measure"]: m for m in document["measures"]}
    assert all(measures[item]["source"] == "measured" for item in ITEMS)
    assert measures["trial.duration_s"]["source"] == "event log" and measures["sus"]["source"] == "answered"
    assert sorted((v["participant"], v["condition"], v["measure"]) for v in document["measured"]) \
        == sorted(zip(rows["participant"], rows["condition"], rows["measure"]))  # each trial's values in the JSON
    assert {v["unit"] for v in document["measured"] if v["measure"] == "qam.P5"} == {"seconds per completed task"}
    for item in ITEMS:  # the JSON counts each missing value, and says why
        missing = rows[(rows["measure"] == item) & rows["value"].isna()]
        assert sum(measures[item]["missing"].values()) == len(missing)
        assert sorted((g["participant"], g["condition"], g["reason"]) for g in measures[item]["missing_reasons"]) \
            == sorted(zip(missing["participant"], missing["condition"], missing["note"]))


def test_each_trials_recording_opens_with_the_state_and_holds_none_of_the_previous_trial(classroom, tmp_path):
    """A trial after the first starts its recording on a running server: it opens with the state topics' last
    messages (who is in the classroom, before the trial's own first state), and the previous trial's /study/trial
    (history) is not in it; so every completed trial has P4-P6 from its own recording."""
    log = [json.loads(line) for line in (classroom / "events.jsonl").read_text().splitlines()]
    later = 0
    for enrol in (e for e in log if e["what"] == "enrol"):
        for condition in enrol["order"]:
            first: dict[str, float] = {}
            trials = []
            for t, topic, m in messages(classroom / enrol["participant"] / f"{condition}.mcap"):
                first.setdefault(topic, t)
                if topic == TRIAL:
                    trials.append(m["trial"])
            assert first[BYSTANDERS] <= first[TRIAL], (enrol["participant"], condition)
            assert trials and set(trials) == {condition}, (enrol["participant"], condition, set(trials))
            later += condition != enrol["order"][0]
    assert later == 2 * 2  # two participants' second and third trials
    rows, _ = report(classroom, tmp_path)
    completed = {(e["participant"], e["condition"]) for e in log if e["what"] == "trial_end"
                 and e["outcome"] == "completed"}
    assert len(completed) == 2 * 3
    measured = rows[rows["measure"].isin(["qam.P4", "qam.P5", "qam.P6"])]
    assert {(r.participant, r.condition) for r in measured.itertuples()} == completed
    assert measured["value"].notna().all(), measured[measured["value"].isna()]["note"].tolist()


def test_a_recording_without_a_topic_says_so(classroom, tmp_path):
    folder = tmp_path / "study"
    shutil.copytree(classroom, folder)
    path = folder / "P01" / "teleoperated.mcap"
    with (classroom / "P01" / "teleoperated.mcap").open("rb") as f, path.open("wb") as out:
        writer = Writer(out)
        writer.start()
        channels: dict[int, int] = {}
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            if channel.topic in (OUTCOMES, BYSTANDERS):
                continue
            if channel.id not in channels:
                sid = writer.register_schema(schema.name, schema.encoding, schema.data)
                channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding, sid,
                                                               channel.metadata)
            writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time)
        writer.finish()
    rows, document = report(folder, tmp_path)
    mine = rows[(rows["participant"] == "P01") & (rows["condition"] == "teleoperated")].set_index("measure")
    assert mine["value"].isna().all()
    for item in ("qam.P1", "qam.P2"):
        assert mine.loc[item, "note"] == ("P01/teleoperated.mcap: the recording has no /vr_teleop/autonomy/outcomes "
                                          "(the robot's proposals and the teacher's own actions)")
    for item in ("qam.P4", "qam.P5", "qam.P6"):
        assert mine.loc[item, "note"] == "P01/teleoperated.mcap: the recording has no /sim/bystanders (who speaks when)"
    p1 = next(m for m in document["measures"] if m["measure"] == "qam.P1")
    assert {"participant": "P01", "condition": "teleoperated", "reason": mine.loc["qam.P1", "note"]} \
        in p1["missing_reasons"]
    assert p1["missing"]["teleoperated"] >= 1


def test_a_task_trials_qam_items_are_those_its_recording_holds(tmp_path):
    folder = pilot(tmp_path, "toolbox", 1)
    rows, _ = report(folder, tmp_path)
    assert len(rows) == 3 * 6
    assert check(rows, folder, task_expected) == 3 * 3  # P4, P5 and P6 of each condition
    assert rows[rows["measure"] == "qam.P1"]["note"].str.contains("no way to ask for assistance").all()
