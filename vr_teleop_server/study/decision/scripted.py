"""Scripted decision: a py_trees behaviour tree built from the study file's plan (decision A), and the
semi-autonomous variant whose `teleop: true` steps wait for the operator's command.

The tree is a memory Sequence of one leaf per plan step and part: a robot leaf runs the study's action
through the action module; a human leaf succeeds once the human action has been labelled stopped. The tree is
ticked every TICK_S and at every state update, from the event loop, so leaves never block.
"""

from __future__ import annotations

import asyncio

import py_trees
from py_trees.common import Status

from ...core.bus import BusError
from .base import Decision, DecisionContext

TICK_S = 0.05


class RobotStep(py_trees.behaviour.Behaviour):
    def __init__(self, ctx: DecisionContext, action: str, part_index: int, *, teleop: bool = False) -> None:
        super().__init__(name=ctx.subtask(action, part_index))
        self.ctx, self.action, self.part_index, self.teleop = ctx, action, part_index, teleop
        self.task: asyncio.Task[bool] | None = None
        self.commanded = False  # semi-autonomous: the operator has said go

    def initialise(self) -> None:
        self.task = None

    def update(self) -> Status:
        if self.task is None:
            if self.teleop and not self.commanded:
                self.ctx.log.set_state("running", current=f"awaiting operator: {self.name}")
                return Status.RUNNING
            self.task = self.ctx.start_action(self.action, self.part_index)
        if not self.task.done():
            return Status.RUNNING
        if self.task.cancelled():  # an override: it moves on, whatever its verdict
            return Status.SUCCESS
        return Status.SUCCESS if self.task.result() else Status.FAILURE


class HumanStep(py_trees.behaviour.Behaviour):
    def __init__(self, ctx: DecisionContext, action: str) -> None:
        super().__init__(name=action)
        self.ctx, self.action = ctx, action

    def update(self) -> Status:
        if self.ctx.log.happened("human", self.action, "stop"):
            if self.ctx.current.human == self.action:
                self.ctx.current.human = ""
            return Status.SUCCESS
        if self.ctx.current.task is None or self.ctx.current.task.done():
            self.ctx.current.human = self.action
            self.ctx.log.set_state("running", current=f"awaiting human: {self.action}", awaiting_human=self.action)
        return Status.RUNNING


def build_tree(ctx: DecisionContext, *, semi: bool = False) -> py_trees.trees.BehaviourTree:
    root = py_trees.composites.Sequence(name=ctx.study.study, memory=True)
    for i, step, name in ctx.study.expanded_plan():
        if step.robot is not None:
            root.add_child(RobotStep(ctx, step.robot, i, teleop=semi and step.teleop))
        else:
            root.add_child(HumanStep(ctx, name))
    return py_trees.trees.BehaviourTree(root)


class ScriptedDecision(Decision):
    kind = "scripted"
    semi = False

    def __init__(self, ctx: DecisionContext) -> None:
        super().__init__(ctx)
        self.tree = build_tree(ctx, semi=self.semi)

    async def run(self) -> str:
        ctx = self.ctx
        while not ctx.finished.is_set():
            if self.tree.root.status != Status.SUCCESS:  # a finished tree ticked again would start over
                self.tree.tick()
            status = self.tree.root.status
            if status == Status.SUCCESS and self._humans_done():
                ctx.end("completed")
            elif status == Status.FAILURE:
                ctx.end("failed")
            else:
                waits = [asyncio.ensure_future(ctx.log.changed()), asyncio.ensure_future(ctx.finished.wait())]
                await asyncio.wait(waits, timeout=TICK_S, return_when=asyncio.FIRST_COMPLETED)
                for w in waits:
                    w.cancel()
        self.tree.interrupt()
        return ctx.outcome

    def _humans_done(self) -> bool:
        """The task is done when the plan is, and the human has finished every planned action too."""
        return all(self.ctx.log.happened("human", h) for h in self.ctx.study.planned_human_actions())


class SemiAutonomousDecision(ScriptedDecision):
    """Scripted, except that steps marked `teleop: true` wait until the operator commands that action."""

    kind = "semi"
    semi = True

    async def teleop(self, obj: str, action: str) -> str:
        for node in self.tree.root.iterate():
            if isinstance(node, RobotStep) and node.teleop and node.status == Status.RUNNING and not node.commanded:
                part = self.ctx.study.parts[node.part_index].name
                if (obj, action) != (part, node.action):
                    raise BusError(f"the plan is waiting for {node.action} on {part}, not {action} on {obj}")
                node.commanded = True
                return f"{node.name} started"
        raise BusError("the plan is not waiting for an operator command now")
