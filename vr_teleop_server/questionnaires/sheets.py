"""Answer sheets (CSV or JSON): reading, cell validation and error reporting by file, row and column.

Every questionnaire here uses the same sheet shape: one row per respondent (per phase, for QAM), with
`respondent_id`, an optional `role` and `condition`, and one column per item. The reader collects every problem
in a sheet before failing, so a researcher fixes a sheet in one pass rather than one error per run.

Rules shared by all sheets:
- Row numbers are those a spreadsheet shows: the header is row 1, the first answer row is row 2. In a JSON
  sheet, row N is the N-th object of the `rows` list.
- An empty cell, "-" (or null in JSON) is a missing answer. It is kept as missing and counted in every summary.
- Column names are matched without regard to case or surrounding spaces; an unknown column is an error.
- The key (respondent_id, condition, phase) must be unique: a respondent has at most one row per phase and
  condition. Without conditions this is the (respondent_id, phase) pair.
- Rows whose every cell is empty carry no answers; they are skipped and reported by row number.
"""

from __future__ import annotations

import csv
import difflib
import io
import json
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

ID_COLUMN = "respondent_id"
PHASE_COLUMN = "phase"
OPTIONAL_TEXT_COLUMNS = ("role", "condition")
MISSING_MARKERS = frozenset({"", "-"})
CSV_SUFFIXES = frozenset({".csv", ".tsv", ".txt"})


@dataclass(frozen=True)
class SheetIssue:
    """One problem in a sheet, located as precisely as it can be."""

    file: str
    message: str
    row: int | None = None
    column: str | None = None

    def __str__(self) -> str:
        where = self.file
        if self.row is not None:
            where += f", row {self.row}"
        if self.column is not None:
            where += f", column {self.column}"
        return f"{where}: {self.message}"


class SheetError(Exception):
    """All problems found in one sheet; raised only after the whole sheet was read."""

    def __init__(self, issues: Sequence[SheetIssue]):
        self.issues = tuple(issues)
        super().__init__("\n".join(str(issue) for issue in self.issues))


