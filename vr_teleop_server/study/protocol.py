"""What a study file says about its people (any kind of study): the design and order of conditions, the consent
form's version, the demographic questions (in bands) and which questionnaires are due when.

    design: within            # or between
    order: latin              # latin (within only), random (seeded by the file's seed) or fixed
    consent_form: "v1 2026-11-01"
    demographics:
      - {id: age_group, question: Your age, choices: ["18-29", "30-44", "45-64", "65+"]}
    questionnaires:
      before_first: [{name: qam, phase: expected}]
      after_each: [sus, tlx, {name: ssq, who: whoever wore the headset}]
      after_last: [{name: qam, phase: perceived}]

A questionnaire is a packaged instrument's name (qam, sus, tlx, godspeed, ssq) or the path of a lab's own file.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from ..questionnaires.definitions import DefinitionError
from ..questionnaires.instrument import Instrument, load_instrument
from .design import Design, Order

_STRICT = ConfigDict(extra="forbid", frozen=True)


class QuestionnaireEntry(BaseModel):
    model_config = _STRICT
    name: str = Field(min_length=1)
    phase: str | None = None  # for an instrument with phases (QAM: expected, perceived)
    who: str | None = None  # who fills it in, when not every participant (the SSQ: whoever wore the headset)

    @model_validator(mode="before")
    @classmethod
    def _bare_name(cls, value: Any) -> Any:
        return {"name": value} if isinstance(value, str) else value

    def instrument(self) -> Instrument:
        return load_instrument(self.name)


class QuestionnairePlan(BaseModel):
    model_config = _STRICT
    before_first: list[QuestionnaireEntry] = []
    after_each: list[QuestionnaireEntry] = []
    after_last: list[QuestionnaireEntry] = []

    @model_validator(mode="after")
    def _instruments_exist(self) -> QuestionnairePlan:
        for when in ("before_first", "after_each", "after_last"):
            for index, entry in enumerate(getattr(self, when)):
                try:
                    instrument = entry.instrument()
                except DefinitionError as exc:
                    raise ValueError(f"{when}.{index}: {exc}") from None
                if instrument.phases and entry.phase not in instrument.phases:
                    raise ValueError(f"{when}.{index}: {entry.name} is given in phases "
                                     f"({', '.join(instrument.phases)}): say which with phase:")
                if not instrument.phases and entry.phase is not None:
                    raise ValueError(f"{when}.{index}: {entry.name} has no phases; leave phase: out")
        return self


class Demographic(BaseModel):
    """One question, answered by choosing a band (an age group, never a birth date)."""

    model_config = _STRICT
    id: str = Field(min_length=1, pattern=r"^[a-z][a-z0-9_]*$")
    question: str
    choices: list[str] = Field(min_length=2)


class ProtocolFields(BaseModel):
    """The fields a study file of any kind may carry for a study with people."""

    design: Design = "within"
    order: Order = "latin"
    consent_form: str | None = Field(default=None, min_length=1,
                                     description="the consent form's version, recorded with each consent")
    demographics: list[Demographic] = []
    questionnaires: QuestionnairePlan = QuestionnairePlan()

    @model_validator(mode="after")
    def _order_fits_design(self) -> ProtocolFields:
        if self.design == "between" and self.order == "latin":
            raise ValueError("order: latin is for design: within; a between-subject design takes order: random "
                             "(a seeded shuffle per block of participants) or fixed")
        return self


@dataclass(frozen=True)
class StudyPlan:
    """What the study folder needs of a study file: its name, conditions (in the file's order) and protocol."""

    study: str
    conditions: tuple[str, ...]
    seed: int
    protocol: ProtocolFields

    def to_json(self) -> dict[str, Any]:
        return {"study": self.study, "conditions": list(self.conditions), "seed": self.seed,
                "protocol": self.protocol.model_dump(mode="json")}

    @classmethod
    def from_json(cls, document: dict[str, Any]) -> StudyPlan:
        return cls(document["study"], tuple(document["conditions"]), int(document["seed"]),
                   ProtocolFields.model_validate(document["protocol"]))


def plan_of(study: Any) -> StudyPlan:
    """The plan of a loaded study file of either kind (its trials, or a classroom's conditions, in file order)."""
    fields = ProtocolFields.model_validate({k: getattr(study, k) for k in ProtocolFields.model_fields})
    return StudyPlan(study.study, tuple(study.trials), study.seed, fields)
