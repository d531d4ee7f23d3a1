"""NASA-TLX (Hart and Staveland, 1988): raw and weighted workload.

Scoring rules:
- Six subscales, each rated 0-100 (higher = more workload; performance runs from perfect to failure, so it is
  not reversed).
- Raw TLX (RTLX, Hart 2006) = the mean of the six ratings.
- Weighted TLX: the respondent makes the 15 pairwise comparisons of the six subscales; a subscale's weight is how
  often it was chosen (0-5), so the weights sum to 15. Weighted TLX = sum(weight x rating) / 15.
- Weights are optional per row, but all six or none: a partial set or a sum other than 15 is an error.
  Either score needs all six ratings; an incomplete row is listed, not scored.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Literal

from pydantic import BaseModel, model_validator

from . import tables
from .definitions import view
from .instrument import load_instrument, source_name
from .sheets import AnswerRow, Sheet, SheetSpec, ValueColumn, split_rows
from .stats import Describe, describe

PAIRWISE_COMPARISONS = 15  # C(6, 2)


class TLXScale(BaseModel):
    min: float
    max: float


class TLXSubscale(BaseModel):
    id: str
    label: str
    low: str
    high: str


class TLXDefinition(BaseModel):
    scale: TLXScale
    subscales: list[TLXSubscale]
    weight_prefix: str = "w_"

    @model_validator(mode="after")
    def _six(self) -> TLXDefinition:
        if len(self.subscales) != 6 or len({s.id for s in self.subscales}) != 6:
            raise ValueError("NASA-TLX has six distinct subscales")
        return self

    def weight_column(self, subscale_id: str) -> str:
        return f"{self.weight_prefix}{subscale_id}"

    @property
    def weight_columns(self) -> list[str]:
        return [self.weight_column(s.id) for s in self.subscales]

    def sheet_spec(self) -> SheetSpec:
        ratings = [ValueColumn(s.id, self.scale.min, self.scale.max, integer=False) for s in self.subscales]
        weights = [ValueColumn(c, 0, len(self.subscales) - 1, integer=True) for c in self.weight_columns]
        return SheetSpec("tlx", "NASA-TLX", tuple(ratings + weights), row_check=self._check_weights)

    def _check_weights(self, row: AnswerRow) -> Iterable[tuple[str | None, str]]:
        columns = self.weight_columns
        if any(c in row.invalid_columns for c in columns):
            return []  # the cell errors are already reported
        given = [c for c in columns if row.values[c] is not None]
        if not given:
            return []
        if len(given) < len(columns):
            missing = [c for c in columns if c not in given]
            return [(missing[0], f"weights must be given for all six subscales or for none "
                                 f"(missing: {', '.join(missing)})")]
        total = sum(row.values[c] for c in columns)  # type: ignore[misc]
        if total != PAIRWISE_COMPARISONS:
            return [(f"{columns[0]}..{columns[-1]}",
                     f"the weights sum to {tables.num(total)}, but the 15 pairwise comparisons give weights that "
                     "sum to 15 (each weight is how often that subscale was chosen)")]
        return []


def load_tlx_definition() -> TLXDefinition:
    """NASA-TLX's view of data/tlx.yaml: its items are the six subscales a respondent rates."""
    instrument = load_instrument("tlx")
    return view(TLXDefinition, dict(
        scale=dict(min=instrument.scale.min, max=instrument.scale.max),
        subscales=[dict(id=i.id, label=i.text, low=i.left, high=i.right) for i in instrument.all_items],
        weight_prefix=instrument.weights.column_prefix if instrument.weights else "w_"), source_name("tlx"))


def raw_tlx(ratings: Mapping[str, float]) -> float:
    """RTLX: the unweighted mean of the six ratings."""
    return sum(ratings.values()) / len(ratings)


def weighted_tlx(ratings: Mapping[str, float], weights: Mapping[str, float]) -> float:
    """sum(weight x rating) / 15, with weights from the 15 pairwise comparisons."""
    if set(weights) != set(ratings):
        raise ValueError("weights and ratings must name the same subscales")
    if sum(weights.values()) != PAIRWISE_COMPARISONS:
        raise ValueError(f"TLX weights must sum to 15, got {sum(weights.values())}")
    return sum(weights[k] * ratings[k] for k in ratings) / PAIRWISE_COMPARISONS


class TLXRespondent(BaseModel):
    row: int
    respondent_id: str
    role: str | None
    condition: str | None
    ratings: dict[str, float | None]
    weights: dict[str, float] | None
    raw: float | None
    weighted: float | None
    missing_ratings: list[str]


