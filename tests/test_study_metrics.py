"""Fluency metrics: hand-computed interval sets, properties, live == batch, readers, CLI and the Gantt chart."""

from __future__ import annotations

import itertools
import json
import os
import struct
import subprocess
import sys
from fractions import Fraction
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from vr_teleop_server import cli as main_cli
from vr_teleop_server.study.metrics import (
    Intervention,
    LiveMetrics,
    MetricsInputError,
    StateUpdate,
    compute_metrics,
    read_interventions,
    read_trial,
)
from vr_teleop_server.study.metrics import intervals
from vr_teleop_server.study.metrics.gantt import plot_gantt

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "fluency_example.csv"
EXAMPLE_INTERVENTIONS = REPO / "examples" / "fluency_example_interventions.csv"
VR_TELEOP = Path(sys.executable).parent / "vr-teleop"
JSON_KEYS = {"h_idle", "r_idle", "c_act", "f_del", "both_idle", "efficiency_s", "counts", "t0", "t1", "unfinished"}


def up(agent: str, action: str, start: float, stop: float | None) -> StateUpdate:
    return StateUpdate(agent=agent, action=action, start=start, stop=stop)


# ---- model ---------------------------------------------------------------------------------------------


def test_state_update_validation() -> None:
    assert up("human", "wait", 3.0, 3.0).stop == 3.0  # zero length is allowed
    assert up("robot", "hold", 3.0, None).finished is False
    with pytest.raises(ValidationError, match="stop .* is before start"):
        up("human", "take", 5.0, 4.0)
    with pytest.raises(ValidationError, match="'human' or 'robot'"):
        up("experimenter", "take", 0.0, 1.0)
    with pytest.raises(ValidationError):
        StateUpdate(agent="human", action="take", start="1.0", stop=2.0)  # type: ignore[arg-type]
    with pytest.raises(ValidationError):
        up("human", "take", float("nan"), 2.0)
    with pytest.raises(ValidationError):
        up("human", "", 0.0, 2.0)


# ---- interval arithmetic ---------------------------------------------------------------------------------


def test_interval_primitives() -> None:
    assert intervals.union([(5, 7), (0, 2), (1, 3), (3, 4), (6, 6)]) == [(0, 4), (5, 7)]
    assert intervals.intersection([(0, 4), (6, 10)], [(3, 7), (9, 9), (10, 12)]) == [(3, 4), (6, 7), (9, 9), (10, 10)]
    assert intervals.clip([(-5, -1), (-2, 3), (4, 20), (10, 10)], 0, 10) == [(0, 3), (4, 10), (10, 10)]
    assert intervals.measure([(0, 4), (2, 6), (8, 8)]) == 6
    # exactness: 0.1 + 0.2 style rounding does not leak into a sum of pieces
    pieces = [(0.1 * i, 0.1 * (i + 1)) for i in range(10)]
    assert intervals.measure(pieces) == Fraction(pieces[-1][1]) - Fraction(0.0)


# ---- batch metrics: hand-computed cases ------------------------------------------------------------------


def test_no_overlap() -> None:
    r = compute_metrics([up("robot", "pick", 0, 10), up("human", "screw", 10, 20)])
    assert (r.t0, r.t1, r.efficiency_s) == (0, 20, 20)
    assert (r.h_idle, r.r_idle, r.c_act, r.both_idle) == (0.5, 0.5, 0.0, 0.0)
    assert r.f_del == 0.0 and r.counts.handovers == 1 and r.counts.handovers_robot_to_human == 1


def test_full_overlap_and_tie_rule() -> None:
    # Same start and end: the tie-break puts the human first, so the pair is human-to-robot, term 0 - 10.
    r = compute_metrics([up("robot", "hold", 0, 10), up("human", "screw", 0, 10)])
    assert (r.h_idle, r.r_idle, r.c_act, r.both_idle) == (0.0, 0.0, 1.0, 0.0)
    assert r.f_del == -1.0
    assert compute_metrics([up("robot", "hold", 0, 10), up("human", "screw", 0, 10)],
                           fdel_direction="robot_to_human").f_del == 0.0
    assert compute_metrics([up("robot", "hold", 0, 10), up("human", "screw", 0, 10)],
                           fdel_direction="human_to_robot").f_del == -1.0


