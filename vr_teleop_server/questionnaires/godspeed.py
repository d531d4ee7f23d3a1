"""Godspeed questionnaire series (Bartneck, Kulic, Croft and Zoghbi, 2009): five series of 5-point semantic
differentials, each scored as the mean of its items.

Scoring rules:
- A reverse-keyed item (`reverse: true` in the item data) is scored as (min + max - answer), i.e. 6 - answer on
  the 1-5 scale, before averaging; on the published English form no item is reversed (see data/godspeed.yaml).
- A respondent's series mean needs every item of that series; a series with a missing item is left unscored
  for that respondent and counted as incomplete. Other series of the same respondent are still scored.
- Per series and group: mean, SD, median, IQR of the respondents' series means, and Cronbach's alpha over the
  respondents who answered every item of the series (Bartneck et al. report alpha for each series).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, model_validator

from . import tables
from .definitions import view
from .instrument import Instrument, load_instrument, load_instrument_file, score, source_name
from .sheets import Sheet, SheetSpec, ValueColumn, split_rows
from .stats import Describe, cronbach_alpha, describe


class GodspeedScale(BaseModel):
    min: int
    max: int


class GodspeedItem(BaseModel):
    id: str
    left: str  # the anchor at the scale's minimum
    right: str  # the anchor at its maximum
    reverse: bool = False


class GodspeedSeries(BaseModel):
    id: str
    name: str
    items: list[GodspeedItem]


class GodspeedDefinition(BaseModel):
    """Godspeed's view of its instrument file: series (subscales) of semantic differentials."""

    instrument: Instrument
    scale: GodspeedScale
    series: list[GodspeedSeries]

    @model_validator(mode="after")
    def _consistent(self) -> GodspeedDefinition:
        ids = [item.id for s in self.series for item in s.items]
        duplicates = sorted({i for i in ids if ids.count(i) > 1})
        if duplicates:
            raise ValueError(f"item ids must be unique, repeated: {', '.join(duplicates)}")
        empty = [s.id for s in self.series if not s.items]
        if empty:
            raise ValueError(f"series without items: {', '.join(empty)}")
        return self

    @property
    def items(self) -> list[GodspeedItem]:
        return [item for s in self.series for item in s.items]

    def keyed(self, item: GodspeedItem, answer: float) -> float:
        """The answer with the item's keying applied (reverse-keyed: min + max - answer)."""
        return self.scale.min + self.scale.max - answer if item.reverse else answer

    def sheet_spec(self) -> SheetSpec:
        columns = tuple(ValueColumn(i.id, self.scale.min, self.scale.max) for i in self.items)
        return SheetSpec("godspeed", "Godspeed", columns)


def load_godspeed_definition(path: str | Path | None = None) -> GodspeedDefinition:
    """The packaged items, or a user's item file (e.g. a translation with some anchors swapped)."""
    name = "godspeed" if path is None else path
    instrument = load_instrument("godspeed") if path is None else load_instrument_file(path)
    return view(GodspeedDefinition, dict(
        instrument=instrument, scale=dict(min=instrument.scale.min, max=instrument.scale.max),
        series=[dict(id=s.id, name=s.name, items=[dict(id=i.id, left=i.left, right=i.right, reverse=i.reverse)
                                                  for i in instrument.members(s)])
                for s in instrument.subscales]), source_name(name))


def series_means(answers: Mapping[str, float | None], definition: GodspeedDefinition) -> dict[str, float | None]:
    """Each series' mean of keyed answers (the instrument's scoring rule); None for a series with a missing item."""
    scores = score(definition.instrument, answers)
    return {s.id: scores[f"{definition.instrument.id}.{s.id}"] for s in definition.series}


class GodspeedRespondent(BaseModel):
    row: int
    respondent_id: str
    role: str | None
    condition: str | None
    series: dict[str, float | None]
    missing_items: dict[str, list[str]]  # per series, only series with missing items


class GodspeedSeriesSummary(BaseModel):
    id: str
    name: str
    items: int
    reversed_items: list[str]
    score: Describe  # over respondents' series means; missing = respondents with an incomplete series
    cronbach_alpha: float | None


