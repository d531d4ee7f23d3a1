"""Fluency metrics while a trial runs: actions start and stop as they happen, `snapshot(now)` reads the figures.

Idle and concurrency are accumulated by a sweep: each event (a start or a stop) first credits the time since
the previous event to whichever agents were active, then changes the active counts, so an event costs
O(log n) and a snapshot O(1) plus the hand-overs still open. Hand-overs are kept per group of actions that
share a start time; a group's terms (within it, and the bridge to the next group) are fixed, and folded into
a running sum, once every action of both groups has stopped and no further action can join the next group.
Only the terms around running actions are recomputed at a snapshot, because a running action's end is `now`.

Events normally arrive in time order. One that arrives late (an experimenter labelling an action after the
fact, a stop time earlier than an event already seen) makes the calculator replay its whole history from T0,
which is still exact, just O(n log n) once.

All sums are exact `Fraction`s and the final figures go through the same `build_result` as the batch
computation, so a snapshot equals `compute_metrics(live.updates(), t0=live.t0, t1=now)` bit for bit.
"""

from __future__ import annotations

import heapq
from collections.abc import Sequence
from dataclasses import dataclass, field
from fractions import Fraction

from . import intervals
from .fluency import AGENT_RANK, Handovers, Measures, build_result, check_direction
from .model import Agent, FdelDirection, FluencyResult, Intervention, StateUpdate, UnfinishedAction

_START, _STOP = 0, 1


@dataclass(slots=True)
class _Record:
    update: StateUpdate
    start_seq: int
    stop_seq: int | None = None
    # Sweep state, reset on replay.
    group: int | None = None
    stop_swept: bool = False


@dataclass(slots=True)
class _Group:
    start: float
    members: list[int] = field(default_factory=list)
    running: int = 0  # members whose stop has not been swept yet


@dataclass(slots=True)
class _Sweep:
    """Everything derived from the records; thrown away and rebuilt on replay."""

    t0: float
    clock: float
    heap: list[tuple[float, int, int, int]] = field(default_factory=list)  # (time, seq, kind, record id)
    active: dict[str, int] = field(default_factory=lambda: {"human": 0, "robot": 0})
    human: Fraction = Fraction(0)
    robot: Fraction = Fraction(0)
    concurrent: Fraction = Fraction(0)
    either: Fraction = Fraction(0)
    started: dict[str, int] = field(default_factory=lambda: {"human": 0, "robot": 0})
    groups: list[_Group] = field(default_factory=list)
    unsettled: set[int] = field(default_factory=set)
    settled: Handovers = field(default_factory=Handovers)

    def credited(self, until: float) -> Measures:
        """The measures as they stand at `until` (>= clock), without moving the clock."""
        d = intervals.length(self.clock, until) if until > self.clock else Fraction(0)
        h, r = self.active["human"] > 0, self.active["robot"] > 0
        return Measures(
            human=self.human + (d if h else 0),
            robot=self.robot + (d if r else 0),
            concurrent=self.concurrent + (d if h and r else 0),
            either=self.either + (d if h or r else 0),
        )


