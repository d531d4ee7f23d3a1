"""One trial on a running server: the trial's perception, decision and action implementations, chosen by the
study file, composed on the server's bus and robot.

prepare() starts perception, runs the study's setup primitives (before T0, unreported), preplans motion B and,
with ArUco, waits until every object with a marker has been seen. run() starts the clock (T0) and returns when
the decision module reports the trial completed, preempted or failed (T1), with the final metrics.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass

from client_protocol.vocabulary import Owner
from simclock import WALL, Clock

from ..core.bus import Bus
from ..core.ownership import Ownership
from ..robot.gestures import GestureLibrary
from ..robot.interface import Robot
from .action import ActionModule
from .decision import MODULES, DecisionContext, DecisionHost
from .metrics import FluencyResult
from .perception import ArucoTracker, Perception, StaticTracker, Tracker
from .studyfile import Study
from .trial import TrialLog


@dataclass(frozen=True)
class TrialResult:
    trial: str
    outcome: str
    metrics: FluencyResult
    interventions: int


class TrialRuntime:
    def __init__(self, bus: Bus, robot: Robot, study: Study, trial: str,
                 gestures: GestureLibrary | None = None, clock: Clock = WALL,
                 owners: Ownership | None = None,
                 observer: Callable[[str, str, dict[str, object]], None] | None = None) -> None:
        """`observer(caller, service, request)`: hears each Wizard-of-Oz, override and preempt command taken."""
        if trial not in study.trials:
            raise ValueError(f"study {study.study!r} has no trial {trial!r}; trials: {', '.join(study.trials)}")
        self.bus = bus
        self.robot = robot
        self.owners = owners or Ownership(robot.model.parts)  # a running trial owns what its modules move
        self.study = study
        self.name = trial
        spec = study.trials[trial]
        self.spec = spec
        self.log = TrialLog(bus, study.study, trial, (spec.perception, spec.decision, spec.motion),
                            len(study.planned_robot_subtasks()), clock=clock)
        static = StaticTracker(study.objects, clock)
        trackers: dict[str, Tracker] = {"static": static}
        if spec.perception == "aruco":
            trackers["aruco"] = ArucoTracker(robot, study.objects)
        self.perception = Perception(bus, study.objects, trackers, spec.perception, clock)
        self.static_perception = Perception(bus, study.objects, {"static": static}, "static", clock)
        self.actions = ActionModule(robot, self.perception, self.log, study, spec.motion, gestures,
                                    static=self.static_perception)
        self.ctx = DecisionContext(study, self.log, self.actions, frozenset(spec.stalls))
        self.decision = MODULES[spec.decision](self.ctx)
        self.host = DecisionHost(bus, self.decision, observer)

    async def prepare(self, sight_timeout: float = 10.0) -> None:
        self.log.attach()
        await self.perception.start()
        for spec in self.study.setup:
            if spec.joints:
                await self.actions.move_joints(spec.joints)
        self.actions.preplan()
        aruco = self.perception.trackers.get("aruco")
        if aruco is not None:
            marked = [n for n, o in self.study.objects.items() if o.marker is not None]
            loop = asyncio.get_running_loop()
            deadline = loop.time() + sight_timeout
            while any(aruco.object_pose(n) is None for n in marked):
                if loop.time() > deadline:
                    unseen = [n for n in marked if aruco.object_pose(n) is None]
                    raise RuntimeError(f"ArUco perception did not see {', '.join(unseen)} within {sight_timeout:g} s "
                                       "of setup: check the setup's head pose and the markers' ids")
                await asyncio.sleep(0.1)
        self.host.start()
        self.log.set_state("ready")

    async def run(self) -> TrialResult:
        self.log.begin()
        self.owners.claim(Owner.TRIAL, self.robot.model.parts, self.name)
        try:
            outcome = await self.decision.run()
        finally:
            self.owners.release(Owner.TRIAL, who=self.name)
        metrics = await self.log.finish(outcome)
        return TrialResult(self.name, outcome, metrics, len(self.log.interventions))

    async def close(self) -> None:
        task = self.ctx.current.task
        if task is not None and not task.done():
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
        self.host.stop()
        await self.perception.stop()
        self.log.detach()
