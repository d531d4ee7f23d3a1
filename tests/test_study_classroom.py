"""The classroom study (examples/classroom.yaml, `kind: classroom`): its measures against hand-computed lessons, a
bad file refused naming the field, the network profile's model on an in-process connection, and (slow) short
lessons of the three autonomy levels through `vr-teleop study run` in this process and on two Dask workers, giving
the same table for the same seed with the order the design gives (the teacher works most when teleoperating)."""

from __future__ import annotations

import asyncio
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
import simclock
import yaml
from client_protocol.vocabulary import Decider, Outcome
from netem.model import DirectionParams, Profile
from simclock import SimulatedClock

from vr_teleop_server.cli import main as cli_main
from vr_teleop_server.study.classroom_file import ClassroomStudy
from vr_teleop_server.study.metrics.classroom import ClassroomTimeline, OutcomeAt, Speech, classroom_metrics
from vr_teleop_server.study.network import RTO_MIN_S, ImpairedConnection
from vr_teleop_server.study.kinds import load_study
from vr_teleop_server.study.studyfile import StudyFileError

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "classroom.yaml"
VR_TELEOP = Path(sys.executable).parent / "vr-teleop"


# ---- the measures, on lessons built by hand ---------------------------------------------------------------------
def test_the_measures_of_a_hand_built_lesson():
    tl = ClassroomTimeline(
        lesson_s=60.0,
        speeches=[Speech("child_left", 10.0, 14.0, 30.0),  # looked at from 11.0 to the end: 1.0 s, 3 of 4 s
                  Speech("child_right", 20.0, 22.0, -30.0),  # never looked at
                  Speech("adult_centre", 58.0, 70.0, 0.0)],  # clipped at 60: looked at throughout (from before)
        heads=[(0.0, 0.0), (10.5, 15.0), (11.0, 29.0), (14.0, 30.0), (19.0, 0.0), (30.0, 0.0)],
        outcomes=[OutcomeAt(5.0, Outcome.ACCEPTED, "/rosbridge_websocket/client_2"),
                  OutcomeAt(6.0, Outcome.REJECTED, "/rosbridge_websocket/client_2"),
                  OutcomeAt(7.0, Outcome.FORBIDDEN, "/rosbridge_websocket/client_2"),
                  OutcomeAt(8.0, Outcome.TIMED_OUT_EXECUTED, Decider.TIMEOUT),
                  OutcomeAt(9.0, Outcome.ACCEPTED, Decider.AUTONOMY),
                  OutcomeAt(12.0, Outcome.TEACHER_INITIATED, "/rosbridge_websocket/client_2"),
                  OutcomeAt(13.0, Outcome.SUPERSEDED, Decider.SERVER),
                  OutcomeAt(61.0, Outcome.TEACHER_INITIATED, "/rosbridge_websocket/client_2")],  # after the lesson
        interventions=[21.0, 75.0])
    r = classroom_metrics(tl)
    assert r.speeches == 3 and r.never_looked_at == 1
    assert r.onset_to_look_mean_s == pytest.approx((1.0 + 0.0) / 2)
    assert r.onset_to_look_p95_s is None  # the 95th percentile of (1, never, 0) falls on the never
    assert r.share_attended == pytest.approx((3.0 + 0.0 + 2.0) / (4.0 + 2.0 + 2.0))
    assert (r.accepted, r.rejected, r.timed_out, r.robot_executed, r.superseded) == (1, 2, 1, 1, 1)
    assert (r.teacher_own, r.teacher_decisions, r.interventions) == (2, 3, 1)
    assert r.teacher_actions_per_min == pytest.approx(5 / 1.0)
    assert r.effectiveness == pytest.approx(2 / 3, abs=1e-4)  # kept to 4 decimals
    assert r.to_json_dict()["efficiency_s"] is None  # efficiency does not apply to a lesson


def test_a_lesson_where_every_pupil_is_looked_at_has_a_p95_and_nothing_of_the_teacher():
    tl = ClassroomTimeline(lesson_s=30.0,
                           speeches=[Speech("a", 1.0, 3.0, 20.0), Speech("b", 5.0, 6.0, 20.0)],
                           heads=[(0.0, 0.0), (1.5, 12.0), (2.0, 20.0), (10.0, 20.0)])
    r = classroom_metrics(tl)
    assert (r.onset_to_look_mean_s, r.onset_to_look_p95_s) == (pytest.approx(0.25), pytest.approx(0.5))
    assert r.share_attended == pytest.approx((1.5 + 1.0) / 3.0, abs=1e-4)
    assert r.teacher_actions_per_min == 0.0 and r.effectiveness == 1.0
    empty = classroom_metrics(ClassroomTimeline(lesson_s=30.0))
    assert (empty.speeches, empty.share_attended, empty.onset_to_look_mean_s, empty.effectiveness) == (0, None, None,
                                                                                                       None)


