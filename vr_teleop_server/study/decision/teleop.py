"""Teleoperated decision (Wizard of Oz, decision B): the robot does what the operator or experimenter commands.

A command names a part (or any object) and one of the study's actions. One robot action runs at a time; a command
while the robot is busy is refused with the running action's name. The trial is complete once every planned
robot subtask and every planned human action has stopped.
"""

from __future__ import annotations

import asyncio

from ...core.bus import BusError
from .base import Decision


class TeleopDecision(Decision):
    kind = "teleop"

    async def run(self) -> str:
        ctx = self.ctx
        robot = set(ctx.study.planned_robot_subtasks())
        human = set(ctx.study.planned_human_actions())
        while not ctx.finished.is_set():
            idle = ctx.current.task is None or ctx.current.task.done()
            if idle and all(ctx.log.happened("robot", s) for s in robot) and \
                    all(ctx.log.happened("human", h) for h in human):
                ctx.end("completed")
                break
            waits = [asyncio.ensure_future(ctx.log.changed()), asyncio.ensure_future(ctx.finished.wait())]
            await asyncio.wait(waits, timeout=0.2, return_when=asyncio.FIRST_COMPLETED)
            for w in waits:
                w.cancel()
        return ctx.outcome

    async def teleop(self, obj: str, action: str) -> str:
        ctx = self.ctx
        if action not in ctx.study.actions:
            raise BusError(f"unknown action {action!r}; actions: {', '.join(ctx.study.actions)}")
        try:
            index = ctx.study.part_index(obj)
        except KeyError as exc:
            raise BusError(str(exc.args[0])) from None
        if ctx.current.task is not None and not ctx.current.task.done():
            raise BusError(f"the robot is busy with {ctx.current.subtask}; wait for it, or override it")
        ctx.start_action(action, index)
        return f"{ctx.subtask(action, index)} started"