def test_gaps_and_directions() -> None:
    ups = [up("robot", "pick", 0, 4), up("human", "take", 6, 10), up("robot", "fetch", 12, 16)]
    r = compute_metrics(ups, t1=20)
    assert r.efficiency_s == 20
    assert r.h_idle == pytest.approx(16 / 20) and r.r_idle == pytest.approx(12 / 20)
    assert r.c_act == 0.0 and r.both_idle == pytest.approx(8 / 20)
    assert r.f_del == pytest.approx((2 + 2) / 20)
    assert compute_metrics(ups, t1=20, fdel_direction="robot_to_human").f_del == pytest.approx(2 / 20)
    assert compute_metrics(ups, t1=20, fdel_direction="human_to_robot").f_del == pytest.approx(2 / 20)
    with pytest.raises(ValueError, match="unknown F-DEL direction"):
        compute_metrics(ups, fdel_direction="sideways")  # type: ignore[arg-type]


def test_negative_fdel_when_next_starts_early() -> None:
    r = compute_metrics([up("robot", "hand over", 0, 10), up("human", "take", 8, 12)])
    assert r.f_del == pytest.approx(-2 / 12)
    assert r.c_act == pytest.approx(2 / 12)


def test_simultaneous_starts_order_by_end_then_agent() -> None:
    # B (human) and C (robot) both start at 5; C ends first so the order is A, C, B: one hand-over C->B = 5 - 7.
    ups = [up("robot", "A", 0, 5), up("human", "B", 5, 9), up("robot", "C", 5, 7)]
    expected = -2 / 9
    for perm in itertools.permutations(ups):
        r = compute_metrics(list(perm))
        assert r.f_del == pytest.approx(expected)
        assert r.counts.handovers == 1 and r.counts.handovers_robot_to_human == 1


def test_unfinished_actions_clip_to_t1() -> None:
    r = compute_metrics([up("robot", "pick", 0, 10), up("human", "screw", 5, None), up("robot", "hold", 12, 15)])
    assert r.t1 == 15
    assert r.human_active_s == 10 and r.robot_active_s == 13 and r.concurrent_s == 8
    assert [(u.agent, u.action, u.start) for u in r.unfinished] == [("human", "screw", 5.0)]
    assert r.counts.unfinished == 1
    # An unfinished action starting last sets T1 to its start (it is known to run at least until then).
    r = compute_metrics([up("robot", "pick", 0, 10), up("human", "screw", 12, None)])
    assert r.t1 == 12 and r.human_active_s == 0
    # Cut off before it starts, it is outside the window and not reported.
    r = compute_metrics([up("robot", "pick", 0, 10), up("human", "screw", 12, None)], t1=11)
    assert r.unfinished == [] and r.counts.human_actions == 0


def test_overlapping_labels_of_one_agent_count_once() -> None:
    r = compute_metrics([up("human", "hold", 0, 10), up("human", "look", 5, 15), up("robot", "pick", 20, 30)])
    assert r.human_active_s == 15
    assert r.h_idle == pytest.approx(15 / 30)
    assert r.counts.human_actions == 2


def test_zero_length_actions_count_no_time() -> None:
    r = compute_metrics([up("robot", "pick", 0, 10), up("human", "press", 5, 5)])
    assert r.human_active_s == 0 and r.concurrent_s == 0 and r.h_idle == 1.0
    assert r.counts.human_actions == 1
    assert r.f_del == pytest.approx(-5 / 10)  # robot (ends 10) hands over to the press at 5


