"""QAM's objective items measured from a trial's recording (`DIR/P03/CONDITION.mcap`), for the study report.

QAM (docs/guides/questionnaires.md) asks for parameters 4-6 as objective ratings, and parameters 1-3 are counts a
session can hold. What a recording gives, per kind of study (the kind is the one its /study/session says):

- P1, P2 (classroom): who initiated the interactions that involved the teacher. The robot's requests are its
  proposals put to her (/vr_teleop/autonomy/outcomes with initiator robot, not done by the robot itself); hers are
  her own actions (outcome teacher_initiated) and her interventions (an engage event on /vr_teleop/events while the
  level was not teleoperated). P1 = robot's / all x 100, P2 = hers / all x 100. A task study's robot has no way to
  ask for assistance: missing there.
- P3 needs each interruption rated critical or not, a judgement no recording holds: always missing.
- P4 effectiveness (% of tasks completed successfully). Classroom: the share of pupils' speeches the head looked
  at within 5 s (metrics/classroom.py). Task: the share of the plan's robot subtasks done without a human
  intervention (metrics/fluency.py).
- P5 efficiency (seconds per completed task). Classroom: the mean time from a speech's onset to the head pointing
  at the speaker, over those looked at. Task: the trial's time over the robot subtasks it finished.
- P6 efficacy (% of intended outcomes achieved). Classroom: of the pupils' speech time, the share the head pointed
  at the speaker. Task: the robot subtasks finished (with help or not) over those planned.

An item the recording cannot give is returned with value None and the reason (a topic it lacks, nothing to count),
so that the report counts it as missing and says why; nothing is filled in. Each kind's qam_items (kind.py) is one
of the functions here; kinds.measure_qam picks it by the kind the recording names.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from client_protocol import names
from client_protocol.events import EventKind
from client_protocol.vocabulary import AutonomyLevel, Decider, Initiator, Outcome

from ..recording.format import read_recording
from .metrics.autonomy import HeadAndSpeech
from .metrics.classroom import ClassroomTimeline, Speech, classroom_metrics
from .metrics.fluency import compute_metrics
from .metrics.model import MetricsInputError
from .metrics.mcap_reader import read_trial_mcap

ITEMS = ("P1", "P2", "P3", "P4", "P5", "P6")
UNITS = {"P1": "% of requests for assistance", "P2": "% of requests for assistance",
         "P3": "interruptions rated non-critical", "P4": "% of tasks completed successfully",
         "P5": "seconds per completed task", "P6": "% of intended outcomes achieved"}
P3_REASON = ("rating each interruption of the operator as critical or not is a judgement no recording holds: "
             "code the robot's requests (P1) and add the count by hand")


@dataclass(frozen=True)
class Measured:
    """One QAM item of one trial: its value, or None and why it is missing."""

    item: str  # P1 ... P6
    value: float | None
    how: str  # what was measured, or the reason it is missing

    @property
    def unit(self) -> str:
        return UNITS[self.item]


def _pct(part: float, whole: float) -> float:
    return round(100.0 * part / whole, 4)


def all_missing(reason: str) -> list[Measured]:
    return [Measured(item, None, reason) for item in ITEMS]


def recording_kind(path: Path) -> str | None:
    """The kind of study the recording's /study/session names (None: it has none)."""
    for rec in read_recording(path):
        if rec.topic == names.STUDY_SESSION_TOPIC:
            return str(rec.data.get("kind", ""))
    return None


def _lacks(topic: str, what: str) -> str:
    return f"the recording has no {topic} ({what})"


