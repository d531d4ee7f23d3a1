"""SUS, the System Usability Scale (Brooke, 1996): ten items, one 0-100 score per respondent.

Brooke's scoring rule: each item's contribution is (answer - 1) for the positively worded items (1, 3, 5, 7, 9)
and (5 - answer) for the negatively worded ones (2, 4, 6, 8, 10); the sum of contributions (0-40) is multiplied
by 2.5. The score is defined only for a complete questionnaire, so a respondent with a missing item gets no score
and is listed as incomplete (Brooke asks respondents to tick the centre point rather than skip an item; this
tool does not impute it for them).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Literal

from pydantic import BaseModel, model_validator

from . import tables
from .definitions import view
from .instrument import Instrument, load_instrument, score, source_name
from .sheets import Sheet, SheetSpec, ValueColumn, split_rows
from .stats import Describe, describe


class SUSScale(BaseModel):
    min: int
    max: int
    low: str
    high: str


class SUSItem(BaseModel):
    id: str
    positive: bool
    text: str


class SUSDefinition(BaseModel):
    """SUS's view of its instrument file (data/sus.yaml): ten items, positively or negatively worded."""

    instrument: Instrument
    scale: SUSScale
    items: list[SUSItem]

    @model_validator(mode="after")
    def _ten_items(self) -> SUSDefinition:
        if len(self.items) != 10:
            raise ValueError(f"SUS has 10 items, got {len(self.items)}")
        if len({item.id for item in self.items}) != 10:
            raise ValueError("SUS item ids must be unique")
        return self

    def sheet_spec(self) -> SheetSpec:
        columns = tuple(ValueColumn(item.id, self.scale.min, self.scale.max) for item in self.items)
        return SheetSpec("sus", "SUS", columns)


def load_sus_definition() -> SUSDefinition:
    instrument = load_instrument("sus")
    scale = instrument.scale
    return view(SUSDefinition, dict(
        instrument=instrument,
        scale=dict(min=scale.min, max=scale.max, low=scale.anchors.get(int(scale.min), ""),
                   high=scale.anchors.get(int(scale.max), "")),
        items=[dict(id=i.id, positive=not i.reverse, text=i.text or "") for i in instrument.all_items]),
        source_name("sus"))


def sus_score(answers: Mapping[str, float], definition: SUSDefinition | None = None) -> float:
    """Brooke's rule on one complete questionnaire (answers by item id, 1-5)."""
    definition = definition or load_sus_definition()
    low, high = definition.scale.min, definition.scale.max
    for item in definition.items:
        if not low <= answers[item.id] <= high:
            raise ValueError(f"{item.id}: {answers[item.id]} is outside {low}-{high}")
    return score(definition.instrument, answers)["sus"]  # type: ignore[return-value]  # complete: never None


class SUSRespondent(BaseModel):
    row: int
    respondent_id: str
    role: str | None
    condition: str | None
    score: float | None
    missing_items: list[str]


class SUSSubset(BaseModel):
    label: str
    rows: int
    incomplete: int
    score: Describe


class SUSReport(BaseModel):
    questionnaire: Literal["sus"] = "sus"
    file: str
    by: str | None
    blank_rows: list[int]
    method: str
    respondents: list[SUSRespondent]
    subsets: list[SUSSubset]


METHOD = ("Brooke (1996): odd items contribute answer - 1, even items 5 - answer; sum x 2.5 = 0-100. "
          "Scored only when all 10 items are answered.")


def score_sus(sheet: Sheet, definition: SUSDefinition | None = None, by: str | None = None) -> SUSReport:
    definition = definition or load_sus_definition()
    respondents = []
    for row in sheet.rows:
        missing = [item.id for item in definition.items if row.values[item.id] is None]
        score = None if missing else sus_score(row.values, definition)  # type: ignore[arg-type]
        respondents.append(SUSRespondent(row=row.row, respondent_id=row.respondent_id, role=row.role,
                                         condition=row.condition, score=score, missing_items=missing))
    by_row = {r.row: r for r in respondents}
    subsets = []
    for label, rows in split_rows(sheet.rows, by):
        scores = [by_row[r.row].score for r in rows]
        subsets.append(SUSSubset(label=label, rows=len(rows), incomplete=sum(s is None for s in scores),
                                 score=describe(scores)))
    return SUSReport(file=sheet.file, by=by, blank_rows=list(sheet.blank_rows), method=METHOD,
                     respondents=respondents, subsets=subsets)


def format_sus_report(report: SUSReport, per_respondent: bool = False) -> str:
    out = [f"SUS scores: {report.file}", f"Scoring: {report.method}"]
    if report.blank_rows:
        out.append("Skipped empty rows: " + ", ".join(map(str, report.blank_rows)) + ".")
    out.append("")
    headers = ["group" if report.by is None else report.by, "rows", "scored", "incomplete", "mean", "SD",
               "95% CI", "median", "IQR", "min", "max"]
    rows = []
    for s in report.subsets:
        d = s.score
        ci = "-" if d.ci95_low is None else f"[{tables.num(d.ci95_low, digits=1)}, {tables.num(d.ci95_high, digits=1)}]"
        rows.append([s.label, str(s.rows), str(d.n), str(s.incomplete), tables.num(d.mean, digits=1),
                     tables.num(d.sd, digits=1), ci, tables.num(d.median, digits=1), tables.num(d.iqr, digits=1),
                     tables.num(d.min, digits=1), tables.num(d.max, digits=1)])
    out.append(tables.table(headers, rows))
    incomplete = [r for r in report.respondents if r.score is None]
    if incomplete:
        out.append("")
        out.append("Not scored (incomplete questionnaires):")
        for r in incomplete:
            out.append(f"  row {r.row}, {r.respondent_id}: missing {', '.join(r.missing_items)}")
    if per_respondent:
        out.append("")
        out.append(_respondent_table(report.respondents))
    return "\n".join(out)


def _respondent_table(respondents: Sequence[SUSRespondent]) -> str:
    rows = [[str(r.row), r.respondent_id, r.role or "", r.condition or "", tables.num(r.score, digits=1)]
            for r in respondents]
    return tables.table(["row", "respondent", "role", "condition", "SUS"], rows, left=(1, 2, 3))