def test_zero_length_task_is_defined_not_an_exception() -> None:
    r = compute_metrics([up("robot", "blink", 3, 3), up("human", "nod", 3, 3)])
    assert r.efficiency_s == 0
    assert (r.h_idle, r.r_idle, r.c_act, r.both_idle, r.f_del) == (None, None, None, None, None)
    assert "zero-length task" in (r.undefined_reason or "")
    d = r.to_json_dict()
    assert d["h_idle"] is None and d["counts"]["human_actions"] == 1
    r = compute_metrics([up("robot", "pick", 0, 10)], t0=4, t1=4, interventions=[])
    assert r.h_idle is None and r.effectiveness == 1.0


def test_window_and_errors() -> None:
    r = compute_metrics([up("robot", "pick", 0, 10), up("human", "take", 8, 20)], t0=5, t1=15)
    assert r.robot_active_s == 5 and r.human_active_s == 7 and r.concurrent_s == 2
    r = compute_metrics([], t0=0, t1=10)
    assert (r.h_idle, r.r_idle, r.both_idle, r.f_del) == (1.0, 1.0, 1.0, 0.0)
    with pytest.raises(ValueError, match="pass both t0 and t1"):
        compute_metrics([])
    with pytest.raises(ValueError, match="T1 .* is before T0"):
        compute_metrics([up("robot", "pick", 0, 10)], t0=8, t1=2)


def test_effectiveness_rule() -> None:
    robot = [up("robot", f"subtask {i}", 10 * i, 10 * i + 5) for i in range(20)]
    r = compute_metrics(robot)
    assert r.effectiveness is None and "effectiveness" not in r.to_json_dict()
    r = compute_metrics(robot, interventions=[])
    assert r.effectiveness == 1.0 and r.to_json_dict()["effectiveness"] == 1.0
    r = compute_metrics(robot, interventions=[Intervention(start=12, stop=14, subtask="subtask 1")])
    assert r.effectiveness == pytest.approx(0.95)  # the paper's teleoperated trial: 1 of 20
    assert r.counts.planned_subtasks == 20 and r.intervention_s == 2
    # Two interventions on one subtask count once; unnamed ones count one each.
    ivs = [Intervention(start=1, subtask="subtask 0"), Intervention(start=2, subtask="subtask 0"),
           Intervention(start=30), Intervention(start=40)]
    r = compute_metrics(robot, interventions=ivs, planned_subtasks=10)
    assert r.counts.intervened_subtasks == 3 and r.effectiveness == pytest.approx(0.7)
    with pytest.raises(ValueError, match="only 2 planned"):
        compute_metrics(robot, interventions=ivs, planned_subtasks=2)
    r = compute_metrics([up("human", "screw", 0, 5)], interventions=[])
    assert r.effectiveness is None and "no planned robot subtasks" in (r.undefined_reason or "")


# ---- properties ------------------------------------------------------------------------------------------

grid_action = st.tuples(st.sampled_from(["human", "robot"]), st.integers(0, 40), st.integers(0, 12),
                        st.booleans())


def _grid_updates(raw: list[tuple[str, int, int, bool]]) -> list[StateUpdate]:
    return [up(a, f"{a}{i}", float(s), None if unfinished else float(s + d))
            for i, (a, s, d, unfinished) in enumerate(raw)]


@settings(max_examples=150, deadline=None)
@given(st.lists(grid_action, min_size=1, max_size=12), st.integers(0, 10), st.integers(0, 60))
def test_measures_match_brute_force_and_identity(raw, t0, t1_extra) -> None:
    """On an integer grid a unit cell is either wholly covered or not, which gives an independent oracle."""
    ups = _grid_updates(raw)
    t1 = t0 + t1_extra
    r = compute_metrics(ups, t0=t0, t1=t1)

    def covered(agent: str, k: int) -> bool:
        return any(u.agent == agent and u.start <= k and (t1 if u.stop is None else u.stop) >= k + 1 for u in ups)

    cells = range(t0, t1)
    assert r.human_active_s == sum(covered("human", k) for k in cells)
    assert r.robot_active_s == sum(covered("robot", k) for k in cells)
    assert r.concurrent_s == sum(covered("human", k) and covered("robot", k) for k in cells)
    assert r.both_idle_s == sum(not covered("human", k) and not covered("robot", k) for k in cells)
    if t1 > t0:
        assert r.h_idle + r.r_idle + r.c_act == pytest.approx(1 + r.both_idle, abs=1e-12)
    else:
        assert r.h_idle is None


