"""Batch computation of Hoffman's fluency metrics and the team metrics from a trial's state updates.

The rules this module fixes (fluency.md leaves them to the implementation):

Window. T0 defaults to the earliest start. T1 defaults to the latest known time: the latest stop of a
finished action, or the start of an unfinished one if that is later (an unfinished action is known to
have run at least until its start, nothing more). Every action is clipped to [T0, T1]; an action that
does not touch the window is left out of every figure and count. Unfinished actions run to T1 and are
listed as unfinished.

Idle and concurrency. Each agent's intervals are first united (overlapping labels of one agent count once),
then H-IDLE = 1 - |H|/T, R-IDLE = 1 - |R|/T, C-ACT = |H n R|/T, BOTH-IDLE = 1 - |H u R|/T, all exact (see
`intervals`), so H-IDLE + R-IDLE + C-ACT = 1 + BOTH-IDLE up to the final rounding of each figure.

F-DEL. Actions (clipped) are ordered by start; ties at equal start are broken by the earlier end first,
then by agent ("human" before "robot"), then by action name, so the order depends on the data alone, never
on input order. Each consecutive pair of different agents is a hand-over, with term next.start - prev.end
(negative when the next action starts before the previous one ends). With the tie rule, two actions of
different agents starting at the same instant form a hand-over whose term is minus the shorter one's
length, i.e. minus their overlap. F-DEL = sum of the terms / T, over both directions (default), or only
human-to-robot pairs (the wait the human experiences) or only robot-to-human pairs.

Effectiveness (only when interventions are known; an empty list means "known: none"). The share of the
robot's planned subtasks completed without a human intervention:
    effectiveness = 1 - intervened_subtasks / planned_subtasks
where intervened_subtasks counts the distinct `subtask` names among the interventions touching the window,
plus one for each intervention that names none, and planned_subtasks is given by the caller or defaults to
the number of robot actions in the window. One intervention among 20 planned robot subtasks gives 0.95,
the teleoperated trial's figure. Intervention time is reported (`intervention_s`) but does not enter the
score, so a long takeover of one subtask costs what a short one does.

Zero-length task (T1 == T0): fractions of T are undefined, so they are None and `undefined_reason` says
why; efficiency is 0 s, counts and effectiveness are still given.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction
from types import MappingProxyType
from typing import Any

from . import intervals
from .model import (
    FDEL_DIRECTIONS,
    Counts,
    FdelDirection,
    FluencyResult,
    Intervention,
    StateUpdate,
    UnfinishedAction,
)

# Tie-break for hand-over order at equal start and end: data-only, so input order never matters.
AGENT_RANK = MappingProxyType({"human": 0, "robot": 1})


@dataclass(frozen=True, slots=True)
class ClippedAction:
    """An action as it counts inside [T0, T1]."""

    agent: str
    action: str
    start: float
    end: float
    unfinished: bool

    def order_key(self) -> tuple[float, float, int, str]:
        return (self.start, self.end, AGENT_RANK[self.agent], self.action)


def _as_updates(updates: Iterable[StateUpdate | Mapping[str, Any]]) -> list[StateUpdate]:
    return [u if isinstance(u, StateUpdate) else StateUpdate.model_validate(u) for u in updates]


def default_window(updates: Sequence[StateUpdate]) -> tuple[float, float]:
    """(earliest start, latest stop or unfinished start); see the module docstring."""
    if not updates:
        raise ValueError("no state updates, so T0 and T1 cannot be inferred: add updates or pass both t0 and t1")
    t0 = min(u.start for u in updates)
    t1 = max(u.stop if u.stop is not None else u.start for u in updates)
    return t0, t1


def resolve_window(updates: Sequence[StateUpdate], t0: float | None, t1: float | None) -> tuple[float, float]:
    if t0 is None or t1 is None:
        d0, d1 = default_window(updates)
        t0 = d0 if t0 is None else t0
        t1 = d1 if t1 is None else t1
    if t1 < t0:
        raise ValueError(f"T1 ({t1:g} s) is before T0 ({t0:g} s): pass a t1 at or after t0")
    return float(t0), float(t1)


def clip_actions(updates: Iterable[StateUpdate], t0: float, t1: float) -> list[ClippedAction]:
    out = []
    for u in updates:
        end = u.stop if u.stop is not None else t1
        if u.start > t1 or end < t0:
            continue
        out.append(ClippedAction(u.agent, u.action, max(u.start, t0), min(end, t1), u.stop is None))
    return out


def handover_terms(actions: Iterable[ClippedAction]) -> list[tuple[str, str, Fraction]]:
    """(prev agent, next agent, exact next.start - prev.end) for each hand-over, in start order."""
    ordered = sorted(actions, key=ClippedAction.order_key)
    return [
        (prev.agent, nxt.agent, intervals.length(prev.end, nxt.start))
        for prev, nxt in zip(ordered, ordered[1:])
        if prev.agent != nxt.agent
    ]


@dataclass(frozen=True, slots=True)
class Handovers:
    """Hand-over terms summed exactly per direction (keyed by the agent that hands over)."""

    human_to_robot_s: Fraction = Fraction(0)
    robot_to_human_s: Fraction = Fraction(0)
    human_to_robot: int = 0
    robot_to_human: int = 0

    @classmethod
    def from_terms(cls, terms: Iterable[tuple[str, str, Fraction]]) -> Handovers:
        out = cls()
        for prev_agent, _, term in terms:
            out = out + (cls(term, Fraction(0), 1, 0) if prev_agent == "human" else cls(Fraction(0), term, 0, 1))
        return out

    def __add__(self, other: Handovers) -> Handovers:
        return Handovers(
            self.human_to_robot_s + other.human_to_robot_s,
            self.robot_to_human_s + other.robot_to_human_s,
            self.human_to_robot + other.human_to_robot,
            self.robot_to_human + other.robot_to_human,
        )

    def sum_for(self, direction: FdelDirection) -> Fraction:
        if direction == "human_to_robot":
            return self.human_to_robot_s
        if direction == "robot_to_human":
            return self.robot_to_human_s
        return self.human_to_robot_s + self.robot_to_human_s


def check_direction(direction: str) -> FdelDirection:
    if direction not in FDEL_DIRECTIONS:
        raise ValueError(f"unknown F-DEL direction {direction!r}: use one of {', '.join(FDEL_DIRECTIONS)}")
    return direction  # type: ignore[return-value]


def team_effectiveness(
    interventions: Sequence[Intervention], planned_subtasks: int
) -> tuple[Fraction | None, int]:
    """(1 - intervened/planned, intervened); None when nothing was planned. See the module docstring."""
    named = {iv.subtask for iv in interventions if iv.subtask is not None}
    intervened = len(named) + sum(1 for iv in interventions if iv.subtask is None)
    if planned_subtasks < 0:
        raise ValueError(f"planned subtasks must be >= 0, got {planned_subtasks}")
    if intervened > planned_subtasks:
        raise ValueError(
            f"{intervened} intervened subtasks but only {planned_subtasks} planned: "
            "pass the number of planned robot subtasks (planned_subtasks / --planned-subtasks)"
        )
    if planned_subtasks == 0:
        return None, intervened
    return 1 - Fraction(intervened, planned_subtasks), intervened


@dataclass(frozen=True, slots=True)
class Measures:
    """Exact seconds that the fractions are made of; the batch and the live calculator both produce these."""

    human: Fraction
    robot: Fraction
    concurrent: Fraction
    either: Fraction


def build_result(
    *,
    t0: float,
    t1: float,
    measures: Measures,
    handovers: Handovers,
    n_human: int,
    n_robot: int,
    unfinished: Sequence[UnfinishedAction],
    fdel_direction: FdelDirection,
    interventions: Sequence[Intervention] | None,
    planned_subtasks: int | None,
) -> FluencyResult:
    """Turn exact measures into the result; shared by batch and live so they round identically."""
    total = intervals.length(t0, t1)
    fdel_sum = handovers.sum_for(fdel_direction)
    both_idle_s = total - measures.either
    reasons: list[str] = []

    def frac(x: Fraction) -> float | None:
        return None if total == 0 else float(x / total)

    if total == 0:
        reasons.append("T1 equals T0 (zero-length task): fractions of T are undefined")

    counts: dict[str, Any] = dict(
        human_actions=n_human,
        robot_actions=n_robot,
        handovers=handovers.human_to_robot + handovers.robot_to_human,
        handovers_human_to_robot=handovers.human_to_robot,
        handovers_robot_to_human=handovers.robot_to_human,
        unfinished=len(unfinished),
    )
    effectiveness = None
    intervention_s = None
    if interventions is not None:
        window = [
            iv for iv in interventions
            if iv.start <= t1 and (iv.stop if iv.stop is not None else t1) >= t0
        ]
        planned = n_robot if planned_subtasks is None else planned_subtasks
        eff, intervened = team_effectiveness(window, planned)
        effectiveness = None if eff is None else float(eff)
        if eff is None:
            reasons.append("no planned robot subtasks: effectiveness is undefined")
        spans = [(iv.start, iv.stop if iv.stop is not None else t1) for iv in window]
        intervention_s = float(intervals.measure(intervals.clip(spans, t0, t1)))
        counts.update(interventions=len(window), intervened_subtasks=intervened, planned_subtasks=planned)

    return FluencyResult(
        t0=t0,
        t1=t1,
        efficiency_s=float(total),
        h_idle=frac(total - measures.human),
        r_idle=frac(total - measures.robot),
        c_act=frac(measures.concurrent),
        both_idle=frac(both_idle_s),
        f_del=frac(fdel_sum),
        fdel_direction=fdel_direction,
        effectiveness=effectiveness,
        interventions_known=interventions is not None,
        counts=Counts(**counts),
        unfinished=sorted(unfinished, key=lambda u: (u.start, AGENT_RANK[u.agent], u.action)),
        human_active_s=float(measures.human),
        robot_active_s=float(measures.robot),
        concurrent_s=float(measures.concurrent),
        both_idle_s=float(both_idle_s),
        fdel_sum_s=float(fdel_sum),
        intervention_s=intervention_s,
        undefined_reason="; ".join(reasons) or None,
    )


def compute_metrics(
    updates: Iterable[StateUpdate | Mapping[str, Any]],
    t0: float | None = None,
    t1: float | None = None,
    fdel_direction: FdelDirection = "both",
    interventions: Iterable[Intervention | Mapping[str, Any]] | None = None,
    planned_subtasks: int | None = None,
) -> FluencyResult:
    """Fluency and team metrics of one trial; the rules are in this module's docstring.

    Raises ValueError when the window cannot be inferred or is reversed, or the direction is unknown.
    """
    direction = check_direction(fdel_direction)
    ups = _as_updates(updates)
    ivs = None
    if interventions is not None:
        ivs = [iv if isinstance(iv, Intervention) else Intervention.model_validate(iv) for iv in interventions]
    t0, t1 = resolve_window(ups, t0, t1)
    actions = clip_actions(ups, t0, t1)
    human = [(a.start, a.end) for a in actions if a.agent == "human"]
    robot = [(a.start, a.end) for a in actions if a.agent == "robot"]
    measures = Measures(
        human=intervals.measure(human),
        robot=intervals.measure(robot),
        concurrent=intervals.measure(intervals.intersection(human, robot)),
        either=intervals.measure(human + robot),
    )
    unfinished = [
        UnfinishedAction(agent=u.agent, action=u.action, start=u.start)
        for u in ups
        if u.stop is None and u.start <= t1
    ]
    return build_result(
        t0=t0,
        t1=t1,
        measures=measures,
        handovers=Handovers.from_terms(handover_terms(actions)),
        n_human=sum(1 for a in actions if a.agent == "human"),
        n_robot=sum(1 for a in actions if a.agent == "robot"),
        unfinished=unfinished,
        fdel_direction=direction,
        interventions=ivs,
        planned_subtasks=planned_subtasks,
    )


def fluency_summary(name: str, r: FluencyResult) -> str:
    """A trial's fluency metrics in a few lines (`vr-teleop metrics`, `study run`)."""
    def f(x: float | None) -> str:
        return "  n/a" if x is None else f"{x:5.2f}"

    c = r.counts
    lines = [
        f"{name}: {c.human_actions} human and {c.robot_actions} robot actions, {c.unfinished} unfinished",
        f"T0 {r.t0:.2f} s   T1 {r.t1:.2f} s   efficiency {r.efficiency_s:.2f} s",
        f"  H-IDLE     {f(r.h_idle)}   human active {r.human_active_s:.2f} s",
        f"  R-IDLE     {f(r.r_idle)}   robot active {r.robot_active_s:.2f} s",
        f"  C-ACT      {f(r.c_act)}   both active {r.concurrent_s:.2f} s",
        f"  BOTH-IDLE  {f(r.both_idle)}   neither active {r.both_idle_s:.2f} s",
        f"  F-DEL      {f(r.f_del)}   {r.fdel_direction.replace('_', ' ')}; {c.handovers} hand-overs "
        f"({c.handovers_human_to_robot} human to robot, {c.handovers_robot_to_human} robot to human)",
    ]
    if r.interventions_known:
        lines.append(f"  effectiveness {f(r.effectiveness)}   {c.intervened_subtasks} of {c.planned_subtasks} "
                     f"planned robot subtasks intervened ({c.interventions} intervention"
                     f"{'' if c.interventions == 1 else 's'}, "
                     f"{r.intervention_s:.2f} s)")
    else:
        lines.append("  effectiveness  n/a   no interventions given (--interventions FILE)")
    for u in r.unfinished:
        lines.append(f"  unfinished: {u.agent} {u.action!r} from {u.start:.2f} s, clipped to T1")
    if r.undefined_reason:
        lines.append(f"  note: {r.undefined_reason}")
    return "\n".join(lines)