# ---- the file ---------------------------------------------------------------------------------------------------
def test_the_example_loads_as_a_classroom_study_with_the_three_levels():
    study = load_study(EXAMPLE)
    assert isinstance(study, ClassroomStudy)
    assert [c.autonomy for c in study.trials.values()] == ["teleoperated", "supervised", "autonomous"]


@pytest.mark.parametrize(("change", "named"), [
    (lambda d: d["teacher"].update(accept_probability=1.5), "teacher.accept_probability"),
    (lambda d: d["pupils"].update(speech_s=[4.0, 1.0]), "speech_s [4.0, 1.0] must be [min, max]"),
    (lambda d: d["pupils"].update(who=["child_left", "nobody"]), "nobody is not a pupil of the stand-in"),
    (lambda d: d["conditions"]["supervised"].update(autonomy="semi"), "conditions.supervised.autonomy"),
    (lambda d: d["teacher"].update(reaction=[0.1, 0.2]), "teacher.reaction"),
    (lambda d: d.update(kind="clasroom"), "kind: 'clasroom' is not a kind of study"),
])
def test_a_bad_classroom_file_is_refused_naming_the_field(tmp_path, capsys, change, named):
    doc = yaml.safe_load(EXAMPLE.read_text())
    change(doc)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(StudyFileError, match=named.replace("[", r"\[").replace("]", r"\]")):
        load_study(path)
    assert cli_main(["study", "run", str(path), "--all", "--speed", "max"]) == 2
    assert named in capsys.readouterr().err


def test_network_profiles_need_the_simulated_clock_and_a_known_name(tmp_path, capsys):
    assert cli_main(["study", "run", str(EXAMPLE), "--all", "--network", "lan"]) == 2
    assert "simulated clock only" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli_main(["study", "run", str(EXAMPLE), "--all", "--speed", "max", "--network", "lan,moon"])
    assert "unknown profile moon" in capsys.readouterr().err


# ---- the network profile on an in-process connection -------------------------------------------------------------
class Echo:
    """An in-process connection's shape (send, iterate, close) that answers each frame at once."""

    def __init__(self) -> None:
        self.got: list[tuple[float, str]] = []
        self.out: asyncio.Queue[str] = asyncio.Queue()
        self.clock: SimulatedClock | None = None

    async def send(self, frame: str) -> None:
        self.got.append((self.clock.monotonic(), frame))
        await self.out.put(frame)

    async def __aiter__(self):
        while True:
            yield await self.out.get()

    async def close(self) -> None:
        pass


def test_a_profile_delays_both_ways_in_order_and_a_lost_frame_comes_one_time_out_later():
    clock = SimulatedClock()
    lossy = DirectionParams(delay_ms=75.0, loss=0.3)
    profile = Profile("test", lossy, lossy)

    async def main() -> tuple[list[tuple[float, str]], list[tuple[float, str]], int, float]:
        echo = Echo()
        echo.clock = clock
        conn = ImpairedConnection(echo, profile, clock, seed=5)
        back: list[tuple[float, str]] = []

        async def read() -> None:
            async for frame in conn:
                back.append((clock.monotonic(), frame))

        reader = asyncio.ensure_future(read())
        start = clock.monotonic()
        for i in range(40):
            await conn.send(str(i))
            await asyncio.sleep(0.01)  # simulated time: the clock jumps to it
        while len(back) < 40:
            await asyncio.sleep(0.05)  # simulated time: the clock jumps to it
        reader.cancel()
        await conn.close()
        return [(t - start, f) for t, f in echo.got], [(t - start, f) for t, f in back], \
            conn.up.retransmitted + conn.down.retransmitted, start

    got, back, retransmitted, _ = simclock.run(main(), clock)
    assert [f for _, f in got] == [f for _, f in back] == [str(i) for i in range(40)]  # in order, none lost
    sent = {str(i): i * 0.01 for i in range(40)}
    arrived = {f: t for t, f in got}
    assert all(arrived[f] >= sent[f] + 0.075 - 1e-9 for f in sent)  # the one-way delay, at least
    assert all(t >= arrived[f] + 0.075 - 1e-9 for t, f in back)  # and again on the way back
    assert retransmitted > 0  # 30% loss over 80 frames: some were sent again...
    late = max(arrived[f] - sent[f] for f in sent)
    assert late >= 0.075 + RTO_MIN_S + 0.15 - 1e-9  # ...one time-out (RTO_MIN_S + the RTT) later at least