float_action = st.tuples(st.sampled_from(["human", "robot"]),
                         st.floats(0, 1e4, allow_nan=False), st.floats(0, 1e3, allow_nan=False), st.booleans())


@settings(max_examples=150, deadline=None)
@given(st.lists(float_action, min_size=1, max_size=15), st.randoms(use_true_random=False))
def test_identity_and_order_independence_on_floats(raw, rnd) -> None:
    ups = [up(a, f"{a}{i}", s, None if unfinished else s + d) for i, (a, s, d, unfinished) in enumerate(raw)]
    r = compute_metrics(ups)
    if r.efficiency_s > 0:
        assert r.h_idle + r.r_idle + r.c_act == pytest.approx(1 + r.both_idle, abs=1e-12)
        for x in (r.h_idle, r.r_idle, r.c_act, r.both_idle):
            assert 0.0 <= x <= 1.0
        assert -1.0 * len(ups) <= r.f_del <= 1.0 * len(ups)
    shuffled = list(ups)
    rnd.shuffle(shuffled)
    assert compute_metrics(shuffled).model_dump() == r.model_dump()


# ---- live == batch ---------------------------------------------------------------------------------------


def _events(ups: list[StateUpdate]) -> list[tuple[float, int, str, int]]:
    ev = []
    for i, u in enumerate(ups):
        ev.append((u.start, 0, "start", i))
        if u.stop is not None:
            ev.append((u.stop, 1, "stop", i))
    return sorted(ev, key=lambda e: (e[0], e[1], e[3]))


def _feed_and_compare(ups: list[StateUpdate], t0: float | None, extra_nows: list[float]) -> None:
    live = LiveMetrics(t0=t0)
    handles: dict[int, int] = {}
    for time, _, kind, i in _events(ups):
        u = ups[i]
        if kind == "start":
            handles[i] = live.start(u.agent, u.action, u.start)
        else:
            live.stop(handles[i], time)
        for now in (time, *[time + x for x in extra_nows]):
            batch = compute_metrics(live.updates(), t0=live.t0, t1=now)
            assert live.snapshot(now).model_dump() == batch.model_dump(), (time, now)


def test_live_equals_batch_on_example_trial() -> None:
    ups = read_trial(EXAMPLE).updates
    _feed_and_compare(ups, t0=None, extra_nows=[0.05, 3.3])
    _feed_and_compare(ups, t0=0.0, extra_nows=[1.0])


def test_live_work_per_snapshot_stays_small() -> None:
    """Finished hand-overs are folded into running sums; only those around the last actions stay open."""
    ups = read_trial(EXAMPLE).updates
    live = LiveMetrics()
    handles: dict[int, int] = {}
    running = 0
    for time, _, kind, i in _events(ups):
        if kind == "start":
            handles[i] = live.start(ups[i].agent, ups[i].action, time)
            running += 1
        else:
            live.stop(handles[i], time)
            running -= 1
        assert live.pending_groups <= 2 * running + 2  # each running action holds its group and the one before
    assert live.pending_groups == 1  # the last group, which has no next action to hand over to


