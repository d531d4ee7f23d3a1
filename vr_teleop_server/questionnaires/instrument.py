"""Instruments as data: one YAML format for a rating questionnaire (its items, scale and anchors, reverse keys,
subscales and scoring rule), so that a lab adds its own instrument, or its licensed translation, as a file.

The packaged instruments (`qam`, `sus`, `tlx`, `godspeed`, `ssq`) are files of this format in `data/`;
`load_instrument` takes one of those names or the path of a lab's own file. `check_answers` validates one
respondent's answers (the participant's page sends them as a JSON object from item id to answer) and `score`
applies the file's scoring rule. The format is documented in docs/guides/questionnaires.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Literal

from pydantic import AliasChoices, BaseModel, ConfigDict, Field, model_validator

from client_protocol.files import load_model_file

from .definitions import DefinitionError, data_file
from .sheets import ValueColumn

PACKAGED = ("qam", "sus", "tlx", "godspeed", "ssq")
PREFER_NOT = "prefer_not_to_answer"  # the explicit answer of a respondent who declines an item

_STRICT = ConfigDict(extra="forbid", frozen=True)


class Scale(BaseModel):
    """The answers' range; `anchors` label points of it (1: strongly disagree ...)."""

    model_config = _STRICT
    min: float
    max: float | None = Field(description="null: no upper bound (an objective measure in seconds)")
    integer: bool = Field(default=True, description="false: any number in range (NASA-TLX's 0-100)")
    anchors: dict[int, str] = Field(default={}, description="labels of points of the scale: {1: strongly disagree}")
    unit: str | None = None

    @model_validator(mode="after")
    def _ordered(self) -> Scale:
        if self.max is not None and self.max <= self.min:
            raise ValueError(f"scale max ({self.max:g}) must be above its min ({self.min:g})")
        return self


class Item(BaseModel):
    """One item; its id is the answer sheet's column. `left`/`right` anchor a semantic differential."""

    model_config = _STRICT
    id: str = Field(min_length=1, pattern=r"^[A-Za-z][A-Za-z0-9_]*$")
    text: str | None = None
    short: str | None = Field(default=None, description="a label for tables and charts")
    left: str | None = Field(default=None, description="a semantic differential's anchor at the minimum")
    right: str | None = Field(default=None, description="its anchor at the maximum")
    reverse: bool = Field(default=False, description="reverse-keyed: scored as min + max - answer")
    scale: Scale | None = Field(default=None, description="the item's own scale (QAM's objective parameters)")


class Subscale(BaseModel):
    """Items scored together: declared inline (`items`) or named by id (`includes`), when an item counts in
    several subscales (the SSQ). Its score is the raw score (sum or mean of keyed items) x `multiplier`."""

    model_config = _STRICT
    id: str = Field(min_length=1)
    name: str
    long_name: str | None = None
    items: list[Item] = Field(default=[], description="the subscale's own items")
    includes: list[str] = Field(default=[], description="ids of items declared elsewhere that count here too")
    multiplier: float = Field(default=1.0, description="the score is the raw score times this weight")


class Total(BaseModel):
    """The instrument's one overall score: `rule` over the keyed items (less the scale's min when `from_min`)
    or over the subscales' raw scores, times `multiplier`."""

    model_config = _STRICT
    name: str
    of: Literal["items", "subscales"] = Field(default="items", description="keyed items, or subscales' raw scores")
    rule: Literal["sum", "mean"] = "sum"
    from_min: bool = Field(default=False, description="subtract the scale's min from each keyed answer (SUS)")
    multiplier: float = 1.0


class Scoring(BaseModel):
    model_config = _STRICT
    subscales: Literal["sum", "mean"] = Field(default="mean", description="a subscale's raw score from its items")
    total: Total | None = Field(default=None, description="the one overall score, if there is one")


class PairwiseWeights(BaseModel):
    """NASA-TLX's weights: how often each item won the pairwise comparisons, in columns PREFIX + item id."""

    model_config = _STRICT
    column_prefix: str = "w_"


class Instrument(BaseModel):
    model_config = _STRICT
    id: str = Field(min_length=1)
    title: str
    source: str
    scale: Scale
    phases: list[str] = Field(default=[], description="when it is given (QAM: expected, perceived)")
    items: list[Item] = Field(default=[], description="items not declared inside a subscale")
    subscales: list[Subscale] = Field(default=[], validation_alias=AliasChoices("subscales", "series"),
                                      description="also accepted as series (Godspeed)")
    scoring: Scoring | None = Field(default=None, description="null: reported item by item (QAM)")
    weights: PairwiseWeights | None = None

    @model_validator(mode="after")
    def _consistent(self) -> Instrument:
        ids = [item.id for item in self.all_items]
        duplicates = sorted({i for i in ids if ids.count(i) > 1})
        if duplicates:
            raise ValueError(f"item ids must be unique, repeated: {', '.join(duplicates)}")
        if not ids:
            raise ValueError("the instrument has no items")
        known = set(ids)
        for sub in self.subscales:
            unknown = [i for i in sub.includes if i not in known]
            if unknown:
                raise ValueError(f"subscale {sub.id} includes unknown items: {', '.join(unknown)}")
            if not sub.items and not sub.includes:
                raise ValueError(f"series without items: {sub.id}")
        subscale_ids = [s.id for s in self.subscales]
        if len(set(subscale_ids)) != len(subscale_ids):
            raise ValueError("subscale ids must be unique")
        total = self.scoring.total if self.scoring else None
        if total is not None and total.of == "subscales" and not self.subscales:
            raise ValueError("scoring.total is of subscales, but the instrument has none")
        return self

    @property
    def all_items(self) -> list[Item]:
        """Every item in the order a sheet's columns take: top-level ones, then each subscale's own."""
        return [*self.items, *(item for sub in self.subscales for item in sub.items)]

    def item(self, item_id: str) -> Item:
        return next(i for i in self.all_items if i.id == item_id)

    def members(self, subscale: Subscale) -> list[Item]:
        by_id = {i.id: i for i in self.all_items}
        return [*subscale.items, *(by_id[i] for i in subscale.includes)]

    def scale_of(self, item: Item) -> Scale:
        return item.scale or self.scale

    def keyed(self, item: Item, answer: float) -> float:
        scale = self.scale_of(item)
        if item.reverse:
            assert scale.max is not None, "a reverse-keyed item needs a bounded scale"
            return scale.min + scale.max - answer
        return answer

    def column(self, item: Item) -> ValueColumn:
        scale = self.scale_of(item)
        return ValueColumn(item.id, scale.min, scale.max, integer=scale.integer, unit=scale.unit)

    def measures(self) -> list[str]:
        """The names of the scores `score` gives: the total as the instrument's id, subscales as id.subscale."""
        if self.scoring is None:
            return []
        names = [f"{self.id}.{s.id}" for s in self.subscales]
        return ([self.id] if self.scoring.total is not None else []) + names


