"""The decision interface and the services that reach whichever module runs the trial.

/decision/teleop (DecisionCommand: object, action): the operator's or experimenter's command (Wizard of Oz).
/decision/preempt (std_srvs/Trigger): the participant stops the study; the robot holds where it is.
/decision/override (DecisionOverride: succeeded, note): the experimenter ends the running robot action (or the
awaited human action) as succeeded or failed, and the plan moves on. Each override is an intervention.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable
from dataclasses import dataclass, field

from client_protocol import names

from ...core.bus import SERVER_NODE, Bus, BusError

from ...core.tasks import cancel_and_wait
from ..action import ActionModule
from ..studyfile import Study
from ..trial import TrialLog



@dataclass
class Current:
    """The robot action running now (its task and state-update id) or the human action awaited."""

    subtask: str = ""
    task: asyncio.Task[bool] | None = None
    uid: int | None = None
    human: str = ""


@dataclass
class DecisionContext:
    study: Study
    log: TrialLog
    actions: ActionModule
    stalls: frozenset[str] = frozenset()
    current: Current = field(default_factory=Current)
    finished: asyncio.Event = field(default_factory=asyncio.Event)
    outcome: str = ""  # completed, preempted or failed

    def subtask(self, action: str, part_index: int) -> str:
        return f"{action}_{self.study.parts[part_index].name}"

    def start_action(self, action: str, part_index: int) -> asyncio.Task[bool]:
        """Run a robot action as the current one; only one runs at a time."""
        name = self.subtask(action, part_index)
        task = asyncio.ensure_future(self.actions.run_action(action, part_index, stall=name in self.stalls))
        self.current = Current(subtask=name, task=task)
        self.log.set_state("running", current=name)
        return task

    def running_uid(self, subtask: str) -> int | None:
        for uid, run in self.log.running.items():
            if run.agent == "robot" and run.action == subtask:
                return uid
        return None

    def end(self, outcome: str) -> None:
        if not self.finished.is_set():
            self.outcome = outcome
            self.finished.set()


class Decision:
    """A decision module: runs the trial until it is complete, preempted or failed."""

    kind = ""

    def __init__(self, ctx: DecisionContext) -> None:
        self.ctx = ctx

    async def run(self) -> str:
        raise NotImplementedError

    async def teleop(self, obj: str, action: str) -> str:
        raise BusError(f"the {self.kind} decision module takes no teleoperation commands in this trial")

    async def preempt(self) -> None:
        ctx = self.ctx
        task = ctx.current.task
        if task is not None and not task.done():
            await cancel_and_wait(task)
        here = ctx.actions.robot.joint_state().as_dict()
        ctx.actions.robot.set_joint_targets(here)  # hold where it is
        t = ctx.log.now()
        ctx.log.intervention("preempt", ctx.current.subtask, t, t, "the participant stopped the study")
        ctx.end("preempted")

    async def override(self, succeeded: bool, note: str) -> str:
        ctx = self.ctx
        t = ctx.log.now()
        task = ctx.current.task
        if task is not None and not task.done():
            uid = ctx.running_uid(ctx.current.subtask)
            if uid is not None:
                ctx.actions.outcome[uid] = succeeded
                start = ctx.log.running[uid].start
            else:
                start = t
            await cancel_and_wait(task)
            ctx.log.intervention("override", ctx.current.subtask, start, t, note)
            return f"{ctx.current.subtask} marked {'succeeded' if succeeded else 'failed'}"
        if ctx.current.human:
            name = ctx.current.human
            ctx.log.add("human", name, t, t, "override")  # its stop is what the plan waits for
            ctx.log.intervention("override", name, t, t, note)
            return f"human action {name} marked done"
        raise BusError("nothing to override: no robot action is running and no human action is awaited")


class DecisionHost:
    """Provides the decision services on the bus and forwards them to the trial's module."""

    def __init__(self, bus: Bus, module: Decision,
                 observer: Callable[[str, str, dict[str, object]], None] | None = None) -> None:
        """`observer(caller, service, request)` hears each command the module took (a live study logs them)."""
        self.bus = bus
        self.module = module
        self.observer = observer

    def _took(self, service: str, request: dict[str, object]) -> None:
        if self.observer is not None:
            self.observer(Bus.caller(), service, request)

    def start(self) -> None:
        self.bus.provide(names.DECISION_TELEOP_SERVICE, "vr_teleop_msgs/DecisionCommand", self._teleop)
        self.bus.provide(names.DECISION_PREEMPT_SERVICE, "std_srvs/Trigger", self._preempt)
        self.bus.provide(names.DECISION_OVERRIDE_SERVICE, "vr_teleop_msgs/DecisionOverride", self._override)

    def stop(self) -> None:
        for name in (names.DECISION_TELEOP_SERVICE, names.DECISION_PREEMPT_SERVICE, names.DECISION_OVERRIDE_SERVICE):
            with contextlib.suppress(BusError):
                self.bus.unadvertise_service(SERVER_NODE, name)

    def _check_running(self) -> None:
        if self.module.ctx.finished.is_set() or self.module.ctx.log.state != "running":
            raise BusError(f"trial {self.module.ctx.log.trial} is not running ({self.module.ctx.log.state})")

    async def _teleop(self, req: object) -> dict[str, object]:
        self._check_running()
        message = await self.module.teleop(req.object.strip(), req.action.strip())  # type: ignore[attr-defined]
        self._took(names.DECISION_TELEOP_SERVICE, {"object": req.object.strip(), "action": req.action.strip()})  # type: ignore[attr-defined]
        return {"success": True, "message": message}

    async def _preempt(self, _req: object) -> dict[str, object]:
        self._check_running()
        await self.module.preempt()
        self._took(names.DECISION_PREEMPT_SERVICE, {})
        return {"success": True, "message": "trial preempted; the robot holds"}

    async def _override(self, req: object) -> dict[str, object]:
        self._check_running()
        message = await self.module.override(req.succeeded, req.note)  # type: ignore[attr-defined]
        self._took(names.DECISION_OVERRIDE_SERVICE, {"succeeded": req.succeeded, "note": req.note})  # type: ignore[attr-defined]
        return {"success": True, "message": message}
