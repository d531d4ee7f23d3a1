"""Learning from the teacher, as SPARC's instance-based learner does: every decision and every action the teacher
takes herself is stored as a point (situation features, action, reward); proposals in a situation weigh the points
stored in situations like it. A forbidden action is never proposed again in that situation; an action the teacher
took herself twice in a situation is proposed the third time. The memory is a JSON file, loaded at start (a bad
one is refused by name) and written after each change."""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from client_protocol.registry import describe_validation_error
from client_protocol.vocabulary import Outcome
from pydantic import BaseModel, ConfigDict, Field, ValidationError

# the reward each end gives the (situation, action) point; superseded and dropped ones teach nothing
REWARDS = {Outcome.ACCEPTED: 1.0, Outcome.TIMED_OUT_EXECUTED: 0.5, Outcome.REJECTED: -1.0, Outcome.FORBIDDEN: -1.0,
           Outcome.TEACHER_INITIATED: 1.0}
SIMILAR = 0.98  # SPARC: a stored situation this similar to the current one counts
TEACHER_REPEATS = 2  # the teacher's own action this many times in a situation: proposed the next time
VERSION = 1


@dataclass(frozen=True)
class Situation:
    """What the robot perceives when it proposes (or the teacher acts): the event and a few features, 0..1."""

    name: str  # the event: speech_ended, silence, new_face, looked_away, or idle
    features: tuple[tuple[str, float], ...] = ()

    def vector(self) -> dict[str, float]:
        return {f"event:{self.name}": 1.0, **dict(self.features)}


def similarity(a: Situation, b: Situation) -> float:
    """1 for the same situation; 1 - mean absolute difference over the features either has (0 across events)."""
    if a.name != b.name:
        return 0.0
    va, vb = a.vector(), b.vector()
    keys = set(va) | set(vb)
    return 1.0 - sum(abs(va.get(k, 0.0) - vb.get(k, 0.0)) for k in keys) / len(keys)


class _Point(BaseModel):
    model_config = ConfigDict(extra="forbid")
    situation: str = Field(min_length=1)
    features: dict[str, float] = Field(default_factory=dict)
    action: str = Field(min_length=1)
    outcome: str
    reward: float


class _Memory(BaseModel):
    model_config = ConfigDict(extra="forbid")
    version: int = VERSION
    points: list[_Point] = Field(default_factory=list)


@dataclass(frozen=True)
class Point:
    situation: Situation
    action: str
    outcome: Outcome
    reward: float


class Learner:
    def __init__(self, path: Path | None = None) -> None:
        self.path = path
        self.points: list[Point] = []
        if path is not None and path.exists():
            self.points = self._load(path)

    @staticmethod
    def _load(path: Path) -> list[Point]:
        try:
            memory = _Memory.model_validate_json(path.read_bytes())
        except ValidationError as exc:
            raise ValueError(f"autonomy memory {path}: not a memory this server wrote ({describe_validation_error(exc)}"
                             "); move it away or give another --autonomy-memory") from None
        except OSError as exc:
            raise ValueError(f"autonomy memory {path}: {exc}") from None
        if memory.version != VERSION:
            raise ValueError(f"autonomy memory {path}: version {memory.version}, this server reads {VERSION}")
        bad = [p.outcome for p in memory.points if p.outcome not in REWARDS]
        if bad:
            raise ValueError(f"autonomy memory {path}: unknown outcome(s) {', '.join(sorted(set(bad)))}")
        return [Point(Situation(p.situation, tuple(sorted(p.features.items()))), p.action, Outcome(p.outcome),
                      p.reward)
                for p in memory.points]

    def record(self, situation: Situation, action: str, outcome: Outcome) -> bool:
        """Store one point; False (nothing stored) for outcomes that teach nothing."""
        reward = REWARDS.get(outcome)
        if reward is None:
            return False
        self.points.append(Point(situation, action, outcome, reward))
        return True

    def dump(self) -> str:
        points = [{"situation": p.situation.name, "features": dict(p.situation.features), "action": p.action,
                   "outcome": p.outcome, "reward": p.reward} for p in self.points]
        return json.dumps({"version": VERSION, "points": points}, indent=1)

    def save(self) -> None:
        """Write the memory (atomically: a crash leaves the old file, never half a new one)."""
        if self.path is None:
            return
        tmp = self.path.with_name(self.path.name + ".tmp")
        tmp.write_text(self.dump(), encoding="utf-8")
        os.replace(tmp, self.path)

    def _near(self, situation: Situation) -> list[Point]:
        return [p for p in self.points if similarity(p.situation, situation) >= SIMILAR]

    def forbidden(self, situation: Situation, action: str) -> bool:
        return any(p.action == action and p.outcome == Outcome.FORBIDDEN for p in self._near(situation))

    def value(self, situation: Situation, action: str) -> float:
        """The rewards of this action in situations like this one, summed."""
        return sum(p.reward for p in self._near(situation) if p.action == action)

    def confidence(self, situation: Situation, action: str, prior: float) -> float:
        """A rule's confidence moved by what the teacher taught: squashed into 0..1."""
        logit = math.log(max(prior, 1e-3) / max(1.0 - prior, 1e-3)) + self.value(situation, action)
        return 1.0 / (1.0 + math.exp(-logit))

    def learned(self, situation: Situation) -> list[tuple[str, float]]:
        """Actions the teacher took herself at least TEACHER_REPEATS times in situations like this (never
        forbidden there), with a confidence."""
        near = self._near(situation)
        counts: dict[str, int] = {}
        for p in near:
            if p.outcome == Outcome.TEACHER_INITIATED:
                counts[p.action] = counts.get(p.action, 0) + 1
        return [(action, self.confidence(situation, action, 0.5)) for action, n in counts.items()
                if n >= TEACHER_REPEATS and not self.forbidden(situation, action)]

    def stats(self) -> dict[str, Any]:
        return {"points": len(self.points), "forbidden": sum(p.outcome == Outcome.FORBIDDEN for p in self.points),
                "path": str(self.path) if self.path else ""}