class AnswerError(ValueError):
    """Answers that cannot be taken; `problems` names each item and what is wrong with it."""

    def __init__(self, problems: list[str]):
        self.problems = problems
        super().__init__("; ".join(problems))


def _number_text(value: float) -> str:
    return f"{value:g}"


def check_answers(instrument: Instrument, answers: Mapping[str, object]) -> dict[str, float | None]:
    """Every item answered, in its scale, or declined with PREFER_NOT (kept as None): the answers by item id.

    Raises AnswerError naming every item that is unknown, missing or out of its scale."""
    if not isinstance(answers, Mapping):
        raise AnswerError(["the answers must be an object from item id to answer"])
    problems = []
    items = {i.id: i for i in instrument.all_items}
    unknown = [k for k in answers if k not in items]
    if unknown:
        problems.append(f"unknown item{'s' if len(unknown) > 1 else ''} {', '.join(map(str, unknown))} "
                        f"(the {instrument.id} items are {', '.join(items)})")
    checked: dict[str, float | None] = {}
    for item_id, item in items.items():
        if item_id not in answers:
            problems.append(f"{item_id}: no answer (give one, or \"{PREFER_NOT}\")")
            continue
        raw = answers[item_id]
        if raw == PREFER_NOT:
            checked[item_id] = None
            continue
        column = instrument.column(item)
        if isinstance(raw, bool) or not isinstance(raw, (int, float)) or not math.isfinite(raw):
            problems.append(f"{item_id}: {raw!r} is not an answer (use {column.range_text()}, "
                            f"or \"{PREFER_NOT}\")")
            continue
        scale = instrument.scale_of(item)
        if raw < scale.min or (scale.max is not None and raw > scale.max):
            problems.append(f"{item_id}: {_number_text(raw)} is outside its scale {column.range_text()}")
        elif scale.integer and not float(raw).is_integer():
            problems.append(f"{item_id}: {_number_text(raw)} is not a whole number ({column.range_text()})")
        else:
            checked[item_id] = float(raw)
    if problems:
        raise AnswerError(problems)
    return checked


def _combine(values: list[float], rule: str) -> float:
    return sum(values) if rule == "sum" else sum(values) / len(values)


def score(instrument: Instrument, answers: Mapping[str, float | None]) -> dict[str, float | None]:
    """The file's scoring rule on one respondent's answers: {measure name: score}, None where an item the
    score needs was not answered (a score is never computed from part of its items)."""
    if instrument.scoring is None:
        return {}
    rule = instrument.scoring.subscales
    raw: dict[str, float | None] = {}
    for sub in instrument.subscales:
        values = [answers.get(i.id) for i in instrument.members(sub)]
        raw[sub.id] = None if any(v is None for v in values) else \
            _combine([instrument.keyed(i, v) for i, v in zip(instrument.members(sub), values)], rule)
    result: dict[str, float | None] = {}
    total = instrument.scoring.total
    if total is not None:
        if total.of == "subscales":
            parts = list(raw.values())
        else:
            parts = []
            for item in instrument.all_items:
                value = answers.get(item.id)
                parts.append(None if value is None else instrument.keyed(item, value)
                             - (instrument.scale_of(item).min if total.from_min else 0.0))
        result[instrument.id] = None if any(p is None for p in parts) else \
            _combine(parts, total.rule) * total.multiplier  # type: ignore[arg-type]
    for sub in instrument.subscales:
        value = raw[sub.id]
        result[f"{instrument.id}.{sub.id}"] = None if value is None else value * sub.multiplier
    return result


def source_name(name_or_path: str | Path) -> str:
    """How errors name an instrument's file."""
    text = str(name_or_path)
    return f"package data {text}.yaml" if text in PACKAGED else text


def load_instrument_file(path: str | Path) -> Instrument:
    """A lab's own instrument file (YAML)."""
    return load_model_file(Instrument, Path(path), error=DefinitionError)


def load_instrument(name_or_path: str | Path) -> Instrument:
    """A packaged instrument by name (`sus`), or a lab's own file (its path)."""
    text = str(name_or_path)
    if text in PACKAGED:
        return load_model_file(Instrument, data_file(f"{text}.yaml"), shown=source_name(text),
                               error=DefinitionError)
    if not text.endswith((".yaml", ".yml")) and not Path(text).is_file():
        raise DefinitionError(f"{text}: not a questionnaire (the packaged ones are {', '.join(PACKAGED)}; "
                              "a lab's own is the path of its .yaml file)")
    return load_instrument_file(text)
