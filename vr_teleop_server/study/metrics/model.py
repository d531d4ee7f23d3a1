"""Validated inputs (state updates, interventions) and the result of a fluency computation."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

Agent = Literal["human", "robot"]
AGENTS: tuple[Agent, ...] = ("human", "robot")
FdelDirection = Literal["both", "human_to_robot", "robot_to_human"]
FDEL_DIRECTIONS: tuple[FdelDirection, ...] = ("both", "human_to_robot", "robot_to_human")

# Strict: a JSON `"start": "12"` or `true` is a mistake in the file, not something to guess at.
# Non-finite times would poison every sum, so they are refused at the door.
_STRICT = ConfigDict(frozen=True, extra="forbid", strict=True)


class StateUpdate(BaseModel):
    """One subtask of one agent: the unit the framework asks every module to report."""

    model_config = _STRICT

    agent: Agent
    action: str = Field(min_length=1)
    start: float = Field(allow_inf_nan=False, description="seconds since the study start")
    stop: float | None = Field(default=None, allow_inf_nan=False, description="None while the action runs")

    @model_validator(mode="after")
    def _stop_not_before_start(self) -> StateUpdate:
        if self.stop is not None and self.stop < self.start:
            raise ValueError(f"stop ({self.stop:g}) is before start ({self.start:g})")
        return self

    @property
    def finished(self) -> bool:
        return self.stop is not None


class Intervention(BaseModel):
    """A human stepping in where the design says the system acts (experimenter override, operator takeover).

    `subtask` names the robot subtask it affected; interventions naming the same subtask count once
    towards effectiveness, unnamed ones count one each.
    """

    model_config = _STRICT

    start: float = Field(allow_inf_nan=False)
    stop: float | None = Field(default=None, allow_inf_nan=False)
    subtask: str | None = Field(default=None, min_length=1)
    note: str = ""

    @model_validator(mode="after")
    def _stop_not_before_start(self) -> Intervention:
        if self.stop is not None and self.stop < self.start:
            raise ValueError(f"stop ({self.stop:g}) is before start ({self.start:g})")
        return self


class UnfinishedAction(BaseModel):
    model_config = ConfigDict(frozen=True)

    agent: Agent
    action: str
    start: float


class Counts(BaseModel):
    """Counts over the actions that touch [T0, T1]."""

    model_config = ConfigDict(frozen=True)

    human_actions: int
    robot_actions: int
    handovers: int = Field(description="hand-overs in both directions, whatever fdel_direction says")
    handovers_human_to_robot: int
    handovers_robot_to_human: int
    unfinished: int
    interventions: int | None = None
    intervened_subtasks: int | None = None
    planned_subtasks: int | None = None


class FluencyResult(BaseModel):
    """Hoffman's fluency metrics plus team efficiency/effectiveness for one trial window [t0, t1].

    Fractions are of T = t1 - t0 and are None when T == 0 (`undefined_reason` says so).
    The *_s fields are the same quantities in seconds, for checks and for readers who want them.
    """

    model_config = ConfigDict(frozen=True)

    t0: float
    t1: float
    efficiency_s: float
    h_idle: float | None
    r_idle: float | None
    c_act: float | None
    both_idle: float | None
    f_del: float | None
    fdel_direction: FdelDirection
    effectiveness: float | None = None
    interventions_known: bool = False
    counts: Counts
    unfinished: list[UnfinishedAction]
    human_active_s: float
    robot_active_s: float
    concurrent_s: float
    both_idle_s: float
    fdel_sum_s: float
    intervention_s: float | None = None
    undefined_reason: str | None = None

    @property
    def duration_s(self) -> float:
        """The window's length (study/kind.py's Measures)."""
        return self.t1 - self.t0

    def to_json_dict(self) -> dict[str, Any]:
        """The `--json` document: the paper's metrics, counts, window and unfinished actions, nothing else."""
        out: dict[str, Any] = {
            "h_idle": self.h_idle,
            "r_idle": self.r_idle,
            "c_act": self.c_act,
            "f_del": self.f_del,
            "both_idle": self.both_idle,
            "efficiency_s": self.efficiency_s,
        }
        if self.interventions_known:
            out["effectiveness"] = self.effectiveness
        out["counts"] = self.counts.model_dump(exclude_none=True)
        out["t0"] = self.t0
        out["t1"] = self.t1
        out["unfinished"] = [u.model_dump() for u in self.unfinished]
        return out


class MetricsInputError(ValueError):
    """A trial file that cannot be read; says where (file, row, column) and how to fix it."""

    def __init__(self, path: Path | str, problem: str, fix: str, row: int | str | None = None,
                 column: str | None = None) -> None:
        self.path, self.problem, self.fix, self.row, self.column = Path(path), problem, fix, row, column
        where = [str(path)]
        if row is not None:
            where.append(f"row {row}" if isinstance(row, int) else str(row))
        if column is not None:
            where.append(f"column {column!r}")
        super().__init__(f"{', '.join(where)}: {problem}; fix: {fix}")


@dataclass(frozen=True)
class TrialData:
    updates: list[StateUpdate]
    interventions: list[Intervention] | None = None  # None: not known, so no effectiveness
    planned_subtasks: int | None = None
    t0: float | None = None  # the window, where the input knows it (a recorded trial); None: the defaults
    t1: float | None = None