def test_live_step_by_step_by_hand() -> None:
    live = LiveMetrics(t0=0)
    r = live.start("robot", "hand over", 0)
    s = live.snapshot(4)
    assert s.r_idle == 0.0 and s.h_idle == 1.0 and [u.action for u in s.unfinished] == ["hand over"]
    h = live.start("human", "take", 8)
    assert live.snapshot(9).f_del == pytest.approx((8 - 9) / 9)  # robot still running: its end is now
    live.stop(r, 10)
    s = live.snapshot(12)
    assert s.f_del == pytest.approx(-2 / 12) and s.c_act == pytest.approx(2 / 12)
    live.stop(h, 12)
    assert s.counts.unfinished == 1 and live.snapshot(12).counts.unfinished == 0


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(grid_action, min_size=1, max_size=10), st.lists(st.integers(0, 3), max_size=4),
       st.booleans())
def test_live_equals_batch_property(raw, extras, fixed_t0) -> None:
    ups = [up(a, f"{a}{i % 3}", s / 4, None if unf else (s + d) / 4) for i, (a, s, d, unf) in enumerate(raw)]
    _feed_and_compare(ups, t0=0.0 if fixed_t0 else None, extra_nows=[x / 2 for x in extras])


@settings(max_examples=80, deadline=None)
@given(st.lists(grid_action, min_size=1, max_size=10), st.randoms(use_true_random=False))
def test_live_late_labels_replay_exactly(raw, rnd) -> None:
    """Whole actions added in random order (experimenter labels after the fact) still match the batch."""
    ups = _grid_updates(raw)
    rnd.shuffle(ups)
    live = LiveMetrics()
    latest = 0.0
    for u in ups:
        live.add(u)
        latest = max(latest, u.start, u.stop or 0.0)
        now = latest + rnd.choice([0.0, 0.5, 2.0])
        assert live.snapshot(now).model_dump() == compute_metrics(live.updates(), t0=live.t0, t1=now).model_dump()


def test_live_errors() -> None:
    with pytest.raises(ValueError, match="no actions yet"):
        LiveMetrics().snapshot(1.0)
    live = LiveMetrics(t0=10)
    assert live.snapshot(20).h_idle == 1.0
    with pytest.raises(ValueError, match="before the study start"):
        live.start("human", "take", 5)
    h = live.start("human", "take", 12)
    with pytest.raises(ValidationError):
        live.stop(h, 11)
    live.stop(h, 13)
    with pytest.raises(ValueError, match="already stopped"):
        live.stop(h, 14)
    with pytest.raises(ValueError, match="unknown action handle"):
        live.stop(99, 14)
    with pytest.raises(ValueError, match="before the last event"):
        live.snapshot(12.5)
    with pytest.raises(ValueError, match="unknown F-DEL direction"):
        LiveMetrics(fdel_direction="up")  # type: ignore[arg-type]
    r = live.snapshot(20, interventions=[Intervention(start=12.5)], planned_subtasks=4)
    assert r.effectiveness == 0.75


# ---- readers ---------------------------------------------------------------------------------------------


def test_example_csv_reads() -> None:
    ups = read_trial(EXAMPLE).updates
    assert len(ups) >= 10 and {u.agent for u in ups} == {"human", "robot"}
    assert all(u.stop is not None and u.stop >= u.start for u in ups)


def test_csv_reader_ok(tmp_path: Path) -> None:
    p = tmp_path / "t.csv"
    p.write_text("stop,agent,action,start\n4.5,robot,pick, 0\n\n,human,\"screw, then check\",3\n")
    ups = read_trial(p).updates
    assert ups == [up("robot", "pick", 0, 4.5), up("human", "screw, then check", 3, None)]
    assert read_trial(p).interventions is None