def _fmt_number(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else f"{value:g}"


@dataclass(frozen=True)
class ValueColumn:
    """An answer column: its accepted range, whether answers are whole numbers, and what they mean."""

    name: str
    min: float
    max: float | None
    integer: bool = True
    unit: str | None = None

    def range_text(self) -> str:
        if self.max is None:
            return f">= {_fmt_number(self.min)}"
        return f"{_fmt_number(self.min)}-{_fmt_number(self.max)}"

    def hint(self) -> str:
        if self.integer and self.unit is None:
            what = self.range_text()
        else:
            what = f"a {'whole ' if self.integer else ''}number {self.range_text()}"
            if self.unit:
                what += f" ({self.unit})"
        return f'use {what}, or "-" for missing'

    def parse(self, raw: object) -> tuple[float | None, str | None]:
        """Return (value, None), (None, None) for a missing answer, or (None, error message)."""
        if raw is None:
            return None, None
        if isinstance(raw, bool) or not isinstance(raw, (str, int, float)):
            return None, f"{json.dumps(raw)} is not a number ({self.hint()})"
        text = raw.strip() if isinstance(raw, str) else _fmt_number(float(raw))
        if text in MISSING_MARKERS:
            return None, None
        try:
            value = float(text)
        except ValueError:
            return None, f'"{text}" is not a number ({self.hint()})'
        if not math.isfinite(value):
            return None, f'"{text}" is not a number ({self.hint()})'
        if self.integer and not value.is_integer():
            return None, f'"{text}" is not a whole number ({self.hint()})'
        if self.max is None and value < self.min:
            return None, f'"{text}" is below {_fmt_number(self.min)} ({self.hint()})'
        if value < self.min or (self.max is not None and value > self.max):
            return None, f'"{text}" is outside {self.range_text()} ({self.hint()})'
        return value, None


@dataclass(frozen=True)
class AnswerRow:
    """One validated row. `values` holds every answer column; None means missing."""

    row: int
    respondent_id: str
    phase: str | None
    role: str | None
    condition: str | None
    values: Mapping[str, float | None]
    invalid_columns: frozenset[str] = frozenset()

    def group_value(self, by: str) -> str | None:
        return {"condition": self.condition, "role": self.role}[by]


RowCheck = Callable[[AnswerRow], Iterable[tuple[str | None, str]]]


@dataclass(frozen=True)
class SheetSpec:
    """What a questionnaire's sheet must contain. `row_check` adds cross-column rules (e.g. TLX weights)."""

    questionnaire: str  # the CLI name: "qam", "sus", ...
    title: str  # for messages: "QAM", "SUS", ...
    value_columns: tuple[ValueColumn, ...]
    phases: tuple[str, ...] = ()  # empty: the sheet has no phase column
    row_check: RowCheck | None = None

    @property
    def required_columns(self) -> tuple[str, ...]:
        head = (ID_COLUMN, PHASE_COLUMN) if self.phases else (ID_COLUMN,)
        return head + tuple(column.name for column in self.value_columns)

    @property
    def all_columns(self) -> tuple[str, ...]:
        head = (ID_COLUMN, PHASE_COLUMN) if self.phases else (ID_COLUMN,)
        return head + OPTIONAL_TEXT_COLUMNS + tuple(column.name for column in self.value_columns)

    def columns_summary(self) -> str:
        names = [column.name for column in self.value_columns]
        head = ", ".join(self.all_columns[: len(self.all_columns) - len(names)])
        items = f"{names[0]}..{names[-1]}" if len(names) > 3 else ", ".join(names)
        return f"{head}, {items}"


@dataclass(frozen=True)
class Sheet:
    """A fully validated sheet."""

    file: str
    spec: SheetSpec
    rows: tuple[AnswerRow, ...]
    blank_rows: tuple[int, ...] = ()


@dataclass
class _Collector:
    file: str
    issues: list[SheetIssue] = field(default_factory=list)

    def add(self, message: str, row: int | None = None, column: str | None = None) -> None:
        self.issues.append(SheetIssue(self.file, message, row, column))


def read_sheet(path: str | Path, spec: SheetSpec, display_name: str | None = None) -> Sheet:
    """Read and validate a CSV or JSON sheet; raise SheetError listing every problem found."""
    path = Path(path)
    shown = display_name or str(path)
    issues = _Collector(shown)
    suffix = path.suffix.lower()
    if suffix not in CSV_SUFFIXES and suffix != ".json":
        issues.add(f'unknown sheet format "{path.suffix or "(no suffix)"}" (save the sheet as .csv or .json)')
        raise SheetError(issues.issues)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        issues.add(f"file not found (check the path; `vr-teleop {spec.questionnaire} template --out FILE.csv` "
                   "writes an empty sheet)")
        raise SheetError(issues.issues) from None
    except UnicodeDecodeError as exc:
        issues.add(f"is not UTF-8 text ({exc.reason} at byte {exc.start}); save the sheet as CSV UTF-8 or JSON")
        raise SheetError(issues.issues) from None
    except OSError as exc:
        issues.add(f"cannot be read ({exc.strerror})")
        raise SheetError(issues.issues) from None
    records = _csv_records(text, issues) if suffix in CSV_SUFFIXES else _json_records(text, spec, issues)
    sheet = _validate(records, spec, issues)
    if issues.issues:  # file-level problems first, then by row; found order within a row
        raise SheetError(sorted(issues.issues, key=lambda issue: issue.row or 0))
    return sheet


@dataclass(frozen=True)
class _Record:
    """A row before cell validation: its number, its cells by column name, and cells under an empty header."""

    row: int
    cells: dict[str, object]
    unnamed: tuple[tuple[int, str], ...] = ()  # (1-based position, text) of cells under an empty header


@dataclass(frozen=True)
class _CSVRows:
    """A CSV sheet before validation: the header cells and each row's number and cells."""

    header: list[str]
    rows: list[tuple[int, list[str]]]


def _canonical_map(spec: SheetSpec) -> dict[str, str]:
    return {name.lower(): name for name in spec.all_columns}


def _csv_records(text: str, issues: _Collector) -> _CSVRows:
    first_line = text.split("\n", 1)[0]
    delimiter = max(",;\t", key=first_line.count) if any(d in first_line for d in ",;\t") else ","
    reader = csv.reader(io.StringIO(text, newline=""), delimiter=delimiter)
    try:
        header = next(reader)
    except StopIteration:
        issues.add("the sheet is empty (it needs a header row)", row=1)
        return _CSVRows([], [])
    except csv.Error as exc:
        issues.add(f"is not valid CSV ({exc})", row=1)
        return _CSVRows([], [])
    rows: list[tuple[int, list[str]]] = []
    last_line = reader.line_num
    try:
        for cells in reader:
            row_number = last_line + 1
            last_line = reader.line_num
            rows.append((row_number, cells))
    except csv.Error as exc:
        issues.add(f"is not valid CSV ({exc})", row=last_line + 1)
    return _CSVRows(header, rows)


def _json_records(text: str, spec: SheetSpec, issues: _Collector) -> list[_Record]:
    try:
        document = json.loads(text)
    except json.JSONDecodeError as exc:
        issues.add(f"is not valid JSON ({exc.msg} at line {exc.lineno}, column {exc.colno})")
        return []
    if isinstance(document, dict):
        extra = sorted(set(document) - {"questionnaire", "rows"})
        if extra:
            issues.add(f'unknown top-level key "{extra[0]}" (a JSON sheet is {{"rows": [...]}} or a list of rows)')
        kind = document.get("questionnaire")
        if kind is not None and kind != spec.questionnaire:
            issues.add(f'this is a "{kind}" sheet, not a "{spec.questionnaire}" sheet '
                       f"(score it with `vr-teleop {kind} score`)")
        rows = document.get("rows")
    else:
        rows = document
    if not isinstance(rows, list):
        issues.add('a JSON sheet must be a list of row objects, or {"rows": [...]}')
        return []
    records = []
    for index, entry in enumerate(rows, start=1):
        if not isinstance(entry, dict):
            issues.add(f"is {type(entry).__name__}, expected an object of column: value", row=index)
            continue
        records.append(_Record(index, dict(entry)))
    return records


def _unknown_column_message(name: str, spec: SheetSpec) -> str:
    close = difflib.get_close_matches(name, spec.all_columns, n=1, cutoff=0.6)
    hint = f'did you mean "{close[0]}"? ' if close else ""
    return f'unknown column "{name}" ({hint}the columns are {spec.columns_summary()})'


def _missing_columns(present: set[str], spec: SheetSpec, issues: _Collector, row: int) -> None:
    missing = [name for name in spec.required_columns if name not in present]
    value_names = {column.name for column in spec.value_columns}
    if value_names and value_names <= set(missing):
        issues.add(f"none of the {spec.title} answer columns is in the header; is this a {spec.title} sheet? "
                   f"(expected {spec.columns_summary()}; `vr-teleop {spec.questionnaire} template` writes one)",
                   row=row)
        missing = [name for name in missing if name not in value_names]
    for name in missing:
        issues.add(f"is missing (the header needs {spec.columns_summary()}; give a missing answer as \"-\")",
                   row=row, column=name)


def _normalise_csv(data: _CSVRows, spec: SheetSpec, issues: _Collector) -> list[_Record]:
    canonical = _canonical_map(spec)
    columns: list[str | None] = []  # canonical name per position, None for unknown or unnamed
    seen: dict[str, int] = {}
    for position, raw in enumerate(data.header, start=1):
        name = raw.strip()
        if not name:
            columns.append(None)
            continue
        known = canonical.get(name.lower())
        if known is None:
            issues.add(_unknown_column_message(name, spec), row=1, column=name)
            columns.append(None)
        elif known in seen:
            issues.add(f"appears twice in the header (columns {seen[known]} and {position}); keep one",
                       row=1, column=known)
            columns.append(None)
        else:
            seen[known] = position
            columns.append(known)
    if data.header:
        _missing_columns(set(seen), spec, issues, row=1)
    records = []
    for row_number, cells in data.rows:
        if all(not cell.strip() for cell in cells):
            records.append(_Record(row_number, {}))
            continue
        if len(cells) > len(data.header) and any(cell.strip() for cell in cells[len(data.header):]):
            issues.add(f"has {len(cells)} cells but the header has {len(data.header)} columns "
                       "(remove the extra cells or name their column)", row=row_number)
        named: dict[str, object] = {}
        unnamed = []
        for position, cell in enumerate(cells[: len(data.header)], start=1):
            name = columns[position - 1]
            if name is not None:
                named[name] = cell
            elif not data.header[position - 1].strip() and cell.strip():
                unnamed.append((position, cell))
        for name in seen:
            named.setdefault(name, "")  # short rows: trailing cells left out are empty answers
        records.append(_Record(row_number, named, tuple(unnamed)))
    return records


def _normalise_json(records: list[_Record], spec: SheetSpec, issues: _Collector) -> list[_Record]:
    canonical = _canonical_map(spec)
    result = []
    for record in records:
        named: dict[str, object] = {}
        for key, value in record.cells.items():
            known = canonical.get(str(key).strip().lower())
            if known is None:
                issues.add(_unknown_column_message(str(key), spec), row=record.row, column=str(key))
            elif known in named:
                issues.add("is given twice in this row (keys differ only in case or spaces)",
                           row=record.row, column=known)
            else:
                named[known] = value
        if named:
            _missing_columns(set(named), spec, issues, row=record.row)
        result.append(_Record(record.row, named))
    return result


def _text(value: object) -> str:
    if value is None:
        return ""
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return str(value).strip()


def _validate(raw: list[_Record] | _CSVRows, spec: SheetSpec, issues: _Collector) -> Sheet:
    records = _normalise_csv(raw, spec, issues) if isinstance(raw, _CSVRows) else \
        _normalise_json(raw, spec, issues)
    rows: list[AnswerRow] = []
    blank: list[int] = []
    first_seen: dict[tuple[str, str, str], int] = {}
    for record in records:
        cells = record.cells
        if not record.unnamed and all(_text(value) == "" for value in cells.values()):
            blank.append(record.row)
            continue
        for position, text in record.unnamed:
            issues.add(f'holds "{text.strip()}" under an empty header (name the column or clear the cell)',
                       row=record.row, column=f"#{position}")
        respondent = _text(cells.get(ID_COLUMN))
        if ID_COLUMN in cells and not respondent:
            issues.add("is empty (every row needs a respondent id)", row=record.row, column=ID_COLUMN)
        phase: str | None = None
        if spec.phases and PHASE_COLUMN in cells:
            phase_text = _text(cells.get(PHASE_COLUMN)).lower()
            choices = " or ".join(spec.phases)
            if not phase_text:
                issues.add(f"the phase is missing (use {choices})", row=record.row, column=PHASE_COLUMN)
            elif phase_text not in spec.phases:
                issues.add(f'"{_text(cells.get(PHASE_COLUMN))}" is not a phase (use {choices})',
                           row=record.row, column=PHASE_COLUMN)
            else:
                phase = phase_text
        values: dict[str, float | None] = {}
        invalid = set()
        for column in spec.value_columns:
            if column.name not in cells:
                values[column.name] = None
                invalid.add(column.name)  # already reported as a missing column
                continue
            value, problem = column.parse(cells[column.name])
            if problem:
                issues.add(problem, row=record.row, column=column.name)
                invalid.add(column.name)
            values[column.name] = value
        answer = AnswerRow(
            row=record.row,
            respondent_id=respondent,
            phase=phase,
            role=_text(cells.get("role")) or None,
            condition=_text(cells.get("condition")) or None,
            values=values,
            invalid_columns=frozenset(invalid),
        )
        if spec.row_check is not None:
            for column_name, message in spec.row_check(answer):
                issues.add(message, row=record.row, column=column_name)
        if respondent and (phase is not None or not spec.phases):
            key = (respondent, answer.condition or "", phase or "")
            if key in first_seen:
                what = f"phase {phase}" if phase else "this sheet"
                if answer.condition:
                    what += f", condition {answer.condition}"
                rule = ("a respondent has one expected and one perceived row per condition" if spec.phases
                        else "a respondent has one row per condition")
                issues.add(f'"{respondent}" appears twice for {what} (also on row {first_seen[key]}); {rule}',
                           row=record.row, column=ID_COLUMN)
            else:
                first_seen[key] = record.row
        rows.append(answer)
    if not rows and not issues.issues:
        issues.add("the sheet has no answer rows (add one row per respondent under the header)")
    return Sheet(file=issues.file, spec=spec, rows=tuple(rows), blank_rows=tuple(blank))


def split_rows(rows: Sequence[AnswerRow], by: str | None) -> list[tuple[str, list[AnswerRow]]]:
    """Rows grouped by `condition` or `role` in order of first appearance; one group "all" when by is None."""
    if by is None:
        return [("all", list(rows))]
    groups: dict[str, list[AnswerRow]] = {}
    for row in rows:
        label = row.group_value(by) or f"(no {by})"
        groups.setdefault(label, []).append(row)
    return list(groups.items())


def template_rows(spec: SheetSpec, respondents: int) -> list[dict[str, str]]:
    """Blank rows for `respondents` respondents (one per phase for phased sheets), ids R01, R02, ..."""
    width = max(2, len(str(respondents)))
    rows = []
    for index in range(1, respondents + 1):
        for phase in spec.phases or (None,):
            row = {name: "" for name in spec.all_columns}
            row[ID_COLUMN] = f"R{index:0{width}d}"
            if phase is not None:
                row[PHASE_COLUMN] = phase
            rows.append(row)
    return rows


def write_template(path: str | Path, spec: SheetSpec, respondents: int = 1) -> int:
    """Write an empty sheet (CSV or JSON by suffix); return the number of rows written."""
    path = Path(path)
    rows = template_rows(spec, respondents)
    suffix = path.suffix.lower()
    if suffix == ".json":
        document = {"questionnaire": spec.questionnaire,
                    "rows": [{key: (value or None) for key, value in row.items()} for row in rows]}
        path.write_text(json.dumps(document, indent=2) + "\n", encoding="utf-8")
    elif suffix in CSV_SUFFIXES:
        with path.open("w", newline="", encoding="utf-8") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(spec.all_columns),
                                    delimiter="\t" if suffix == ".tsv" else ",", lineterminator="\n")
            writer.writeheader()
            writer.writerows(rows)
    else:
        raise ValueError(f'{path}: unknown sheet format "{path.suffix or "(no suffix)"}" (use .csv or .json)')
    return len(rows)
