"""The classroom study's measures (beside the fluency metrics): how quickly and how much the robot attends to the
pupil who speaks, and how much work is left to the teacher. `classroom_metrics(timeline)` is pure (no I/O: tests
build timelines by hand); `read_classroom(path, lesson_s)` builds the timeline from a session recording.

- onset to look: from a pupil's speech onset to the robot's head first pointing at them (HeadYaw within
  POINTING_DEG of their direction, as metrics/autonomy.py), within REACH_S of the onset or never; mean over the
  speeches looked at, p95 over all (a p95 that falls on a never is none);
- share attended: of the pupils' speech time in the lesson, the share the head pointed at the speaker (the head's
  yaw held from one joint-state sample to the next);
- the teacher's actions per minute: her own (menu actions, interventions) plus her decisions on proposals;
- proposals: accepted and rejected (forbidden counts as rejected) by her, timed out (done by the time-out), done
  by the robot itself (autonomous), superseded or dropped;
- interventions: the times she took control during the lesson (in teleoperated she holds it from before the
  start: none);
- effectiveness: the share of speeches looked at within REACH_S. Efficiency (the framework's time to complete a
  task) does not apply: a lesson lasts what it lasts.

The lesson starts at the teacher's level choice (an autonomy_level event on /vr_teleop/events) and lasts
`lesson_s`; speeches that begin in it count, clipped at its end.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from client_protocol import names
from client_protocol.events import EventKind
from client_protocol.vocabulary import Decider, Outcome

from ...recording.format import read_recording
from .autonomy import POINTING_DEG, REACH_S, HeadAndSpeech, percentile

DECIDED_BY_MACHINE = tuple(Decider)


@dataclass(frozen=True)
class Speech:
    who: str
    onset: float
    end: float
    yaw: float


@dataclass(frozen=True)
class OutcomeAt:
    """An outcome (/vr_teleop/autonomy/outcomes) at `t`."""
    t: float
    outcome: Outcome
    decided_by: str = ""  # a Decider, or the teacher


@dataclass
class ClassroomTimeline:
    """One lesson, times in seconds since its start (0): what the measures need and nothing else."""
    lesson_s: float
    speeches: list[Speech] = field(default_factory=list)
    heads: list[tuple[float, float]] = field(default_factory=list)  # (t, HeadYaw deg), in time order
    outcomes: list[OutcomeAt] = field(default_factory=list)
    interventions: list[float] = field(default_factory=list)  # when she took control


@dataclass(frozen=True)
class ClassroomResult:
    lesson_s: float
    speeches: int
    never_looked_at: int
    onset_to_look_mean_s: float | None
    onset_to_look_p95_s: float | None
    share_attended: float | None
    teacher_own: int
    teacher_decisions: int
    teacher_actions_per_min: float
    accepted: int
    rejected: int
    timed_out: int
    robot_executed: int
    superseded: int
    dropped: int
    interventions: int
    effectiveness: float | None

    @property
    def duration_s(self) -> float:
        """The lesson's length (study/kind.py's Measures)."""
        return self.lesson_s

    def to_json_dict(self) -> dict[str, Any]:
        """The measures, and efficiency as null: it does not apply to a lesson (the module's docstring)."""
        return {**asdict(self), "efficiency_s": None}


# The measures `--repeat` summarises (mean, SD, 95% CI), in table order.
CLASSROOM_METRICS = ("onset_to_look_mean_s", "onset_to_look_p95_s", "share_attended", "teacher_actions_per_min",
                     "accepted", "rejected", "timed_out", "interventions", "effectiveness")


def classroom_metrics(tl: ClassroomTimeline) -> ClassroomResult:
    times = np.array([h[0] for h in tl.heads], dtype=float)
    yaws = np.array([h[1] for h in tl.heads], dtype=float)
    latencies: list[float] = []
    looked = spoken = 0.0
    for s in tl.speeches:
        end = min(s.end, tl.lesson_s)
        if s.onset >= tl.lesson_s or end <= s.onset:
            continue
        spoken += end - s.onset
        if len(times):
            # the yaw held from each sample to the next, over [onset, end]: the sample before the onset counts too
            first = max(int(np.searchsorted(times, s.onset, side="right")) - 1, 0)
            last = int(np.searchsorted(times, end, side="left"))
            for i in range(first, last):
                a = max(times[i], s.onset)
                b = min(times[i + 1] if i + 1 < len(times) else end, end)
                if b > a and abs(yaws[i] - s.yaw) <= POINTING_DEG:
                    looked += b - a
            held = first if times[first] <= s.onset else None
            if held is not None and abs(yaws[held] - s.yaw) <= POINTING_DEG:
                latencies.append(0.0)
                continue
            # a look counts in the lesson only: the recording runs on while the lesson's server stops, for a
            # stretch of simulated time that depends on the machine (two runs of one seed differed there)
            near = ((times >= s.onset) & (times <= min(s.onset + REACH_S, tl.lesson_s))
                    & (np.abs(yaws - s.yaw) <= POINTING_DEG))
            if near.any():
                latencies.append(float(times[np.argmax(near)] - s.onset))
                continue
        latencies.append(math.inf)
    in_lesson = [o for o in tl.outcomes if 0.0 <= o.t < tl.lesson_s]
    by_teacher = [o for o in in_lesson if o.decided_by not in DECIDED_BY_MACHINE]

    def n(outcomes: list[OutcomeAt], *kinds: Outcome) -> int:
        return sum(o.outcome in kinds for o in outcomes)

    own_menu = n(in_lesson, Outcome.TEACHER_INITIATED)
    interventions = sum(0.0 <= t < tl.lesson_s for t in tl.interventions)
    decisions = n(by_teacher, Outcome.ACCEPTED, Outcome.REJECTED, Outcome.FORBIDDEN)
    finite = [x for x in latencies if math.isfinite(x)]
    minutes = tl.lesson_s / 60.0
    return ClassroomResult(
        lesson_s=tl.lesson_s, speeches=len(latencies), never_looked_at=len(latencies) - len(finite),
        onset_to_look_mean_s=round(sum(finite) / len(finite), 4) if finite else None,
        onset_to_look_p95_s=percentile(latencies, 95),
        share_attended=round(looked / spoken, 4) if spoken else None,
        teacher_own=own_menu + interventions, teacher_decisions=decisions,
        teacher_actions_per_min=round((own_menu + interventions + decisions) / minutes, 4),
        accepted=n(by_teacher, Outcome.ACCEPTED), rejected=n(by_teacher, Outcome.REJECTED, Outcome.FORBIDDEN),
        timed_out=n(in_lesson, Outcome.TIMED_OUT_EXECUTED),
        robot_executed=sum(o.outcome == Outcome.ACCEPTED and o.decided_by == Decider.AUTONOMY for o in in_lesson),
        superseded=n(in_lesson, Outcome.SUPERSEDED), dropped=n(in_lesson, Outcome.DROPPED),
        interventions=interventions,
        effectiveness=round(len(finite) / len(latencies), 4) if latencies else None)


def read_classroom(path: Path, lesson_s: float) -> ClassroomTimeline:
    """A lesson's timeline from its session recording; ValueError when the recording has no lesson start."""
    t0: float | None = None
    follow = HeadAndSpeech()
    outcomes: list[tuple[float, dict[str, Any]]] = []
    engages: list[float] = []
    last = 0.0
    for rec in read_recording(path):
        t = rec.time_ns * 1e-9
        last = t
        topic = rec.topic
        if follow.take(topic, t, rec.data):
            continue
        if topic == names.AUTONOMY_OUTCOMES_TOPIC:
            outcomes.append((t, rec.data))
        elif topic == names.EVENT_TOPIC:
            kind = rec.data.get("kind")
            if kind == EventKind.AUTONOMY_LEVEL.value and t0 is None:
                detail = json.loads(rec.data.get("detail") or "{}")
                if detail.get("by") not in (None, "", "server"):
                    t0 = t
            elif kind == EventKind.ENGAGE.value and rec.data.get("source") == "teleop" and t0 is not None:
                engages.append(t)  # taking control once the lesson has begun (in teleoperated she took it before)
    if t0 is None:
        raise ValueError(f"{path}: no lesson start (the teacher's autonomy level choice) in the recording")
    follow.end(last)
    heads, speeches = follow.heads, follow.speeches
    level_engages = [t - t0 for t in engages]
    return ClassroomTimeline(
        lesson_s=lesson_s,
        speeches=sorted((Speech(w, a - t0, b - t0, y) for w, a, b, y in speeches), key=lambda s: s.onset),
        heads=[(t - t0, y) for t, y in heads],
        outcomes=[OutcomeAt(t - t0, Outcome(o["outcome"]), str(o.get("decided_by", ""))) for t, o in outcomes],
        interventions=level_engages)


def classroom_summary(title: str, r: ClassroomResult) -> str:
    def f(x: float | None, unit: str = "") -> str:
        return "n/a" if x is None else f"{x:.2f}{unit}"

    return "\n".join([
        f"{title}: {r.lesson_s:.0f} s lesson, {r.speeches} speeches ({r.never_looked_at} never looked at)",
        f"  onset to look  mean {f(r.onset_to_look_mean_s, ' s')}  p95 {f(r.onset_to_look_p95_s, ' s')}  "
        f"speech attended {f(r.share_attended)}  effectiveness {f(r.effectiveness)}",
        f"  teacher        {r.teacher_actions_per_min:.2f} actions/min ({r.teacher_own} her own, "
        f"{r.teacher_decisions} decisions), {r.interventions} interventions",
        f"  proposals      accepted {r.accepted}  rejected {r.rejected}  timed out {r.timed_out}  done by the robot "
        f"{r.robot_executed}  superseded {r.superseded}  dropped {r.dropped}",
    ])