@pytest.mark.parametrize(
    ("text", "row", "column", "problem"),
    [
        ("", 1, None, "empty or has no header"),
        ("agent,action,start,stopp\n", 1, "stopp", "unknown column"),
        ("agent,action,start\nrobot,pick,0\n", 1, "stop", "missing column"),
        ("agent,action,start,stop\nrobot,pick,0\n", 2, None, "3 fields where the header has 4"),
        ("agent,action,start,stop\nrobot,pick,0,1\nexperimenter,pick,0,1\n", 3, "agent", "unknown agent"),
        ("agent,action,start,stop\nrobot,,0,1\n", 2, "action", "at least 1 character"),
        ("agent,action,start,stop\nrobot,pick,abc,1\n", 2, "start", "'abc' is not a number"),
        ("agent,action,start,stop\nrobot,pick,nan,1\n", 2, "start", "not a finite time"),
        ("agent,action,start,stop\nrobot,pick,,1\n", 2, "start", "no value"),
        ("agent,action,start,stop\nrobot,pick,1,x\n", 2, "stop", "'x' is not a number"),
        ("agent,action,start,stop\nrobot,pick,5,4\n", 2, "stop", "stop (4) is before start (5)"),
    ],
)
def test_csv_reader_errors(tmp_path: Path, text: str, row: int, column: str | None, problem: str) -> None:
    p = tmp_path / "trial.csv"
    p.write_text(text)
    with pytest.raises(MetricsInputError) as info:
        read_trial(p)
    msg = str(info.value)
    assert msg.startswith(str(p)) and f"row {row}" in msg and problem in msg and "fix:" in msg
    if column is not None:
        assert f"column {column!r}" in msg


def test_csv_duplicate_column(tmp_path: Path) -> None:
    p = tmp_path / "trial.csv"
    p.write_text("agent,action,start,stop,start\n")
    with pytest.raises(MetricsInputError, match="column 'start' appears twice"):
        read_trial(p)


def test_json_reader_ok(tmp_path: Path) -> None:
    p = tmp_path / "t.json"
    p.write_text(json.dumps([{"agent": "robot", "action": "pick", "start": 0, "stop": 4.5},
                             {"agent": "human", "action": "screw", "start": 3, "stop": None}]))
    assert read_trial(p).updates == [up("robot", "pick", 0, 4.5), up("human", "screw", 3, None)]
    p.write_text(json.dumps({"updates": [{"agent": "robot", "action": "pick", "start": 0, "stop": 1}],
                             "interventions": [{"start": 0.5, "subtask": "pick"}], "planned_subtasks": 20}))
    trial = read_trial(p)
    assert trial.interventions == [Intervention(start=0.5, subtask="pick")] and trial.planned_subtasks == 20
    p.write_text(json.dumps({"updates": []}))
    assert read_trial(p).interventions is None


GOOD = {"agent": "robot", "action": "pick", "start": 0, "stop": 1}


@pytest.mark.parametrize(
    ("doc", "where", "problem"),
    [
        ("[{", "line 1", "invalid JSON"),
        ('"hello"', None, "top level is a JSON str"),
        ("[1]", "entry [0]", "not an object"),
        (json.dumps([GOOD, {k: v for k, v in GOOD.items() if k != "stop"}]), "entry [1], column 'stop'",
         "missing key(s) stop"),
        (json.dumps([GOOD | {"stp": 2}]), "entry [0], column 'stp'", "unknown key"),
        (json.dumps([GOOD | {"start": "0"}]), "entry [0], column 'start'", "valid number"),
        (json.dumps([GOOD | {"agent": "Robot"}]), "entry [0], column 'agent'", "unknown agent 'Robot'"),
        (json.dumps([GOOD | {"start": 3}]), "entry [0], column 'stop'", "before start"),
        (json.dumps({"updates": {}}), "column 'updates'", "not a list"),
        (json.dumps({"updates": [], "extra": 1}), None, "unknown top-level key(s) 'extra'"),
        (json.dumps({"interventions": []}), None, 'no "updates"'),
        (json.dumps({"updates": [], "planned_subtasks": 2.5}), "column 'planned_subtasks'", "not a whole number"),
        (json.dumps({"updates": [], "interventions": [{"stop": 1}]}), "entry interventions[0], column 'start'",
         "missing key"),
    ],
)
def test_json_reader_errors(tmp_path: Path, doc: str, where: str | None, problem: str) -> None:
    p = tmp_path / "trial.json"
    p.write_text(doc)
    with pytest.raises(MetricsInputError) as info:
        read_trial(p)
    msg = str(info.value)
    assert msg.startswith(str(p)) and problem in msg and "fix:" in msg
    if where is not None:
        assert where in msg


