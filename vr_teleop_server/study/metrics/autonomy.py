"""Supervision and attention measures of a recorded session (`vr-teleop metrics autonomy FILE.mcap`), as SPARC's
studies report them: proposals per minute, the share accepted, rejected, forbidden, timed out and executed,
superseded or dropped, the median time to a teacher's decision, the teacher's own actions per minute (a workload
proxy); and for attention, from each pupil's speech onset to the head pointing at them (within POINTING_DEG of
their direction, p50 and p95; a speaker never pointed at within REACH_S counts as never, and a percentile that
falls on a never is reported as none), and the share of speech time the speaker was looked at.

Speech onsets and directions come from the stand-in's /sim/bystanders (simulated pupils); a recording of a real
robot has proposals and outcomes but no such ground truth, and its attention figures are empty.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from client_protocol import names
from client_protocol.events import EventKind
from client_protocol.vocabulary import Decider, Decision, Initiator, Outcome

from ...recording.format import read_recording

POINTING_DEG = 10.0
REACH_S = 5.0  # a speaker not pointed at within this long of their onset was never looked at
HUMAN_DECISIONS = tuple(d.outcome for d in Decision)
ROBOT_OUTCOMES = (*HUMAN_DECISIONS, Outcome.TIMED_OUT_EXECUTED, Outcome.SUPERSEDED, Outcome.DROPPED)


def percentile(values: list[float], q: float) -> float | None:
    """None when there are no values, or when the percentile falls on a never (infinite) one."""
    if not values:
        return None
    value = float(np.percentile(values, q, method="higher"))
    return round(value, 4) if math.isfinite(value) else None


class HeadAndSpeech:
    """What attention is judged on, followed through a recording (here and in metrics/classroom.py): the head's yaw
    from the joint states, and each simulated pupil's speech (onset, end, direction) from /sim/bystanders."""

    def __init__(self) -> None:
        self.heads: list[tuple[float, float]] = []  # (t, HeadYaw)
        self.speeches: list[tuple[str, float, float, float]] = []  # (name, onset, end, yaw)
        self._speaking: dict[str, tuple[float, float]] = {}  # name -> (onset, yaw) while speaking

    def take(self, topic: str, t: float, data: dict[str, Any]) -> bool:
        """Follows one record; whether it was one of the two topics."""
        if topic == names.JOINT_STATE_TOPIC:
            joints = dict(zip(data.get("name", []), data.get("position", [])))
            if "HeadYaw" in joints:
                self.heads.append((t, float(joints["HeadYaw"])))
            return True
        if topic == names.SIM_BYSTANDERS_TOPIC:
            for b in data.get("bystanders", []):
                name = b["name"]
                if b["speaking"] and name not in self._speaking:
                    self._speaking[name] = (t, float(b["yaw"]))
                elif not b["speaking"] and name in self._speaking:
                    onset, yaw = self._speaking.pop(name)
                    self.speeches.append((name, onset, t, yaw))
            return True
        return False

    def end(self, last: float) -> None:
        """The recording ended at `last`: whoever is still speaking stops there."""
        for name, (onset, yaw) in self._speaking.items():
            self.speeches.append((name, onset, last, yaw))
        self._speaking.clear()


