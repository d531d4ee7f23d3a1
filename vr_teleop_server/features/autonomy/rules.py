"""The proposal rules (SPARC's situations to actions): a validated YAML file mapping events the robot perceives to
menu items it proposes. Menu item ids are checked against the running menus at start (a rule naming no item is
refused by name, with the file)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import yaml
from client_protocol.registry import describe_validation_error
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

DEFAULT_RULES = Path(__file__).with_name("data") / "rules.yaml"
Event = Literal["speech_ended", "silence", "new_face", "looked_away"]
EVENTS: tuple[str, ...] = ("speech_ended", "silence", "new_face", "looked_away")


class Rule(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    id: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")
    when: Event = Field(description="speech_ended: a pupil stops after speaking at least min_speech_s; silence: "
                                    "nobody has spoken for silence_s; new_face: a face appears that was not in "
                                    "view; looked_away: a face in view has been gone for away_s")
    action: str = Field(min_length=1, description="a menu item id (/vr_teleop/menus), e.g. emotion.happy")
    reason: str = Field(min_length=1, description="why, in the teacher's words (shown with the proposal)")
    confidence: float = Field(0.6, ge=0, le=1)
    min_speech_s: float = Field(2.0, ge=0)
    silence_s: float = Field(30.0, gt=0)
    away_s: float = Field(10.0, gt=0)


class Rules(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    timeout_s: float = Field(6.0, gt=0, le=60, description="a proposal not decided within this...")
    on_timeout: Literal["execute", "drop"] = Field("execute", description="...is executed (SPARC) or dropped")
    rules: list[Rule] = Field(default_factory=list)

    @model_validator(mode="after")
    def _unique(self) -> Rules:
        ids = [r.id for r in self.rules]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ValueError(f"rule ids must be unique: {', '.join(dup)}")
        return self

    def for_event(self, event: str) -> list[Rule]:
        return [r for r in self.rules if r.when == event]


def load_rules(path: Path | None) -> Rules:
    path = path or DEFAULT_RULES
    try:
        return Rules.model_validate(yaml.safe_load(path.read_text(encoding="utf-8")) or {})
    except ValidationError as exc:
        raise ValueError(f"autonomy rules {path}: {describe_validation_error(exc)}") from None
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"autonomy rules {path}: {exc}") from None


def check_actions(rules: Rules, known: set[str], path: Path | None) -> None:
    """Every rule's action must be a menu item: refused with the file and the rule's id otherwise."""
    unknown = [f"{r.id} -> {r.action}" for r in rules.rules if r.action not in known]
    if unknown:
        raise ValueError(f"autonomy rules {path or DEFAULT_RULES}: no menu item for {', '.join(unknown)}; the items "
                         "are the ids on /vr_teleop/menus (e.g. emotion.happy, speech.sentences.well_done)")
