"""One trial's clock and record on the bus: robot and human state updates, the experimenter's labels,
interventions, the trial's state, and the live fluency metrics they feed.

Topics: /study/state_updates (vr_teleop_msgs/StateUpdate, at each start and stop), /study/interventions,
/study/trial (latched TrialState), /study/metrics (FluencyMetrics, 1 Hz and a final one). Services for the
experimenter: /study/label/start and /study/label/stop (LabelAction: a human action starts or stops now),
/study/label/add (AddLabel: a whole action the plan did not foresee). Labels published by the dashboard on
/study/labels (Event kinds human_action_start, human_action_stop, intervention) are taken the same way.

Times are seconds since the trial's clock started (T0 = 0). Everything published is what a session recording
keeps, so `vr-teleop metrics RECORDING.mcap` recomputes the same figures offline.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import logging
from collections.abc import Callable
from dataclasses import dataclass

from client_protocol import names
from client_protocol.events import EventKind, Label
from simclock import WALL, Clock

from ..core.bus import SERVER_NODE, Bus, BusError, Published
from ..core.tasks import cancel_and_wait
from .metrics import FluencyResult, Intervention, LiveMetrics, StateUpdate

log = logging.getLogger(__name__)

METRICS_PERIOD_S = 1.0
LABEL_KINDS = (EventKind.HUMAN_ACTION_START, EventKind.HUMAN_ACTION_STOP, EventKind.INTERVENTION)


@dataclass
class Running:
    id: int
    agent: str
    action: str
    start: float
    handle: int
    source: str
    detail: str


class TrialLog:
    def __init__(self, bus: Bus, study: str, trial: str, modules: tuple[str, str, str], planned_subtasks: int,
                 clock: Clock = WALL) -> None:
        self.bus = bus
        self.clock = clock
        self.study = study
        self.trial = trial
        self.modules = modules
        self.planned_subtasks = planned_subtasks
        self._t0: float | None = None
        self.live = LiveMetrics(t0=0.0)
        self._ids = itertools.count(1)
        self.running: dict[int, Running] = {}
        self.interventions: list[Intervention] = []
        self.events: set[tuple[str, str, str]] = set()  # (agent, action, "start"|"stop") seen so far
        self._changed = asyncio.Event()
        self.listeners: list[Callable[[str, str, str], None]] = []
        self.state = "waiting"
        self.current = ""
        self.awaiting_human = ""  # the human action awaited (TrialState.awaiting_human)
        self.final: FluencyResult | None = None
        self._task: asyncio.Task[None] | None = None
        self._subscription: int | None = None

    # ---- lifetime -----------------------------------------------------------------------------------------------
    def attach(self) -> None:
        bus = self.bus
        bus.declare_topic(names.STUDY_STATE_UPDATES_TOPIC, "vr_teleop_msgs/StateUpdate", persistent=True)
        bus.declare_topic(names.STUDY_INTERVENTIONS_TOPIC, "vr_teleop_msgs/Intervention", persistent=True)
        # latched for a page that opens mid-trial; history, not state (core/bus.py Topic.state): a recording that
        # starts later does not open with the previous trial's last state
        bus.declare_topic(names.STUDY_TRIAL_TOPIC, "vr_teleop_msgs/TrialState", latched=True, persistent=True)
        bus.declare_topic(names.STUDY_METRICS_TOPIC, "vr_teleop_msgs/FluencyMetrics", persistent=True)
        bus.declare_topic(names.STUDY_LABELS_TOPIC, "vr_teleop_msgs/Event", persistent=True)
        self._subscription = bus.subscribe(SERVER_NODE, names.STUDY_LABELS_TOPIC, None, self._on_label_event)
        bus.provide(names.STUDY_LABEL_START_SERVICE, "vr_teleop_msgs/LabelAction", self._label_start)
        bus.provide(names.STUDY_LABEL_STOP_SERVICE, "vr_teleop_msgs/LabelAction", self._label_stop)
        bus.provide(names.STUDY_LABEL_ADD_SERVICE, "vr_teleop_msgs/AddLabel", self._label_add)

    def detach(self) -> None:
        if self._subscription is not None:
            self.bus.unsubscribe(names.STUDY_LABELS_TOPIC, self._subscription)
        for name in (names.STUDY_LABEL_START_SERVICE, names.STUDY_LABEL_STOP_SERVICE, names.STUDY_LABEL_ADD_SERVICE):
            with contextlib.suppress(BusError):
                self.bus.unadvertise_service(SERVER_NODE, name)

    def begin(self) -> None:
        """T0: the trial's clock starts now."""
        self._t0 = self.clock.monotonic()
        self.set_state("running")
        self._task = asyncio.ensure_future(self._metrics_loop())

    @property
    def started(self) -> bool:
        return self._t0 is not None

    def now(self) -> float:
        if self._t0 is None:
            raise BusError(f"trial {self.trial} has not started")
        return self.clock.monotonic() - self._t0

    async def finish(self, state: str, message: str = "") -> FluencyResult:
        """T1: running actions stay unfinished (clipped); the final metrics are published and returned."""
        await cancel_and_wait(self._task)
        t1 = self.now()
        self.final = self.snapshot(t1)
        self.set_state(state, message=message, elapsed=t1)
        self._publish_metrics(self.final, final=True)
        return self.final

    # ---- state updates ------------------------------------------------------------------------------------------
    def start(self, agent: str, action: str, source: str, detail: str = "") -> int:
        t = self.now()
        handle = self.live.start(agent, action, t)  # type: ignore[arg-type]
        uid = next(self._ids)
        self.running[uid] = Running(uid, agent, action, t, handle, source, detail)
        self._publish_update(self.running[uid], finished=False, stop=0.0, succeeded=False)
        self._note(agent, action, "start")
        return uid

    def stop(self, uid: int, succeeded: bool = True) -> float:
        run = self.running.pop(uid, None)
        if run is None:
            raise BusError(f"action {uid} is not running")
        t = max(self.now(), run.start)
        self.live.stop(run.handle, t)
        self._publish_update(run, finished=True, stop=t, succeeded=succeeded)
        self._note(run.agent, run.action, "stop")
        return t

    def add(self, agent: str, action: str, start: float, stop: float | None, source: str) -> None:
        update = StateUpdate(agent=agent, action=action, start=start, stop=stop)  # validates agent and times
        handle = self.live.add(update)
        uid = next(self._ids)
        run = Running(uid, agent, action, start, handle, source, "")
        if stop is None:
            self.running[uid] = run
            self._publish_update(run, finished=False, stop=0.0, succeeded=False)
        else:
            self._publish_update(run, finished=True, stop=stop, succeeded=True)
        self._note(agent, action, "start")
        if stop is not None:
            self._note(agent, action, "stop")

    def intervention(self, kind: str, subtask: str, start: float, stop: float, note: str = "") -> None:
        self.interventions.append(Intervention(start=start, stop=stop, subtask=subtask or None, note=note))
        self.bus.publish(names.STUDY_INTERVENTIONS_TOPIC, {"trial": self.trial, "kind": kind, "subtask": subtask,
                                                           "start": start, "stop": stop, "note": note})

    def _publish_update(self, run: Running, *, finished: bool, stop: float, succeeded: bool) -> None:
        self.bus.publish(names.STUDY_STATE_UPDATES_TOPIC, {
            "trial": self.trial, "id": run.id, "agent": run.agent, "action": run.action, "start": run.start,
            "finished": finished, "stop": stop, "succeeded": succeeded, "source": run.source, "detail": run.detail})

    def _note(self, agent: str, action: str, phase: str) -> None:
        self.events.add((agent, action, phase))
        for listener in list(self.listeners):
            listener(agent, action, phase)
        self._changed.set()
        self._changed = asyncio.Event()

    def happened(self, agent: str, action: str, phase: str = "stop") -> bool:
        return (agent, action, phase) in self.events

    async def changed(self) -> None:
        """Returns at the next start or stop of any action."""
        await self._changed.wait()

    # ---- trial state and metrics --------------------------------------------------------------------------------
    def set_state(self, state: str, *, current: str | None = None, message: str = "",
                  elapsed: float | None = None, awaiting_human: str = "") -> None:
        """`current` (words for people) changes only when given; `awaiting_human` goes with it."""
        self.state = state
        if current is not None:
            self.current, self.awaiting_human = current, awaiting_human
        perception, decision, action = self.modules
        self.bus.publish(names.STUDY_TRIAL_TOPIC, {
            "study": self.study, "trial": self.trial, "state": state, "perception": perception,
            "decision": decision, "action": action,
            "elapsed": elapsed if elapsed is not None else (self.now() if self.started else 0.0),
            "current": self.current, "planned_subtasks": self.planned_subtasks, "message": message,
            "awaiting_human": self.awaiting_human})

    def snapshot(self, now: float | None = None) -> FluencyResult:
        return self.live.snapshot(self.now() if now is None else now, interventions=self.interventions,
                                  planned_subtasks=self.planned_subtasks)

    async def _metrics_loop(self) -> None:
        while True:
            await asyncio.sleep(METRICS_PERIOD_S)
            try:
                self._publish_metrics(self.snapshot(), final=False)
            except Exception:  # a metrics hiccup must never stop a trial
                log.exception("live metrics of trial %s failed", self.trial)

    def _publish_metrics(self, r: FluencyResult, *, final: bool) -> None:
        def v(x: float | None) -> float:
            return 0.0 if x is None else x

        self.bus.publish(names.STUDY_METRICS_TOPIC, {
            "trial": self.trial, "final": final, "defined": r.h_idle is not None, "elapsed": r.t1 - r.t0,
            "h_idle": v(r.h_idle), "r_idle": v(r.r_idle), "c_act": v(r.c_act), "f_del": v(r.f_del),
            "both_idle": v(r.both_idle), "effectiveness": -1.0 if r.effectiveness is None else r.effectiveness,
            "human_actions": r.counts.human_actions, "robot_actions": r.counts.robot_actions,
            "unfinished": r.counts.unfinished, "detail": json.dumps(r.to_json_dict())})

    # ---- the experimenter's labels ------------------------------------------------------------------------------
    def label_start(self, action: str) -> float:
        action = action.strip()
        if not action:
            raise BusError("name the human action to start (e.g. take_side_left)")
        self.start("human", action, "label")
        return self.now()

    def label_stop(self, action: str) -> float:
        action = action.strip()
        humans = [r for r in self.running.values() if r.agent == "human" and (not action or r.action == action)]
        if not humans:
            running = [r.action for r in self.running.values() if r.agent == "human"]
            raise BusError(f"no human action {action!r} is running (running: {', '.join(running) or 'none'}); "
                           "start it first, or use /study/label/add for one whose start was missed")
        return self.stop(max(humans, key=lambda r: r.start).id)

    async def _label_start(self, req: object) -> dict[str, object]:
        t = self.label_start(req.action)  # type: ignore[attr-defined]
        return {"success": True, "message": f"{req.action} started at {t:.2f} s", "time": t}  # type: ignore

    async def _label_stop(self, req: object) -> dict[str, object]:
        t = self.label_stop(req.action)  # type: ignore[attr-defined]
        return {"success": True, "message": f"stopped at {t:.2f} s", "time": t}

    async def _label_add(self, req: object) -> dict[str, object]:
        agent, action = req.agent.strip(), req.action.strip()  # type: ignore[attr-defined]
        start, stop = req.start, req.stop  # type: ignore[attr-defined]
        if agent not in ("human", "robot"):
            raise BusError(f"agent must be human or robot, not {agent!r}")
        if not action:
            raise BusError("name the action")
        try:
            self.add(agent, action, start, None if stop < 0 else stop, "label")
        except ValueError as exc:
            raise BusError(f"label {action!r} refused: {exc}") from None
        return {"success": True, "message": f"{agent} {action} added"}

    def _on_label_event(self, published: Published) -> None:
        """The dashboard's label buttons: Event kinds human_action_start, human_action_stop, intervention."""
        kind, detail = published.data["kind"], published.data["detail"]
        try:
            if kind not in LABEL_KINDS:
                raise ValueError(f"kind {kind!r} is not a label; labels are {', '.join(LABEL_KINDS)}")
            action = Label.model_validate_json(detail or "{}").action
            if not self.started or self.state != "running":
                raise BusError(f"trial {self.trial} is not running")
            if kind == EventKind.HUMAN_ACTION_START:
                self.label_start(action)
            elif kind == EventKind.HUMAN_ACTION_STOP:
                self.label_stop(action)
            else:
                t = self.now()
                self.intervention("label", action, t, t, "marked by the experimenter")
        except (BusError, ValueError) as exc:
            self.bus.report(published.sender, "warning", f"label not taken: {exc}")
