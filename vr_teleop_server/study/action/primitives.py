"""Action primitives on the Robot interface, each reported as a robot state update (start and stop).

Primitives: move_head / move_arm (joint targets, or an object's query point for an arm via analytic IK),
look_at (head toward an object or query point), point_at (the arm reaches along the line to it), gesture,
emotion, say, wait, and hold (move the arm to a point, then stay until a human action has stopped).

Motion A ("online") resolves targets when the action starts, from the trial's perception (so a marker that
moved is followed). Motion B ("preplanned") resolves every target once, before the trial, from the study
file's static poses, and replays those joint targets. QTrobot's arms have no gripper and no obstacles are
modelled, so neither plans around collisions: "online" means the target is perceived at execution time.
Every command goes through Robot.set_joint_targets, which clamps to the limits.
"""

from __future__ import annotations

import asyncio
import json
import math
from collections.abc import Mapping

import numpy as np

from robot_models.kinematics import arm_ik, forward_kinematics

from ...core.bus import BusError
from ...robot.gestures import GestureLibrary
from ...robot.interface import Robot
from ..perception import Perception
from ..studyfile import ActionSpec, MotionKind, Study
from ..trial import TrialLog

ARRIVAL_TOLERANCE_DEG = 1.5
POINTING_REACH_M = 1.0  # well beyond the arm's 0.26 m, so that the arm points straight along the line


class ActionFailed(Exception):
    """A primitive could not do what it was asked (motor off, target unknown); the message says why."""


