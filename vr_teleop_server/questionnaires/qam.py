"""QAM, the Quick Assessment Method (Botev and Rodriguez Lera, HCII 2020): scoring expected against perceived.

The paper gives the 33 parameters and their scale but no scoring formula. The rules used here:
- Per parameter and phase: n answers, missing answers, median and IQR (see `stats`).
- Difference = median(perceived) - median(expected); positive means the parameter proved more influential in
  use than the designers expected.
- Pairing: a rater is paired when the same respondent_id has an expected and a perceived row in the same
  condition. Per parameter, the Wilcoxon signed-rank test uses the pairs with both answers present.
- Group summary: Likert parameters only (the objective parameters 4-6 are on their own scales). Answers are
  pooled over raters and parameters for the median and IQR; each parameter is counted as higher, lower or
  unchanged by its median difference. The group's paired test uses, per paired rater, the mean of that
  rater's answers over the group's parameters answered in both phases.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, model_validator

from . import tables
from .definitions import DefinitionError, view
from .instrument import load_instrument, load_instrument_file, source_name
from .sheets import AnswerRow, Sheet, SheetSpec, ValueColumn, split_rows
from .stats import DEFAULT_MIN_NONZERO, Describe, PairedTest, describe, wilcoxon_paired

PHASES = ("expected", "perceived")


class LikertScale(BaseModel):
    min: int
    max: int
    labels: dict[int, str]


class ObjectiveScale(BaseModel):
    min: float
    max: float | None
    unit: str


class QAMGroup(BaseModel):
    id: str
    name: str
    long_name: str | None = None


class QAMParameter(BaseModel):
    id: int
    group: str
    name: str
    short: str
    scale: ObjectiveScale | None = None  # set for the objective parameters, None for Likert ones

    @property
    def column(self) -> str:
        return f"P{self.id}"

    @property
    def objective(self) -> bool:
        return self.scale is not None


class QAMDefinition(BaseModel):
    likert: LikertScale
    groups: list[QAMGroup]
    parameters: list[QAMParameter]

    @model_validator(mode="after")
    def _consistent(self) -> QAMDefinition:
        ids = [p.id for p in self.parameters]
        if ids != list(range(1, len(ids) + 1)):
            raise ValueError(f"parameter ids must run 1..{len(ids)} in order, got {ids}")
        group_ids = {g.id for g in self.groups}
        for parameter in self.parameters:
            if parameter.group not in group_ids:
                raise ValueError(f"parameter {parameter.id} names unknown group {parameter.group!r}")
        for group in self.groups:
            if not any(p.group == group.id for p in self.parameters):
                raise ValueError(f"group {group.id!r} has no parameters")
        return self

    def in_group(self, group_id: str) -> list[QAMParameter]:
        return [p for p in self.parameters if p.group == group_id]

    def sheet_spec(self) -> SheetSpec:
        columns = []
        for p in self.parameters:
            if p.scale is None:
                columns.append(ValueColumn(p.column, self.likert.min, self.likert.max, integer=True))
            else:
                columns.append(ValueColumn(p.column, p.scale.min, p.scale.max, integer=False, unit=p.scale.unit))
        return SheetSpec("qam", "QAM", tuple(columns), phases=PHASES)


def load_qam_definition(path: str | Path | None = None) -> QAMDefinition:
    """QAM's view of its instrument file: parameter N is item PN, the actor groups are its subscales."""
    name = "qam" if path is None else path
    instrument = load_instrument("qam") if path is None else load_instrument_file(path)
    parameters = []
    for group in instrument.subscales:
        for item in instrument.members(group):
            if not item.id.startswith("P") or not item.id[1:].isdigit():
                raise DefinitionError(f"{source_name(name)}: item {item.id}: QAM's items are P1, P2, ...")
            scale = None if item.scale is None else dict(min=item.scale.min, max=item.scale.max,
                                                         unit=item.scale.unit or "")
            parameters.append(dict(id=int(item.id[1:]), group=group.id, name=item.text or item.id,
                                   short=item.short or item.text or item.id, scale=scale))
    return view(QAMDefinition, dict(
        likert=dict(min=instrument.scale.min, max=instrument.scale.max, labels=instrument.scale.anchors),
        groups=[dict(id=g.id, name=g.name, long_name=g.long_name) for g in instrument.subscales],
        parameters=parameters), source_name(name))


class QAMParameterResult(BaseModel):
    id: int
    column: str
    group: str
    name: str
    short: str
    objective: bool
    unit: str | None
    expected: Describe
    perceived: Describe
    difference: float | None  # median(perceived) - median(expected)
    test: PairedTest


class QAMGroupResult(BaseModel):
    id: str
    name: str
    likert_parameters: list[int]
    objective_parameters: list[int]
    expected: Describe  # pooled over raters and Likert parameters
    perceived: Describe
    difference: float | None
    higher: list[int]  # parameters whose median rose from expected to perceived
    lower: list[int]
    unchanged: list[int]
    not_comparable: list[int]  # a phase has no answers
    test: PairedTest  # on per-rater group means


