"""The classroom study file (`kind: classroom`, examples/classroom.yaml): a short lesson on the stand-in, with
simulated pupils who speak and look away at seeded random times and a simulated teacher in the operator's role;
its conditions are the robot's autonomy levels. The people who act on it are study/classroom.py.

Rates are per minute (the mean of an exponential gap), ranges `[min, max]` seconds drawn uniformly, probabilities
in [0, 1]. Times are simulated seconds at `--speed max`.
"""

from __future__ import annotations

from typing import Literal

from client_protocol.vocabulary import AutonomyLevel
from pydantic import BaseModel, ConfigDict, Field, model_validator

from sim.pupils import PUPILS

from .protocol import ProtocolFields

_STRICT = ConfigDict(extra="forbid", frozen=True)
PUPIL_NAMES = tuple(p.name for p in PUPILS)


def _range(value: tuple[float, float], name: str) -> tuple[float, float]:
    lo, hi = value
    if not 0 <= lo <= hi:
        raise ValueError(f"{name} {list(value)} must be [min, max] seconds with 0 <= min <= max")
    return value


class Pupils(BaseModel):
    """Each pupil speaks, then is quiet for an exponential gap of mean 60 / speak_per_min s; apart from that it
    looks away at look_away_per_min, for look_away_s."""

    model_config = _STRICT
    who: list[str] = Field(default=list(PUPIL_NAMES), min_length=1,
                           description="the stand-in's pupils taking part")
    speak_per_min: float = Field(gt=0, description="how often each pupil starts to speak")
    speech_s: tuple[float, float] = Field(description="how long a pupil speaks (the sentence's words: 2.9 a second)")
    look_away_per_min: float = Field(default=0.0, ge=0)
    look_away_s: tuple[float, float] = (2.0, 6.0)

    @model_validator(mode="after")
    def _check(self) -> Pupils:
        unknown = [w for w in self.who if w not in PUPIL_NAMES]
        if unknown:
            raise ValueError(f"who: {', '.join(unknown)} is not a pupil of the stand-in ({', '.join(PUPIL_NAMES)})")
        _range(self.speech_s, "speech_s")
        if self.speech_s[0] < 0.3:
            raise ValueError(f"speech_s {list(self.speech_s)}: a pupil speaks at least 0.3 s (one word)")
        _range(self.look_away_s, "look_away_s")
        return self


class Teacher(BaseModel):
    """The teacher in the headset. teleoperated: she turns her head to a pupil who starts to speak (reaction_s,
    at turn_deg_s) and, when they stop, answers from the menus with respond_probability (answer_s later).
    supervised: she decides each proposal (accept with accept_probability, else reject, decide_s after it came;
    a decision later than the proposal's time-out is too late: it timed out), and answers herself when no
    proposal came within answer_s of a pupil's stopping. supervised and autonomous: she intervenes (takes control
    and turns the head herself) when the robot has not looked at a speaking pupil within intervene_after_s."""

    model_config = _STRICT
    headset_hz: float = Field(default=72.0, gt=0, le=120, description="head poses a second (a Quest's frame rate)")
    reaction_s: tuple[float, float] = Field(description="from a pupil's onset to her head starting to turn")
    turn_deg_s: float = Field(default=120.0, gt=0, description="how fast she turns her head")
    respond_probability: float = Field(ge=0, le=1, description="she answers a pupil who stopped")
    answer_s: tuple[float, float] = Field(description="from a pupil's stopping to her answer")
    actions: list[str] = Field(min_length=1, description="the menu item ids she answers with (chosen at random)")
    accept_probability: float = Field(ge=0, le=1)
    decide_s: tuple[float, float] = Field(description="from a proposal to her decision")
    intervene_after_s: float = Field(default=3.0, gt=0, description="a speaking pupil not looked at this long")
    intervene_hold_s: float = Field(default=2.0, ge=0, description="she keeps control this long after they stop")

    @model_validator(mode="after")
    def _check(self) -> Teacher:
        for name in ("reaction_s", "answer_s", "decide_s"):
            _range(getattr(self, name), name)
        return self


class Condition(BaseModel):
    model_config = _STRICT
    autonomy: AutonomyLevel
    description: str = ""


class ClassroomStudy(ProtocolFields):
    """A lesson (`lesson_s` simulated seconds) compared across autonomy levels (the conditions); the design and
    questionnaires for its participants: ProtocolFields."""

    model_config = _STRICT
    kind: Literal["classroom"]
    study: str = Field(min_length=1)
    task: str = ""
    seed: int = 0
    lesson_s: float = Field(gt=0, le=3600)
    camera_fps: float = Field(default=2.0, gt=0, le=30, description="the head camera's rate (face detection)")
    perception: Literal["rendered", "modelled"] = Field(
        default="rendered", description="the pupils' faces searched in rendered frames, or modelled from the scene "
                                        "(the server's --perception)")
    pupils: Pupils
    teacher: Teacher
    conditions: dict[str, Condition] = Field(min_length=1)

    @property
    def trials(self) -> dict[str, Condition]:
        """The conditions under the name the study commands use for a study's runs."""
        return self.conditions