class GodspeedSubset(BaseModel):
    label: str
    rows: int
    series: list[GodspeedSeriesSummary]


class GodspeedReport(BaseModel):
    questionnaire: Literal["godspeed"] = "godspeed"
    file: str
    by: str | None
    blank_rows: list[int]
    method: str
    respondents: list[GodspeedRespondent]
    subsets: list[GodspeedSubset]


METHOD = ("series score = mean of the series' items (1-5), reverse-keyed items scored as 6 - answer; "
          "a series is scored only when all its items are answered.")


def score_godspeed(sheet: Sheet, definition: GodspeedDefinition | None = None,
                   by: str | None = None) -> GodspeedReport:
    definition = definition or load_godspeed_definition()
    respondents = []
    for row in sheet.rows:
        missing = {s.id: [i.id for i in s.items if row.values[i.id] is None] for s in definition.series}
        respondents.append(GodspeedRespondent(
            row=row.row, respondent_id=row.respondent_id, role=row.role, condition=row.condition,
            series=series_means(row.values, definition), missing_items={k: v for k, v in missing.items() if v}))
    by_row = {r.row: r for r in respondents}
    subsets = []
    for label, rows in split_rows(sheet.rows, by):
        summaries = []
        for s in definition.series:
            complete = [[definition.keyed(i, r.values[i.id]) for i in s.items] for r in rows
                        if all(r.values[i.id] is not None for i in s.items)]
            summaries.append(GodspeedSeriesSummary(
                id=s.id, name=s.name, items=len(s.items), reversed_items=[i.id for i in s.items if i.reverse],
                score=describe([by_row[r.row].series[s.id] for r in rows]),
                cronbach_alpha=cronbach_alpha(np.array(complete)) if complete else None))
        subsets.append(GodspeedSubset(label=label, rows=len(rows), series=summaries))
    return GodspeedReport(file=sheet.file, by=by, blank_rows=list(sheet.blank_rows), method=METHOD,
                          respondents=respondents, subsets=subsets)


def format_godspeed_report(report: GodspeedReport, per_respondent: bool = False) -> str:
    out = [f"Godspeed scores: {report.file}", f"Scoring: {report.method}"]
    reversed_items = sorted({i for s in report.subsets[0].series for i in s.reversed_items}) if report.subsets \
        else []
    out.append("Reverse-keyed items: " + (", ".join(reversed_items) if reversed_items else "none") + ".")
    if report.blank_rows:
        out.append("Skipped empty rows: " + ", ".join(map(str, report.blank_rows)) + ".")
    for subset in report.subsets:
        out.append("")
        head = "all rows" if report.by is None else f"{report.by}: {subset.label}"
        out.append(f"== {head}: {subset.rows} row{'s' if subset.rows != 1 else ''} ==")
        rows = []
        for s in subset.series:
            d = s.score
            rows.append([s.name, str(s.items), str(d.n), str(d.missing), tables.num(d.mean), tables.num(d.sd),
                         tables.num(d.median), tables.num(d.iqr), tables.num(s.cronbach_alpha)])
        out.append(tables.table(["series", "items", "n", "incomplete", "mean", "SD", "median", "IQR", "alpha"],
                                rows))
    incomplete = [r for r in report.respondents if r.missing_items]
    if incomplete:
        out.append("")
        out.append("Series not scored (missing items):")
        for r in incomplete:
            parts = "; ".join(f"{k}: {', '.join(v)}" for k, v in r.missing_items.items())
            out.append(f"  row {r.row}, {r.respondent_id}: {parts}")
    if per_respondent and report.subsets:
        out.append("")
        ids = [s.id for s in report.subsets[0].series]
        names = [s.name for s in report.subsets[0].series]
        rows = [[str(r.row), r.respondent_id, r.condition or "", *(tables.num(r.series[i]) for i in ids)]
                for r in report.respondents]
        out.append(tables.table(["row", "respondent", "condition", *names], rows, left=(1, 2)))
    return "\n".join(out)