def test_file_level_errors(tmp_path: Path) -> None:
    with pytest.raises(MetricsInputError, match="file not found"):
        read_trial(tmp_path / "missing.csv")
    (tmp_path / "rec.mcap").write_bytes(b"\x89MCAP0\r\n")
    with pytest.raises(MetricsInputError, match="cannot read the recording"):
        read_trial(tmp_path / "rec.mcap")
    (tmp_path / "t.xlsx").write_bytes(b"")
    with pytest.raises(MetricsInputError, match="unknown trial file type '.xlsx'"):
        read_trial(tmp_path / "t.xlsx")
    (tmp_path / "bin.csv").write_bytes(b"\xff\xfe\x00bad")
    with pytest.raises(MetricsInputError, match="cannot read the file"):
        read_trial(tmp_path / "bin.csv")


def test_interventions_readers(tmp_path: Path) -> None:
    assert read_interventions(EXAMPLE_INTERVENTIONS)[0].subtask == "hand over side panel"
    p = tmp_path / "iv.csv"
    p.write_text("start,note\n3,operator took over\n")
    assert read_interventions(p) == [Intervention(start=3, note="operator took over")]
    p.write_text("start,stop\n3,2\n")
    with pytest.raises(MetricsInputError, match=r"row 2, column 'stop'"):
        read_interventions(p)
    p.write_text("stop\n3\n")
    with pytest.raises(MetricsInputError, match="missing column"):
        read_interventions(p)
    j = tmp_path / "iv.json"
    j.write_text(json.dumps([{"start": 1, "stop": None, "subtask": "pick"}]))
    assert read_interventions(j) == [Intervention(start=1, subtask="pick")]
    j.write_text(json.dumps([{"start": 1, "who": "me"}]))
    with pytest.raises(MetricsInputError, match="unknown key 'who'"):
        read_interventions(j)
    with pytest.raises(MetricsInputError, match="unknown interventions file type"):
        read_interventions(tmp_path / "iv.txt")


# ---- CLI -------------------------------------------------------------------------------------------------