def lesson_items(path: Path) -> list[Measured]:
    """A lesson's items (the classroom kind's qam_items)."""
    topics: set[str] = set()
    follow = HeadAndSpeech()
    outcomes: list[dict[str, Any]] = []
    takeovers: list[float] = []
    t0: float | None = None
    level = ""
    last = 0.0
    for rec in read_recording(path):
        t = rec.time_ns * 1e-9
        last = t
        topics.add(rec.topic)
        if follow.take(rec.topic, t, rec.data):
            continue
        if rec.topic == names.AUTONOMY_OUTCOMES_TOPIC:
            outcomes.append(rec.data)
        elif rec.topic == names.EVENT_TOPIC:
            kind = rec.data.get("kind")
            if kind == EventKind.AUTONOMY_LEVEL.value:
                detail = json.loads(rec.data.get("detail") or "{}")
                level = str(detail.get("level", level))
                if t0 is None and detail.get("by") not in (None, "", "server"):
                    t0 = t
            elif kind == EventKind.ENGAGE.value and rec.data.get("source") == "teleop" and t0 is not None \
                    and level != AutonomyLevel.TELEOPERATED:  # a takeover in the lesson (teleoperated: she holds it)
                takeovers.append(t)
    follow.end(last)
    out = [*_initiative(topics, outcomes, takeovers), Measured("P3", None, P3_REASON)]
    if t0 is None:
        return out + [Measured(i, None, "no lesson start (the autonomy level set for the trial on "
                                        f"{names.EVENT_TOPIC}) in the recording") for i in ("P4", "P5", "P6")]
    lacking = [(names.SIM_BYSTANDERS_TOPIC, "who speaks when"), (names.JOINT_STATE_TOPIC, "where the head points")]
    absent = [_lacks(topic, what) for topic, what in lacking if topic not in topics]
    if absent:
        return out + [Measured(i, None, "; ".join(absent)) for i in ("P4", "P5", "P6")]
    result = classroom_metrics(ClassroomTimeline(
        lesson_s=last - t0,
        speeches=sorted((Speech(w, a - t0, b - t0, y) for w, a, b, y in follow.speeches), key=lambda s: s.onset),
        heads=[(t - t0, y) for t, y in follow.heads]))
    if result.speeches == 0:
        return out + [Measured(i, None, "no pupil spoke during the trial: nothing to attend to")
                      for i in ("P4", "P5", "P6")]
    looked = result.speeches - result.never_looked_at
    return out + [
        Measured("P4", round(100.0 * (result.effectiveness or 0.0), 4),
                 f"{looked} of {result.speeches} speeches looked at within 5 s"),
        Measured("P5", result.onset_to_look_mean_s, "mean onset-to-look time over the speeches looked at")
        if result.onset_to_look_mean_s is not None else
        Measured("P5", None, "no speech was looked at within 5 s: no completed task to time"),
        Measured("P6", None if result.share_attended is None else round(100.0 * float(result.share_attended), 4),
                 "share of the pupils' speech time the head pointed at the speaker")]


def _initiative(topics: set[str], outcomes: list[dict[str, Any]], takeovers: list[float]) -> list[Measured]:
    if names.AUTONOMY_OUTCOMES_TOPIC not in topics:
        reason = _lacks(names.AUTONOMY_OUTCOMES_TOPIC, "the robot's proposals and the teacher's own actions")
        return [Measured("P1", None, reason), Measured("P2", None, reason)]
    robot = sum(o.get("initiator") == Initiator.ROBOT and o.get("decided_by") != Decider.AUTONOMY for o in outcomes)
    teacher = sum(o.get("outcome") == Outcome.TEACHER_INITIATED for o in outcomes) + len(takeovers)
    if robot + teacher == 0:
        reason = "no request for assistance either way: nothing to take a percentage of"
        return [Measured("P1", None, reason), Measured("P2", None, reason)]
    counts = f"robot: {robot} proposals put to the teacher; teacher: {teacher} own actions and takeovers"
    total = robot + teacher
    return [Measured("P1", _pct(robot, total), counts), Measured("P2", _pct(teacher, total), counts)]


def task_items(path: Path) -> list[Measured]:
    """A task trial's items (the task kind's qam_items)."""
    no_request = ("a task study's robot has no way to ask for assistance, so the operator's interventions have "
                  "nothing to be a share of")
    out = [Measured("P1", None, no_request), Measured("P2", None, no_request), Measured("P3", None, P3_REASON)]
    try:
        data = read_trial_mcap(path)
    except MetricsInputError as exc:
        return out + [Measured(i, None, exc.problem) for i in ("P4", "P5", "P6")]
    if data.t1 is None:
        reason = f"the trial has no final state on {names.STUDY_TRIAL_TOPIC} (cut short)"
        return out + [Measured(i, None, reason) for i in ("P4", "P5", "P6")]
    try:
        result = compute_metrics(data.updates, data.t0, data.t1, interventions=data.interventions,
                                 planned_subtasks=data.planned_subtasks or None)
    except ValueError as exc:
        reason = f"the trial's state updates give no window ({exc})"
        return out + [Measured(i, None, reason) for i in ("P4", "P5", "P6")]
    planned = result.counts.planned_subtasks or data.planned_subtasks
    done = sum(u.agent == "robot" and u.stop is not None for u in data.updates)
    p4 = (Measured("P4", round(100.0 * result.effectiveness, 4),
                   f"{planned} planned robot subtasks, {result.counts.intervened_subtasks} with an intervention")
          if result.effectiveness is not None else
          Measured("P4", None, _lacks(names.STUDY_INTERVENTIONS_TOPIC, "the interventions")))
    p5 = (Measured("P5", round(result.efficiency_s / done, 4), f"{result.efficiency_s:.2f} s over {done} robot "
                                                                "subtasks finished")
          if done else Measured("P5", None, "no robot subtask finished: no completed task to time"))
    p6 = (Measured("P6", _pct(min(done, planned), planned), f"{done} of {planned} planned robot subtasks finished")
          if planned else Measured("P6", None, f"no planned robot subtasks on {names.STUDY_TRIAL_TOPIC}"))
    return out + [p4, p5, p6]