class QAMSubsetResult(BaseModel):
    label: str
    expected_rows: int
    perceived_rows: int
    paired_raters: int
    parameters: list[QAMParameterResult]
    groups: list[QAMGroupResult]


class QAMReport(BaseModel):
    questionnaire: Literal["qam"] = "qam"
    file: str
    by: str | None
    blank_rows: list[int]
    min_nonzero_pairs: int
    method: dict[str, str]
    subsets: list[QAMSubsetResult]


METHOD = {
    "scale": "1 not at all, 2 slightly, 3 somewhat, 4 very, 5 extremely influential; P4-P6 on their own scales",
    "summary": "n answers, missing answers, median, IQR = Q3 - Q1 (numpy linear quartiles), per phase",
    "difference": "median(perceived) - median(expected)",
    "pairing": "same respondent_id with an expected and a perceived row in the same condition",
    "test": "scipy.stats.wilcoxon, two-sided, zero differences dropped (zero_method='wilcox'); run only with "
            "enough non-zero differences (min_nonzero_pairs)",
    "effect_size": "matched-pairs rank-biserial r = (R+ - R-) / (R+ + R-) on perceived - expected",
    "group_summary": "Likert parameters only; answers pooled over raters and parameters; the group test uses "
                     "each paired rater's mean over the parameters answered in both phases",
}


def _pairs(rows: Sequence[AnswerRow]) -> list[tuple[AnswerRow, AnswerRow]]:
    expected = {(r.respondent_id, r.condition): r for r in rows if r.phase == "expected"}
    return [(expected[(r.respondent_id, r.condition)], r) for r in rows
            if r.phase == "perceived" and (r.respondent_id, r.condition) in expected]


def _difference(expected: Describe, perceived: Describe) -> float | None:
    if expected.median is None or perceived.median is None:
        return None
    return perceived.median - expected.median


def _score_subset(label: str, rows: Sequence[AnswerRow], definition: QAMDefinition,
                  min_nonzero: int) -> QAMSubsetResult:
    expected_rows = [r for r in rows if r.phase == "expected"]
    perceived_rows = [r for r in rows if r.phase == "perceived"]
    pairs = _pairs(rows)
    results = []
    for p in definition.parameters:
        e = describe([r.values[p.column] for r in expected_rows])
        q = describe([r.values[p.column] for r in perceived_rows])
        complete = [(a.values[p.column], b.values[p.column]) for a, b in pairs
                    if a.values[p.column] is not None and b.values[p.column] is not None]
        test = wilcoxon_paired([x for x, _ in complete], [y for _, y in complete], min_nonzero)
        results.append(QAMParameterResult(
            id=p.id, column=p.column, group=p.group, name=p.name, short=p.short, objective=p.objective,
            unit=p.scale.unit if p.scale else None, expected=e, perceived=q, difference=_difference(e, q),
            test=test))
    by_id = {r.id: r for r in results}
    groups = []
    for g in definition.groups:
        likert = [p for p in definition.in_group(g.id) if not p.objective]
        cols = [p.column for p in likert]
        e = describe([r.values[c] for r in expected_rows for c in cols])
        q = describe([r.values[c] for r in perceived_rows for c in cols])
        direction: dict[str, list[int]] = {"higher": [], "lower": [], "unchanged": [], "not_comparable": []}
        for p in likert:
            diff = by_id[p.id].difference
            key = "not_comparable" if diff is None else "higher" if diff > 0 else "lower" if diff < 0 \
                else "unchanged"
            direction[key].append(p.id)
        rater_e, rater_p = [], []
        for a, b in pairs:
            both = [c for c in cols if a.values[c] is not None and b.values[c] is not None]
            if both:
                rater_e.append(sum(a.values[c] for c in both) / len(both))
                rater_p.append(sum(b.values[c] for c in both) / len(both))
        groups.append(QAMGroupResult(
            id=g.id, name=g.name, likert_parameters=[p.id for p in likert],
            objective_parameters=[p.id for p in definition.in_group(g.id) if p.objective],
            expected=e, perceived=q, difference=_difference(e, q), **direction,
            test=wilcoxon_paired(rater_e, rater_p, min_nonzero)))
    return QAMSubsetResult(label=label, expected_rows=len(expected_rows), perceived_rows=len(perceived_rows),
                           paired_raters=len(pairs), parameters=results, groups=groups)


def score_qam(sheet: Sheet, definition: QAMDefinition | None = None, by: str | None = None,
              min_nonzero: int = DEFAULT_MIN_NONZERO) -> QAMReport:
    """Score a validated QAM sheet, as a whole or split by `condition` or `role`."""
    definition = definition or load_qam_definition()
    subsets = [_score_subset(label, rows, definition, min_nonzero) for label, rows in split_rows(sheet.rows, by)]
    return QAMReport(file=sheet.file, by=by, blank_rows=list(sheet.blank_rows), min_nonzero_pairs=min_nonzero,
                     method=dict(METHOD), subsets=subsets)