def test_cli_summary_json_and_options(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "m.json"
    assert main_cli.main(["metrics", str(EXAMPLE), "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "H-IDLE" in printed and "F-DEL" in printed and "no interventions given" in printed
    data = json.loads(out.read_text())
    assert set(data) == JSON_KEYS
    expected = compute_metrics(read_trial(EXAMPLE).updates)
    assert data["h_idle"] == expected.h_idle and data["f_del"] == expected.f_del
    assert data["counts"]["human_actions"] + data["counts"]["robot_actions"] == len(read_trial(EXAMPLE).updates)

    assert main_cli.main(["metrics", str(EXAMPLE), "--json", str(out), "--t0", "10", "--t1", "60",
                          "--fdel", "human_to_robot", "--interventions", str(EXAMPLE_INTERVENTIONS)]) == 0
    data = json.loads(out.read_text())
    assert set(data) == JSON_KEYS | {"effectiveness"}
    windowed = compute_metrics(read_trial(EXAMPLE).updates, t0=10, t1=60, fdel_direction="human_to_robot",
                               interventions=read_interventions(EXAMPLE_INTERVENTIONS))
    assert (data["t0"], data["t1"], data["efficiency_s"]) == (10, 60, 50)
    assert data["f_del"] == windowed.f_del and data["effectiveness"] == windowed.effectiveness
    assert 0 < data["effectiveness"] < 1


def test_cli_json_object_form_and_conflict(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    trial = tmp_path / "trial.json"
    robot = [{"agent": "robot", "action": f"s{i}", "start": i, "stop": i + 0.5} for i in range(20)]
    trial.write_text(json.dumps({"updates": robot, "interventions": [{"start": 3.1, "subtask": "s3"}]}))
    assert main_cli.main(["metrics", str(trial), "--json", "-"]) == 0
    captured = capsys.readouterr()
    data = json.loads(captured.out)  # `--json -`: stdout holds the JSON and nothing else
    assert data["effectiveness"] == pytest.approx(0.95)
    assert "H-IDLE" in captured.err  # the summary went to stderr
    assert main_cli.main(["metrics", str(trial), "--json", "-", "--planned-subtasks", "10"]) == 0
    assert json.loads(capsys.readouterr().out)["effectiveness"] == pytest.approx(0.9)
    assert main_cli.main(["metrics", str(trial), "--planned-subtasks", "-1"]) == 2
    assert "planned subtasks must be >= 0" in capsys.readouterr().err
    assert main_cli.main(["metrics", str(trial), "--interventions", str(EXAMPLE_INTERVENTIONS)]) == 2
    assert "keep one of the two" in capsys.readouterr().err


def test_cli_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("agent,action,start,stop\nrobot,pick,5,4\n")
    assert main_cli.main(["metrics", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.csv, row 2, column 'stop'" in err and "fix:" in err
    empty = tmp_path / "empty.csv"
    empty.write_text("agent,action,start,stop\n")
    assert main_cli.main(["metrics", str(empty)]) == 2
    assert "no state updates" in capsys.readouterr().err
    assert main_cli.main(["metrics", str(EXAMPLE), "--t0", "50", "--t1", "10"]) == 2
    assert "is before T0" in capsys.readouterr().err


def test_cli_end_to_end_real_executable(tmp_path: Path) -> None:
    out, png = tmp_path / "m.json", tmp_path / "g.png"
    env = dict(os.environ, MPLBACKEND="Agg")
    proc = subprocess.run([str(VR_TELEOP), "metrics", str(EXAMPLE), "--json", str(out), "--plot", str(png)],
                          capture_output=True, text=True, timeout=60, env=env, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "H-IDLE" in proc.stdout and f"wrote {png}" in proc.stdout
    assert set(json.loads(out.read_text())) == JSON_KEYS
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    mcap = tmp_path / "session.mcap"
    mcap.write_bytes(b"\x89MCAP0\r\n")
    proc = subprocess.run([str(VR_TELEOP), "metrics", str(mcap)], capture_output=True, text=True, timeout=60,
                          env=env, cwd=tmp_path)
    assert proc.returncode == 2
    assert "cannot read the recording" in proc.stderr and "Traceback" not in proc.stderr


# ---- Gantt chart -----------------------------------------------------------------------------------------


def test_gantt_png_is_valid_and_shows_both_agents(tmp_path: Path) -> None:
    ups = read_trial(EXAMPLE).updates + [up("robot", "wave", 91.0, None), up("human", "nod", 90.5, 90.5)]
    png = plot_gantt(ups, tmp_path / "g.png", title="example")
    raw = png.read_bytes()
    assert raw[:8] == b"\x89PNG\r\n\x1a\n" and raw[12:16] == b"IHDR"
    width, height = struct.unpack(">II", raw[16:24])
    assert 1000 <= width <= 3000 and 300 <= height <= 1200 and width > height
    img = matplotlib.image.imread(png)[..., :3]
    for colour in ("#4C72B0", "#DD8452"):  # robot and human bars are drawn
        rgb = np.array([int(colour[i:i + 2], 16) for i in (1, 3, 5)]) / 255
        assert (np.abs(img - rgb).max(axis=-1) < 0.02).sum() > 1000, colour
    plain = plot_gantt(ups, tmp_path / "plain.png", shade=False)
    assert plain.stat().st_size > 10_000 and plain.read_bytes() != raw


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main_cli.main(["--version"])
    assert info.value.code == 0
    assert capsys.readouterr().out.startswith("vr-teleop ")