class TLXSubset(BaseModel):
    label: str
    rows: int
    incomplete: int
    subscales: dict[str, Describe]
    raw: Describe
    weighted: Describe  # over the rows that gave weights; missing = those with incomplete ratings


class TLXReport(BaseModel):
    questionnaire: Literal["tlx"] = "tlx"
    file: str
    by: str | None
    blank_rows: list[int]
    method: str
    subscale_labels: dict[str, str]
    respondents: list[TLXRespondent]
    subsets: list[TLXSubset]


METHOD = ("raw TLX = mean of the six 0-100 ratings; weighted TLX = sum(weight x rating) / 15, weights from the "
          "15 pairwise comparisons (sum 15). Scored only when all six ratings are given.")


def score_tlx(sheet: Sheet, definition: TLXDefinition | None = None, by: str | None = None) -> TLXReport:
    definition = definition or load_tlx_definition()
    ids = [s.id for s in definition.subscales]
    respondents = []
    for row in sheet.rows:
        ratings = {k: row.values[k] for k in ids}
        missing = [k for k in ids if ratings[k] is None]
        weight_values = {k: row.values[definition.weight_column(k)] for k in ids}
        weights = None if any(v is None for v in weight_values.values()) else weight_values
        raw = weighted = None
        if not missing:
            raw = raw_tlx(ratings)  # type: ignore[arg-type]
            if weights is not None:
                weighted = weighted_tlx(ratings, weights)  # type: ignore[arg-type]
        respondents.append(TLXRespondent(row=row.row, respondent_id=row.respondent_id, role=row.role,
                                         condition=row.condition, ratings=ratings, weights=weights, raw=raw,
                                         weighted=weighted, missing_ratings=missing))
    by_row = {r.row: r for r in respondents}
    subsets = []
    for label, rows in split_rows(sheet.rows, by):
        members = [by_row[r.row] for r in rows]
        subsets.append(TLXSubset(
            label=label, rows=len(members), incomplete=sum(m.raw is None for m in members),
            subscales={k: describe([m.ratings[k] for m in members]) for k in ids},
            raw=describe([m.raw for m in members]),
            weighted=describe([m.weighted for m in members if m.weights is not None])))
    return TLXReport(file=sheet.file, by=by, blank_rows=list(sheet.blank_rows), method=METHOD,
                     subscale_labels={s.id: s.label for s in definition.subscales},
                     respondents=respondents, subsets=subsets)


def format_tlx_report(report: TLXReport, per_respondent: bool = False) -> str:
    out = [f"NASA-TLX scores: {report.file}", f"Scoring: {report.method}"]
    if report.blank_rows:
        out.append("Skipped empty rows: " + ", ".join(map(str, report.blank_rows)) + ".")
    for s in report.subsets:
        out.append("")
        head = "all rows" if report.by is None else f"{report.by}: {s.label}"
        out.append(f"== {head}: {s.rows} row{'s' if s.rows != 1 else ''}, {s.incomplete} incomplete, "
                   f"{s.weighted.n} with weights ==")
        rows = []
        entries = [(report.subscale_labels[k], d) for k, d in s.subscales.items()]
        entries += [("Raw TLX", s.raw), ("Weighted TLX", s.weighted)]
        for name, d in entries:
            rows.append([name, str(d.n), str(d.missing), tables.num(d.mean, digits=1), tables.num(d.sd, digits=1),
                         tables.num(d.median, digits=1), tables.num(d.iqr, digits=1), tables.num(d.min, digits=1),
                         tables.num(d.max, digits=1)])
        out.append(tables.table(["scale", "n", "missing", "mean", "SD", "median", "IQR", "min", "max"], rows))
    incomplete = [r for r in report.respondents if r.raw is None]
    if incomplete:
        out.append("")
        out.append("Not scored (incomplete ratings):")
        for r in incomplete:
            out.append(f"  row {r.row}, {r.respondent_id}: missing {', '.join(r.missing_ratings)}")
    if per_respondent:
        out.append("")
        rows = [[str(r.row), r.respondent_id, r.role or "", r.condition or "", tables.num(r.raw, digits=1),
                 tables.num(r.weighted, digits=1)] for r in report.respondents]
        out.append(tables.table(["row", "respondent", "role", "condition", "raw", "weighted"], rows,
                                left=(1, 2, 3)))
    return "\n".join(out)