# ---- terminal output -------------------------------------------------------------------------------------------

def _plural(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


def _test_cells(test: PairedTest) -> list[str]:
    if not test.tested:
        reason = "no pairs" if test.n_pairs == 0 else f"too few ({test.n_nonzero} differ)"
        return [str(test.n_pairs), "-", "-", "-", reason]
    return [str(test.n_pairs), tables.num(test.statistic, digits=1), tables.p_text(test.p_value),
            tables.num(test.rank_biserial, signed=True), ""]


TEST_HEADERS = ["pairs", "W", "p", "r_rb", "note"]


def format_qam_report(report: QAMReport, definition: QAMDefinition | None = None) -> str:
    definition = definition or load_qam_definition()
    out = [f"QAM scores: {report.file}",
           "Scale 1-5: " + ", ".join(f"{k} {v}" for k, v in sorted(definition.likert.labels.items())) + ".",
           "E = expected (before the trial), P = perceived (after). diff = median P - median E. "
           "IQR = Q3 - Q1. miss = missing answers (E/P). \"-\" = no value."]
    objective = [p for p in definition.parameters if p.objective]
    if objective:
        out.append("Objective parameters, on their own scales: "
                   + "; ".join(f"P{p.id} {p.short.split(' (')[0]} in {p.scale.unit}" for p in objective) + ".")
    if report.blank_rows:
        out.append(f"Skipped {_plural(len(report.blank_rows), 'empty row')}: "
                   + ", ".join(str(r) for r in report.blank_rows) + ".")
    for subset in report.subsets:
        out.append("")
        title = "all rows" if report.by is None else f"{report.by}: {subset.label}"
        out.append(f"== {title}: {_plural(subset.expected_rows, 'expected row')}, "
                   f"{_plural(subset.perceived_rows, 'perceived row')}, "
                   f"{_plural(subset.paired_raters, 'rater')} in both phases ==")
        for phase, count in (("expected", subset.expected_rows), ("perceived", subset.perceived_rows)):
            if count == 0:
                out.append(f"  Note: no {phase} rows here, so no differences can be computed.")
        any_test = any(p.test.tested for p in subset.parameters) or any(g.test.tested for g in subset.groups)
        headers = ["ID", "parameter", "E n", "E median", "E IQR", "P n", "P median", "P IQR", "diff", "miss E/P"]
        if any_test:
            headers += TEST_HEADERS
        name_width = max(len(p.short) for p in definition.parameters)
        for group in definition.groups:
            out.append("")
            out.append(group.long_name or group.name)
            rows = []
            for p in (r for r in subset.parameters if r.group == group.id):
                row = [str(p.id), p.short, str(p.expected.n), tables.num(p.expected.median),
                       tables.num(p.expected.iqr), str(p.perceived.n), tables.num(p.perceived.median),
                       tables.num(p.perceived.iqr), tables.num(p.difference, signed=True),
                       f"{p.expected.missing}/{p.perceived.missing}"]
                if any_test:
                    row += _test_cells(p.test)
                rows.append(row)
            out.append(tables.table(headers, rows, left=(1, len(headers) - 1) if any_test else (1,),
                                    min_widths=(2, name_width)))
        out.append("")
        out.append("Group summary (Likert parameters; answers pooled over raters and parameters)")
        g_headers = ["group", "params", "E n", "E median", "E IQR", "P n", "P median", "P IQR", "diff",
                     "higher", "lower", "same"]
        if any_test:
            g_headers += TEST_HEADERS
        g_rows = []
        for g in subset.groups:
            row = [g.name, str(len(g.likert_parameters)), str(g.expected.n), tables.num(g.expected.median),
                   tables.num(g.expected.iqr), str(g.perceived.n), tables.num(g.perceived.median),
                   tables.num(g.perceived.iqr), tables.num(g.difference, signed=True), str(len(g.higher)),
                   str(len(g.lower)), str(len(g.unchanged))]
            if any_test:
                row += _test_cells(g.test)
            g_rows.append(row)
        out.append(tables.table(g_headers, g_rows, left=(0, len(g_headers) - 1) if any_test else (0,)))
        for g in subset.groups:
            moved = [f"higher: P{', P'.join(map(str, g.higher))}" if g.higher else "",
                     f"lower: P{', P'.join(map(str, g.lower))}" if g.lower else ""]
            moved = [m for m in moved if m]
            if moved:
                out.append(f"  {g.name}: " + "; ".join(moved))
        out.append("")
        if any_test:
            out.append(f"Wilcoxon signed-rank, perceived vs expected (two-sided); r_rb = matched-pairs rank-biserial "
                       f"(+ = higher when perceived). Run where at least {report.min_nonzero_pairs} pairs differ.")
        else:
            out.append(f"Wilcoxon signed-rank test: not run, n too small. {_plural(subset.paired_raters, 'rater')} "
                       f"answered both phases; the test needs at least {report.min_nonzero_pairs} raters whose "
                       "expected and perceived answers differ on a parameter.")
    return "\n".join(out)
