"""The study file (YAML, validated with pydantic): task, objects and query points, robot actions, the plan, the
simulated human and operator, and the trials, each choosing one implementation per module.

Names in actions, plan entries and scripts may hold `{part}`, `{bin}` and `{prev}` (the previous part), filled
per part of the task. A plan entry or script step with `when: hold` applies only to parts with `hold: true`,
`when: not_hold` only to the others; an event naming `{prev}` is dropped for the first part.
Poses are `{xyz: [m, m, m], rpy_deg: [roll, pitch, yaw]}` in the robot's base frame (x forward, y left, z up).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from scipy.spatial.transform import Rotation


from .protocol import ProtocolFields

_STRICT = ConfigDict(extra="forbid", frozen=True)

Perception = Literal["aruco", "static"]
DecisionKind = Literal["scripted", "teleop", "semi"]
MotionKind = Literal["online", "preplanned"]
Primitive = Literal["move_head", "move_arm", "look_at", "point_at", "gesture", "emotion", "say", "wait", "hold"]
When = Literal["always", "hold", "not_hold"]


class StudyFileError(ValueError):
    """A study file that cannot be used; the message names the file, the place and the fix."""


class PoseSpec(BaseModel):
    model_config = _STRICT
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def matrix(self) -> np.ndarray:
        t = np.eye(4)
        t[:3, :3] = Rotation.from_euler("xyz", self.rpy_deg, degrees=True).as_matrix()
        t[:3, 3] = self.xyz
        return t


class MarkerSpec(BaseModel):
    """An ArUco marker (DICT_4X4_50) on the object; `object_in_marker`: the object's frame in the marker's."""

    model_config = _STRICT
    id: int = Field(ge=0, le=49)
    size_m: float = Field(gt=0)
    object_in_marker: PoseSpec = PoseSpec()


class ObjectSpec(BaseModel):
    model_config = _STRICT
    static_pose: PoseSpec | None = None
    marker: MarkerSpec | None = None
    query_points: dict[str, PoseSpec] = {}


class Part(BaseModel):
    model_config = _STRICT
    name: str = Field(min_length=1)
    bin: str = Field(min_length=1, description="the object the part is picked from")
    hold: bool = False


class ActionSpec(BaseModel):
    """One robot action: one primitive, with its arguments. `target`/`query_point` name what it acts on."""

    model_config = _STRICT
    primitive: Primitive
    target: str | None = None
    query_point: str | None = None
    arm: Literal["left", "right"] = "right"
    joints: dict[str, float] = {}
    name: str | None = Field(default=None, description="gesture or emotion name")
    text: str | None = None
    seconds: float = Field(default=0.0, ge=0)
    until_human: str | None = Field(default=None, description="hold/wait: until this human action has stopped")


class PlanStep(BaseModel):
    """One entry of the scripted plan, repeated per part: a robot action or a wait for a human action."""

    model_config = _STRICT
    robot: str | None = None
    human: str | None = None
    when: When = "always"
    teleop: bool = Field(default=False, description="semi-autonomous decision: wait for the operator's command")

    @model_validator(mode="after")
    def _one_kind(self) -> PlanStep:
        if (self.robot is None) == (self.human is None):
            raise ValueError("give exactly one of robot: ACTION or human: ACTION_NAME")
        return self


class ScriptStep(BaseModel):
    """A simulated person's step: `action` (human: the action's name; operator: a robot action) once every
    event in `after` ("agent:action:start|stop") has happened, plus a reaction time."""

    model_config = _STRICT
    action: str = Field(min_length=1)
    after: list[str] = []
    duration_s: tuple[float, float] = (0.0, 0.0)
    when: When = "always"

    @model_validator(mode="after")
    def _events(self) -> ScriptStep:
        for e in self.after:
            bits = e.split(":")
            if len(bits) != 3 or bits[0] not in ("human", "robot") or bits[2] not in ("start", "stop"):
                raise ValueError(f"event {e!r} is not agent:action:start|stop (agent human or robot)")
        lo, hi = self.duration_s
        if not 0 <= lo <= hi:
            raise ValueError(f"duration_s {list(self.duration_s)} must be [min, max] with 0 <= min <= max")
        return self


class Script(BaseModel):
    model_config = _STRICT
    reaction_s: tuple[float, float] = (0.2, 0.5)
    steps: list[ScriptStep] = []


class Override(BaseModel):
    """The experimenter ends a robot action `delay_s` after it starts (marking it succeeded or failed)."""

    model_config = _STRICT
    action: str = Field(min_length=1)
    delay_s: float = Field(ge=0)
    succeeded: bool = True
    note: str = ""


class Trial(BaseModel):
    model_config = _STRICT
    perception: Perception
    decision: DecisionKind
    motion: MotionKind
    description: str = ""
    stalls: list[str] = Field(default=[], description="robot actions that never report completion (a fault)")
    overrides: list[Override] = []


class Study(ProtocolFields):
    """A task study (examples/toolbox.yaml): a robot and a human share a task, compared on fluency metrics.
    Its trials are the conditions participants meet (the design and questionnaires: ProtocolFields)."""

    model_config = _STRICT
    kind: Literal["task"] = "task"
    study: str = Field(min_length=1)
    task: str = ""
    seed: int = 0
    setup: list[ActionSpec] = Field(default=[], description="primitives run before the trial's clock starts")
    objects: dict[str, ObjectSpec]
    parts: list[Part] = Field(min_length=1)
    actions: dict[str, ActionSpec]
    plan: list[PlanStep] = Field(min_length=1)
    human: Script
    operator: Script = Script()
    trials: dict[str, Trial] = Field(min_length=1)

    @model_validator(mode="after")
    def _references(self) -> Study:
        for i, spec in enumerate(self.setup):
            if spec.primitive not in ("move_head", "move_arm") or not spec.joints:
                raise ValueError(f"setup[{i}]: only move_head or move_arm with joints can run before the trial")
        for part in self.parts:
            if part.bin not in self.objects:
                raise ValueError(f"part {part.name!r}: bin {part.bin!r} is not among the objects "
                                 f"({', '.join(self.objects)})")
        if len({p.name for p in self.parts}) != len(self.parts):
            raise ValueError("part names must be unique")
        for step in self.plan:
            if step.robot is not None and step.robot not in self.actions:
                raise ValueError(f"plan step robot: {step.robot!r} is not among the actions ({', '.join(self.actions)})")
        for step in self.operator.steps:
            if step.action not in self.actions:
                raise ValueError(f"operator step {step.action!r} is not among the actions ({', '.join(self.actions)})")
        for name, action in self.actions.items():
            if action.target is not None and "{" not in action.target and action.target not in self.objects:
                raise ValueError(f"action {name!r}: target {action.target!r} is not among the objects")
        planned = set(self.planned_robot_subtasks())
        for tname, trial in self.trials.items():
            for name in [o.action for o in trial.overrides] + trial.stalls:
                if name not in planned:
                    raise ValueError(f"trial {tname!r}: {name!r} is not a planned robot subtask (ACTION_PART)")
        return self

    # ---- the plan, expanded per part --------------------------------------------------------------------------
    def applies(self, when: When, part: Part) -> bool:
        return when == "always" or (when == "hold") == part.hold

    def fill(self, text: str, index: int) -> str | None:
        """Fill {part}, {bin}, {prev} for part `index`; None when it names {prev} of the first part."""
        if "{prev}" in text and index == 0:
            return None
        part = self.parts[index]
        prev = self.parts[index - 1].name if index else ""
        return text.replace("{part}", part.name).replace("{bin}", part.bin).replace("{prev}", prev)

    def expanded_plan(self) -> list[tuple[int, PlanStep, str]]:
        """(part index, step, filled subtask name) in plan order; robot subtasks are named ACTION_PART."""
        out = []
        for i, part in enumerate(self.parts):
            for step in self.plan:
                if not self.applies(step.when, part):
                    continue
                if step.robot is not None:
                    out.append((i, step, f"{step.robot}_{part.name}"))
                else:
                    name = self.fill(step.human or "", i)
                    if name is not None:
                        out.append((i, step, name))
        return out

    def planned_robot_subtasks(self) -> list[str]:
        return [name for _, step, name in self.expanded_plan() if step.robot is not None]

    def planned_human_actions(self) -> list[str]:
        out = []
        for i, part in enumerate(self.parts):
            for step in self.human.steps:
                if self.applies(step.when, part):
                    name = self.fill(step.action, i)
                    if name is not None and name not in out:
                        out.append(name)
        return out

    def part_index(self, name: str) -> int:
        for i, p in enumerate(self.parts):
            if p.name == name:
                return i
        raise KeyError(f"no part {name!r}; parts: {', '.join(p.name for p in self.parts)}")