def autonomy_metrics(path: Path, until: float | None = None) -> dict[str, Any]:
    """The measures of one recording; ValueError naming an empty one. `until` (the recording's clock, seconds since
    1970): attention counts only the speeches that began before it (a bench's later phases are not attention's)."""
    first = last = None
    proposals = 0
    outcomes: list[dict[str, Any]] = []
    levels: list[dict[str, Any]] = []
    follow = HeadAndSpeech()
    for rec in read_recording(path):
        t = rec.time_ns * 1e-9
        first = t if first is None else first
        last = t
        if follow.take(rec.topic, t, rec.data):
            continue
        if rec.topic == names.AUTONOMY_PROPOSALS_TOPIC:
            proposals += 1
        elif rec.topic == names.AUTONOMY_OUTCOMES_TOPIC:
            outcomes.append(rec.data)
        elif rec.topic == names.EVENT_TOPIC and rec.data.get("source") == "autonomy" \
                and rec.data.get("kind") == EventKind.AUTONOMY_LEVEL.value:
            levels.append({"t": round(t - first, 3), **json.loads(rec.data.get("detail") or "{}")})
    if first is None or last is None:
        raise ValueError(f"{path}: an empty recording")
    follow.end(last)
    heads, speeches = follow.heads, follow.speeches
    minutes = max(last - first, 1e-9) / 60.0
    robot = [o for o in outcomes if o.get("initiator") == Initiator.ROBOT]
    teacher = [o for o in outcomes if o.get("outcome") == Outcome.TEACHER_INITIATED]
    counts = {k: sum(o["outcome"] == k for o in robot) for k in ROBOT_OUTCOMES}
    decided = [float(o["seconds"]) for o in robot if o["outcome"] in HUMAN_DECISIONS
               and o.get("decided_by") not in tuple(Decider)]
    latencies, looked, spoken, missed = [], 0.0, 0.0, 0
    times = np.array([h[0] for h in heads])
    yaws = np.array([h[1] for h in heads])
    for _name, onset, end, yaw in speeches:
        if until is not None and onset >= until:
            continue
        inside = (times >= onset) & (times <= end)
        if inside.sum() < 2:
            continue
        on = np.abs(yaws[inside] - yaw) <= POINTING_DEG
        dt = np.diff(times[inside], append=end)
        looked += float(dt[on].sum())
        spoken += float(dt.sum())
        # the first pointing at them, even just after a short sentence ended (within REACH_S of the onset)
        near = (times >= onset) & (times <= onset + REACH_S) & (np.abs(yaws - yaw) <= POINTING_DEG)
        if near.any():
            latencies.append(float(times[np.argmax(near)] - onset))
        else:
            missed += 1
            latencies.append(math.inf)  # never looked at: counts against the percentiles
    return {
        "file": str(path), "duration_s": round(last - first, 3), "levels": levels,
        "proposals": proposals, "proposals_per_min": round(proposals / minutes, 3),
        "outcomes": counts,
        "share": {k: (round(v / len(robot), 4) if robot else None) for k, v in counts.items()},
        "decision_s_median": percentile(decided, 50), "decisions": len(decided),
        "teacher_initiated": len(teacher), "teacher_initiated_per_min": round(len(teacher) / minutes, 3),
        "attention": {"speeches": len(latencies), "never_looked_at": missed,
                      "onset_to_pointing_s_p50": percentile(latencies, 50),
                      "onset_to_pointing_s_p95": percentile(latencies, 95),
                      "speech_time_looked_at": round(looked / spoken, 4) if spoken else None,
                      "pointing_deg": POINTING_DEG},
    }


def autonomy_summary(m: dict[str, Any]) -> str:
    def f(x: Any, unit: str = "") -> str:
        return "n/a" if x is None else f"{x:.2f}{unit}"

    share = m["share"]
    a = m["attention"]
    return "\n".join([
        f"{Path(m['file']).name}: {m['duration_s']:.1f} s, {m['proposals']} proposals "
        f"({m['proposals_per_min']:.2f}/min), {m['teacher_initiated']} teacher-initiated actions "
        f"({m['teacher_initiated_per_min']:.2f}/min)",
        "  outcomes   " + "  ".join(f"{k} {m['outcomes'][k]} ({f(share[k])})" for k in ROBOT_OUTCOMES),
        f"  decision   median {f(m['decision_s_median'], ' s')} over {m['decisions']} teacher decisions",
        f"  attention  {a['speeches']} speeches, onset to pointing (within {a['pointing_deg']:g} deg) p50 "
        f"{f(a['onset_to_pointing_s_p50'], ' s')} p95 {f(a['onset_to_pointing_s_p95'], ' s')}, "
        f"speaker looked at {f(a['speech_time_looked_at'])} of speech time, never looked at {a['never_looked_at']}",
    ])