class ActionModule:
    def __init__(self, robot: Robot, perception: Perception, log: TrialLog, study: Study, motion: MotionKind,
                 gestures: GestureLibrary | None = None, static: Perception | None = None) -> None:
        self.robot = robot
        self.model = robot.model
        self.perception = perception
        self.static = static or perception
        self.log = log
        self.study = study
        self.motion = motion
        self.gestures = gestures
        self._preplanned: dict[tuple[str, int], dict[str, float]] = {}
        self.outcome: dict[int, bool] = {}  # set by an override before it cancels the action

    # ---- the study's actions ------------------------------------------------------------------------------------
    def preplan(self) -> None:
        """Motion B: joint targets for every (action, part) from the static poses, before the trial starts."""
        if self.motion != "preplanned":
            return
        for name, spec in self.study.actions.items():
            if spec.target is None or spec.primitive not in ("move_arm", "point_at", "hold", "look_at"):
                continue
            for i in range(len(self.study.parts)):
                xyz = self._target_xyz(spec, i, self.static)
                self._preplanned[(name, i)] = self._joints_for(spec, xyz)

    async def run_action(self, action: str, part_index: int, *, stall: bool = False) -> bool:
        """Run the study's robot `action` for one part, reported as the subtask ACTION_PART; True on success.

        `stall`: a fault for studies of interventions: the motion runs but never reports completion, until an
        override ends it. Cancellation (an override or a preempt) stops the update with the override's verdict.
        """
        spec = self.study.actions[action]
        part = self.study.parts[part_index]
        subtask = f"{action}_{part.name}"
        detail = {"primitive": spec.primitive, "part": part.name, "motion": self.motion}
        if spec.target:
            detail["target"] = self.study.fill(spec.target, part_index) or ""
        uid = self.log.start("robot", subtask, "action", json.dumps(detail))
        succeeded = False
        try:
            succeeded = await self._execute(action, spec, part_index)
            if stall:
                await asyncio.Event().wait()  # only an override or a preempt ends it
            return succeeded
        except ActionFailed as exc:
            self.log.bus.report(self.log.bus.caller(), "warning", f"{subtask} failed: {exc}")
            return False
        except asyncio.CancelledError:
            succeeded = self.outcome.pop(uid, False)
            raise
        finally:
            if uid in self.log.running:
                self.log.stop(uid, succeeded)

    async def _execute(self, action: str, spec: ActionSpec, i: int) -> bool:
        def fill(text: str) -> str:
            return self.study.fill(text, i) or ""

        match spec.primitive:
            case "move_head":
                return await self.move_joints(spec.joints)
            case "move_arm" | "point_at" | "hold" if spec.target:
                joints = self._preplanned.get((action, i)) or self._joints_for(spec, self._target_xyz(spec, i))
                ok = await self.move_joints(joints)
                if spec.primitive == "hold" and spec.until_human:
                    await self.wait_for_human(fill(spec.until_human))
                return ok
            case "move_arm":
                return await self.move_joints(spec.joints)
            case "look_at":
                joints = self._preplanned.get((action, i)) or self._joints_for(spec, self._target_xyz(spec, i))
                return await self.move_joints(joints)
            case "gesture":
                if self.gestures is None or not spec.name:
                    raise ActionFailed("no gesture library, or no gesture name")
                result = await self.robot.play_gesture(self.gestures.get(spec.name))
                return result.completed
            case "emotion":
                self.robot.show_emotion(spec.name or "neutral")
                return True
            case "say":
                result = await self.robot.say(fill(spec.text or ""))
                return result.completed
            case "wait" | "hold":
                if spec.until_human:
                    await self.wait_for_human(fill(spec.until_human))
                else:
                    await asyncio.sleep(spec.seconds)
                return True
        raise ActionFailed(f"{spec.primitive} needs a target or joints")

    # ---- primitives ---------------------------------------------------------------------------------------------
    async def move_joints(self, targets: Mapping[str, float], timeout: float | None = None) -> bool:
        """Command joints and wait until they arrive (True), or until they could have at their caps (False)."""
        if not targets:
            raise ActionFailed("no joint targets")
        report = self.robot.set_joint_targets(targets)
        if report.ignored:
            raise ActionFailed(report.describe())
        goal = dict(zip(report.names, report.applied))
        here = self.robot.joint_state().as_dict()
        slowest = max(abs(here[n] - v) / self.model.joint(n).max_velocity for n, v in goal.items())
        loop = asyncio.get_running_loop()
        deadline = loop.time() + (timeout if timeout is not None else slowest * 1.5 + 1.5)
        while True:
            here = self.robot.joint_state().as_dict()
            if max(abs(here[n] - v) for n, v in goal.items()) <= ARRIVAL_TOLERANCE_DEG:
                return True
            if loop.time() >= deadline:
                return False
            await asyncio.sleep(0.02)

    async def wait_for_human(self, action: str) -> None:
        while not self.log.happened("human", action, "stop"):
            await self.log.changed()

    def look_at_joints(self, xyz: np.ndarray) -> dict[str, float]:
        """HeadYaw/HeadPitch turning the head toward a point (base frame); pitch positive looks down."""
        frames = forward_kinematics(self.model, self.model.home_pose())
        pivot = frames["HeadPitch"][:3, 3]
        d = np.asarray(xyz, float) - pivot
        yaw = math.degrees(math.atan2(d[1], d[0]))
        pitch = math.degrees(math.atan2(-d[2], math.hypot(d[0], d[1])))
        return {"HeadYaw": self.model.clamp("HeadYaw", yaw), "HeadPitch": self.model.clamp("HeadPitch", pitch)}

    def arm_joints(self, side: str, xyz: np.ndarray) -> dict[str, float]:
        """The arm's joints putting the hand at xyz, or reaching as far toward it as the arm goes."""
        here = self.robot.joint_state().as_dict()
        return dict(arm_ik(side, xyz, self.model, prefer=here).angles_deg)

    # ---- helpers ------------------------------------------------------------------------------------------------
    def _target_xyz(self, spec: ActionSpec, i: int, perception: Perception | None = None) -> np.ndarray:
        target = self.study.fill(spec.target or "", i) or ""
        try:
            pose, _age = (perception or self.perception).query(target, spec.query_point or "")
        except BusError as exc:
            raise ActionFailed(str(exc)) from None
        return pose[:3, 3]

    def _joints_for(self, spec: ActionSpec, xyz: np.ndarray) -> dict[str, float]:
        if spec.primitive == "look_at":
            return self.look_at_joints(xyz)
        if spec.primitive == "point_at":
            return self.arm_joints(spec.arm, self.pointing_target(spec.arm, xyz))
        return self.arm_joints(spec.arm, xyz)

    def pointing_target(self, side: str, xyz: np.ndarray) -> np.ndarray:
        """A point far beyond reach on the line from the shoulder through xyz: IK then stretches the arm along it."""
        shoulder = forward_kinematics(self.model, self.model.home_pose())[f"{side.capitalize()}ShoulderPitch"][:3, 3]
        direction = np.asarray(xyz, float) - shoulder
        norm = float(np.linalg.norm(direction))
        return shoulder + (direction / norm if norm > 1e-6 else np.array([1.0, 0.0, 0.0])) * POINTING_REACH_M