# ---- lessons on the stand-in (slow) -------------------------------------------------------------------------------
def short_lesson(tmp_path: Path) -> Path:
    """The example cut to a 12-second lesson with talkative pupils and a teacher who always answers, quickly, on
    modelled perception: these tests hold the table's shape, the workers and the network profiles, not what the
    head camera sees (tests/test_modelled_faces.py holds the modelled boxes to the detector's; the pilot's lessons,
    tests/test_study_pilot.py, are on rendered frames)."""
    doc = yaml.safe_load(EXAMPLE.read_text())
    doc["lesson_s"] = 12.0
    doc["perception"] = "modelled"
    doc["pupils"].update(speak_per_min=10.0, speech_s=[1.0, 2.5], look_away_per_min=0.0)
    doc["teacher"].update(respond_probability=1.0, answer_s=[0.3, 0.6], decide_s=[0.2, 0.6],
                          accept_probability=0.5, intervene_after_s=4.0)
    path = tmp_path / "short.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def vr_teleop(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(VR_TELEOP), *args], capture_output=True, text=True, timeout=1800, check=False)


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_the_three_levels_in_this_process_and_on_two_workers_give_one_table_in_the_design_s_order(tmp_path):
    study = short_lesson(tmp_path)
    out = {}
    for workers in ("1", "2"):
        proc = vr_teleop("study", "run", str(study), "--all", "--speed", "max", "--seed", "4", "--workers", workers,
                         "--record-dir", str(tmp_path / f"rec{workers}"), "--json", str(tmp_path / f"w{workers}.json"))
        assert proc.returncode == 0, proc.stdout + proc.stderr
        out[workers] = json.loads((tmp_path / f"w{workers}.json").read_text())
        assert sorted(p.name for p in (tmp_path / f"rec{workers}").iterdir()) == [
            "autonomous.mcap", "supervised.mcap", "teleoperated.mcap"]
        table = proc.stdout[proc.stdout.index("condition "):proc.stdout.index("wrote ")]
        out[f"table{workers}"] = table
    assert out["1"] == out["2"]  # the same seed gives the same lesson, metric for metric, wherever it ran
    assert out["table1"] == out["table2"]
    tele, sup, auto = (out["1"][c] for c in ("teleoperated", "supervised", "autonomous"))
    for m in (tele, sup, auto):
        assert m["outcome"] == "completed" and m["speeches"] >= 1 and m["lesson_s"] == 12.0
    # teleoperated: every answer is hers, no proposal is made; autonomous: the robot acts, she only steps in
    assert (tele["accepted"], tele["rejected"], tele["timed_out"], tele["robot_executed"]) == (0, 0, 0, 0)
    assert tele["teacher_own"] >= 1 and tele["interventions"] == 0
    assert auto["teacher_decisions"] == 0 and auto["teacher_own"] == auto["interventions"]
    assert auto["robot_executed"] >= 1
    assert tele["teacher_actions_per_min"] > auto["teacher_actions_per_min"]
    # supervised: the robot proposes and she decides (or lets them time out)
    assert sup["accepted"] + sup["rejected"] + sup["timed_out"] >= 1 and sup["robot_executed"] == 0
    assert sup["teacher_decisions"] == sup["accepted"] + sup["rejected"]
    for m in (tele, sup, auto):
        assert 0.0 <= m["share_attended"] <= 1.0 and m["onset_to_look_mean_s"] is not None
        assert math.isfinite(m["teacher_actions_per_min"])


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_network_profiles_are_a_factor_of_the_conditions(tmp_path):
    study = short_lesson(tmp_path)
    proc = vr_teleop("study", "run", str(study), "--condition", "supervised", "--speed", "max", "--seed", "2",
                     "--network", "lan,continent", "--record-dir", str(tmp_path / "rec"), "--json", "-")
    assert proc.returncode == 0, proc.stderr
    runs = json.loads(proc.stdout)
    assert list(runs) == ["supervised@lan", "supervised@continent"]
    assert [runs[k]["modules"] for k in runs] == [["supervised", "lan"], ["supervised", "continent"]]
    assert sorted(p.name for p in (tmp_path / "rec").iterdir()) == ["supervised@continent.mcap", "supervised@lan.mcap"]
    for m in runs.values():  # the teacher still decides through the profile's delays
        assert m["speeches"] >= 1 and m["accepted"] + m["rejected"] + m["timed_out"] >= 1


def test_a_teacher_action_that_is_no_menu_item_is_refused_when_the_lesson_starts(tmp_path, capsys):
    doc = yaml.safe_load(EXAMPLE.read_text())
    doc["teacher"]["actions"] = ["emotion.happy", "emotion.grumpy"]
    path = tmp_path / "grumpy.yaml"
    path.write_text(yaml.safe_dump(doc))
    assert cli_main(["study", "run", str(path), "--condition", "autonomous", "--speed", "max",
                     "--record-dir", str(tmp_path / "rec")]) == 2
    assert "teacher.actions: emotion.grumpy is not a menu item id" in capsys.readouterr().err