class LiveMetrics:
    """Incremental fluency calculator for one trial.

    `t0` is the study start; without it T0 is the earliest start seen so far. Times before an explicit `t0`
    are refused (the trial had not begun). Handles returned by `start`/`add` identify actions for `stop`.
    """

    def __init__(self, t0: float | None = None, fdel_direction: FdelDirection = "both") -> None:
        self._fixed_t0 = t0
        self._direction = check_direction(fdel_direction)
        self._records: list[_Record] = []
        self._seq = 0
        self._reached: float | None = None  # latest time the sweep has been advanced to
        self._sweep: _Sweep | None = None if t0 is None else _Sweep(t0=t0, clock=t0)

    # ---- recording -------------------------------------------------------------------------------------

    @property
    def t0(self) -> float | None:
        return None if self._sweep is None else self._sweep.t0

    def start(self, agent: Agent, action: str, t: float) -> int:
        """An action begins at t; returns its handle."""
        return self.add(StateUpdate(agent=agent, action=action, start=t))

    def stop(self, handle: int, t: float) -> StateUpdate:
        """The action `handle` ends at t; returns its completed state update."""
        rec = self._record(handle)
        if rec.update.stop is not None:
            raise ValueError(f"action {handle} ({rec.update.action!r}) already stopped at {rec.update.stop:g} s")
        rec.update = StateUpdate(agent=rec.update.agent, action=rec.update.action, start=rec.update.start, stop=t)
        rec.stop_seq = self._next_seq()
        self._schedule(handle, rec, stop_only=True)
        return rec.update

    def add(self, update: StateUpdate) -> int:
        """Record an action known whole or in part (stop None: still running); returns its handle."""
        if self._fixed_t0 is not None and update.start < self._fixed_t0:
            raise ValueError(
                f"{update.agent} action {update.action!r} starts at {update.start:g} s, before the study start "
                f"t0 = {self._fixed_t0:g} s: correct the time or create LiveMetrics with an earlier t0"
            )
        rec = _Record(update=update, start_seq=self._next_seq())
        if update.stop is not None:
            rec.stop_seq = self._next_seq()
        self._records.append(rec)
        handle = len(self._records) - 1
        self._schedule(handle, rec, stop_only=False)
        return handle

    @property
    def pending_groups(self) -> int:
        """Start-time groups whose hand-overs a snapshot still recomputes; stays small as actions stop."""
        return 0 if self._sweep is None else len(self._sweep.unsettled)

    def updates(self) -> list[StateUpdate]:
        """Every action recorded so far, running ones with stop None, in the order they were added."""
        return [r.update for r in self._records]

    def snapshot(
        self,
        now: float,
        interventions: Sequence[Intervention] | None = None,
        planned_subtasks: int | None = None,
    ) -> FluencyResult:
        """Metrics over [T0, now]; running actions count up to `now` and are listed as unfinished."""
        sweep = self._sweep
        if sweep is None:
            raise ValueError("no actions yet and no t0: start an action or create LiveMetrics with t0")
        if now < sweep.clock:
            raise ValueError(f"now ({now:g} s) is before the last event ({sweep.clock:g} s): pass the current time")
        self._advance(now)
        sweep = self._sweep
        assert sweep is not None
        handovers = sweep.settled
        for i in sweep.unsettled:
            handovers = handovers + self._group_handovers(sweep, i, now)
        unfinished = [
            UnfinishedAction(agent=r.update.agent, action=r.update.action, start=r.update.start)
            for r in self._records
            if r.update.stop is None and r.group is not None
        ]
        return build_result(
            t0=sweep.t0,
            t1=float(now),
            measures=sweep.credited(now),
            handovers=handovers,
            n_human=sweep.started["human"],
            n_robot=sweep.started["robot"],
            unfinished=unfinished,
            fdel_direction=self._direction,
            interventions=None if interventions is None else list(interventions),
            planned_subtasks=planned_subtasks,
        )

    # ---- sweep -----------------------------------------------------------------------------------------

    def _record(self, handle: int) -> _Record:
        if not 0 <= handle < len(self._records):
            raise ValueError(f"unknown action handle {handle}: use the value start() or add() returned")
        return self._records[handle]

    def _next_seq(self) -> int:
        self._seq += 1
        return self._seq

    def _schedule(self, handle: int, rec: _Record, *, stop_only: bool) -> None:
        u = rec.update
        sweep = self._sweep
        first_time = u.stop if stop_only else u.start
        assert first_time is not None
        # Late: before an event already swept, or (without a fixed t0) before the T0 assumed so far.
        if sweep is None or first_time < sweep.clock or first_time < sweep.t0:
            self._replay()
            return
        assert sweep is not None
        if not stop_only:
            heapq.heappush(sweep.heap, (u.start, rec.start_seq, _START, handle))
        if u.stop is not None:
            assert rec.stop_seq is not None
            heapq.heappush(sweep.heap, (u.stop, rec.stop_seq, _STOP, handle))
        self._advance(u.stop if stop_only else u.start)

    def _replay(self) -> None:
        t0 = self._fixed_t0 if self._fixed_t0 is not None else min(r.update.start for r in self._records)
        sweep = _Sweep(t0=t0, clock=t0)
        for handle, rec in enumerate(self._records):
            rec.group, rec.stop_swept = None, False
            sweep.heap.append((rec.update.start, rec.start_seq, _START, handle))
            if rec.update.stop is not None:
                assert rec.stop_seq is not None
                sweep.heap.append((rec.update.stop, rec.stop_seq, _STOP, handle))
        heapq.heapify(sweep.heap)
        self._sweep = sweep
        latest = max(r.update.start for r in self._records)
        self._advance(latest if self._reached is None else max(self._reached, latest))

    def _advance(self, until: float) -> None:
        sweep = self._sweep
        assert sweep is not None
        self._reached = until if self._reached is None else max(self._reached, until)
        while sweep.heap and sweep.heap[0][0] <= self._reached:
            time, _, kind, handle = heapq.heappop(sweep.heap)
            self._credit(sweep, time)
            rec = self._records[handle]
            agent = rec.update.agent
            if kind == _START:
                sweep.active[agent] += 1
                sweep.started[agent] += 1
                if not sweep.groups or sweep.groups[-1].start != time:
                    sweep.groups.append(_Group(start=time))
                    sweep.unsettled.add(len(sweep.groups) - 1)
                group_index = len(sweep.groups) - 1
                sweep.groups[group_index].members.append(handle)
                sweep.groups[group_index].running += 1
                rec.group = group_index
            else:
                sweep.active[agent] -= 1
                rec.stop_swept = True
                assert rec.group is not None
                group_index = rec.group
                sweep.groups[group_index].running -= 1
            last = len(sweep.groups) - 1
            for i in {group_index - 1, group_index, last - 2, last - 1}:
                self._try_settle(sweep, i)

    @staticmethod
    def _credit(sweep: _Sweep, time: float) -> None:
        m = sweep.credited(time)
        sweep.human, sweep.robot, sweep.concurrent, sweep.either = m.human, m.robot, m.concurrent, m.either
        sweep.clock = max(sweep.clock, time)

    def _try_settle(self, sweep: _Sweep, i: int) -> None:
        """Fold group i's hand-overs into the running sum once nothing can change them any more."""
        if i not in sweep.unsettled or i + 1 >= len(sweep.groups):
            return
        nxt = sweep.groups[i + 1]
        if sweep.groups[i].running or nxt.running or not sweep.clock > nxt.start:
            return
        sweep.settled = sweep.settled + self._group_handovers(sweep, i, sweep.clock)
        sweep.unsettled.discard(i)

    def _group_handovers(self, sweep: _Sweep, i: int, now: float) -> Handovers:
        """Hand-overs inside group i and from its last action to group i+1's first, ends clipped to now."""

        def key(handle: int) -> tuple[float, int, str]:
            return (self._end(handle, now), AGENT_RANK[self._records[handle].update.agent],
                    self._records[handle].update.action)

        ordered = sorted(sweep.groups[i].members, key=key)
        pairs = list(zip(ordered, ordered[1:]))
        if i + 1 < len(sweep.groups):
            pairs.append((ordered[-1], min(sweep.groups[i + 1].members, key=key)))
        terms = []
        for a, b in pairs:
            ua, ub = self._records[a].update, self._records[b].update
            if ua.agent != ub.agent:
                terms.append((ua.agent, ub.agent, intervals.length(self._end(a, now), ub.start)))
        return Handovers.from_terms(terms)

    def _end(self, handle: int, now: float) -> float:
        rec = self._records[handle]
        if rec.stop_swept:
            assert rec.update.stop is not None
            return rec.update.stop
        return now
