"""Trial files to state updates, with errors that point at the file, row and column to fix.

Formats (chosen by file extension in `read_trial`):
- CSV, header `agent,action,start,stop` (any column order, no other columns); times in seconds; an empty
  stop marks an action still running at the end.
- JSON, either a list of objects with exactly the keys agent, action, start, stop (stop may be null), or an
  object {"updates": [...], "interventions": [...], "planned_subtasks": N} where the last two are optional;
  with "interventions" present (even empty) effectiveness is computed.
- Interventions on their own (`read_interventions`, the CLI's --interventions): a CSV with header
  `start,stop,subtask,note` (stop, subtask and note optional columns and cells) or a JSON list of objects
  with those keys (only start required).
- MCAP session recordings: mcap_reader.py (the study's channels; `trial` picks one of several).
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from types import MappingProxyType
from typing import Any

from pydantic import BaseModel, ValidationError

from .mcap_reader import read_trial_mcap
from .model import AGENTS, Intervention, MetricsInputError, StateUpdate, TrialData

UPDATE_COLUMNS = ("agent", "action", "start", "stop")
INTERVENTION_COLUMNS = ("start", "stop", "subtask", "note")
_FIXES = MappingProxyType({
    "agent": f"write one of: {', '.join(AGENTS)} (lower case)",
    "action": "give the action a non-empty name",
    "start": "write the time in seconds since the study start, e.g. 12.5",
    "stop": "write the time in seconds, at or after start; leave it empty (CSV) or null (JSON) if unfinished",
    "subtask": "name the robot subtask, or leave it empty",
    "note": "write text, or leave it empty",
})


def read_trial(path: Path | str, trial: str | None = None) -> TrialData:
    """Read a trial in whichever supported format its extension names (`trial`: which one, in a recording)."""
    path = Path(path)
    match path.suffix.lower():
        case ".csv":
            return TrialData(updates=read_updates_csv(path))
        case ".json":
            return read_trial_json(path)
        case ".mcap":
            return read_trial_mcap(path, trial)
        case _:
            raise MetricsInputError(path, f"unknown trial file type {path.suffix or '(no extension)'!r}",
                                    "pass a .csv or .json file (see `vr-teleop metrics --help`)")


def read_interventions(path: Path | str) -> list[Intervention]:
    path = Path(path)
    match path.suffix.lower():
        case ".csv":
            rows = _csv_rows(path, required=("start",), allowed=INTERVENTION_COLUMNS)
            return [_validate(Intervention, _nonempty(cells), path, row) for row, cells in rows]
        case ".json":
            data = _load_json(path)
            return _json_items(Intervention, data, path, "interventions", required=("start",))
        case _:
            raise MetricsInputError(path, f"unknown interventions file type {path.suffix or '(none)'!r}",
                                    "pass a .csv (start,stop,subtask,note) or .json file")


def read_updates_csv(path: Path | str) -> list[StateUpdate]:
    path = Path(path)
    rows = _csv_rows(path, required=UPDATE_COLUMNS, allowed=UPDATE_COLUMNS)
    return [_validate(StateUpdate, _nonempty(cells, keep=("agent", "action")), path, row) for row, cells in rows]


def read_trial_json(path: Path | str) -> TrialData:
    path = Path(path)
    data = _load_json(path)
    if isinstance(data, list):
        return TrialData(updates=_json_items(StateUpdate, data, path, None, required=UPDATE_COLUMNS))
    if isinstance(data, dict):
        unknown = sorted(set(data) - {"updates", "interventions", "planned_subtasks"})
        if unknown:
            raise MetricsInputError(path, f"unknown top-level key(s) {', '.join(map(repr, unknown))}",
                                    'use only "updates", "interventions" and "planned_subtasks"')
        if "updates" not in data:
            raise MetricsInputError(path, 'the top-level object has no "updates" list',
                                    'put the state updates under "updates": [...]')
        updates = _json_items(StateUpdate, data["updates"], path, "updates", required=UPDATE_COLUMNS)
        interventions = None
        if "interventions" in data:
            interventions = _json_items(Intervention, data["interventions"], path, "interventions",
                                        required=("start",))
        planned = data.get("planned_subtasks")
        if planned is not None and (type(planned) is not int or planned < 0):
            raise MetricsInputError(path, f"planned_subtasks is {planned!r}, not a whole number >= 0",
                                    "write the number of planned robot subtasks, e.g. 20", column="planned_subtasks")
        return TrialData(updates=updates, interventions=interventions, planned_subtasks=planned)
    raise MetricsInputError(path, f"the top level is a JSON {type(data).__name__}",
                            'write a list of state updates or an object {"updates": [...]}')


# ---- helpers ---------------------------------------------------------------------------------------------


def _open_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise MetricsInputError(path, "file not found", "check the path") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise MetricsInputError(path, f"cannot read the file ({exc})", "pass a readable UTF-8 text file") from None


def _csv_rows(path: Path, required: tuple[str, ...], allowed: tuple[str, ...]) -> list[tuple[int, dict[str, str]]]:
    """(line number, {column: stripped cell}) for each non-blank data row, after checking the header."""
    lines = _open_text(path).splitlines()
    reader = csv.reader(lines)
    header = next(reader, None)
    if header is None or not any(h.strip() for h in header):
        raise MetricsInputError(path, "the file is empty or has no header", f"start with the header line {','.join(allowed)}",
                                row=1)
    header = [h.strip() for h in header]
    for name in header:
        if name not in allowed:
            raise MetricsInputError(path, f"unknown column {name!r}", f"use the columns {','.join(allowed)}",
                                    row=1, column=name)
    missing = [c for c in required if c not in header]
    if missing:
        raise MetricsInputError(path, f"missing column(s) {', '.join(missing)}",
                                f"the header must be {','.join(allowed)}", row=1, column=missing[0])
    duplicated = sorted({h for h in header if header.count(h) > 1})
    if duplicated:
        raise MetricsInputError(path, f"column {duplicated[0]!r} appears twice", "keep one of them",
                                row=1, column=duplicated[0])
    out = []
    for cells in reader:
        line = reader.line_num
        if not any(c.strip() for c in cells):
            continue
        if len(cells) != len(header):
            raise MetricsInputError(path, f"{len(cells)} fields where the header has {len(header)}",
                                    "give every row one value per header column (quote names containing commas)",
                                    row=line)
        row = {name: cell.strip() for name, cell in zip(header, cells)}
        for name in ("start", "stop"):
            if row.get(name):
                row[name] = _number(row[name], path, line, name)  # type: ignore[assignment]
        out.append((line, row))
    return out


def _number(text: str, path: Path, row: int, column: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise MetricsInputError(path, f"{text!r} is not a number", _FIXES[column], row=row, column=column) from None
    if not math.isfinite(value):
        raise MetricsInputError(path, f"{text!r} is not a finite time", _FIXES[column], row=row, column=column)
    return value


def _nonempty(cells: dict[str, Any], keep: tuple[str, ...] = ()) -> dict[str, Any]:
    """Empty CSV cells mean 'not given' (stop: still running), except where emptiness is itself the error."""
    return {k: v for k, v in cells.items() if v != "" or k in keep}


def _validate(model: type[BaseModel], data: Any, path: Path, row: int | str) -> Any:
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = [str(p) for p in err["loc"]]
        column = loc[0] if loc else None
        if err["type"] == "extra_forbidden":
            allowed = ", ".join(model.model_fields)
            raise MetricsInputError(path, f"unknown key {column!r}", f"use only the keys {allowed}",
                                    row=row, column=column) from None
        if column is None:  # a rule across fields (stop before start)
            column = "stop"
        message = str(err["msg"]).removeprefix("Value error, ")
        if err["type"] == "missing":
            message = "no value"
        if column in ("agent",) and err["type"] == "literal_error":
            message = f"unknown agent {err['input']!r}"
        raise MetricsInputError(path, message, _FIXES.get(column, "correct the value"), row=row,
                                column=column) from None


def _load_json(path: Path) -> Any:
    try:
        return json.loads(_open_text(path))
    except json.JSONDecodeError as exc:
        raise MetricsInputError(path, f"invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}",
                                "fix the JSON syntax there") from None


def _json_items(model: type[BaseModel], data: Any, path: Path, key: str | None,
                required: tuple[str, ...]) -> list[Any]:
    where = f'"{key}"' if key else "the top level"
    if not isinstance(data, list):
        raise MetricsInputError(path, f"{where} is a JSON {type(data).__name__}, not a list",
                                "write a list of objects [{...}, ...]", column=key)
    out = []
    for index, item in enumerate(data):
        row = f"entry {key or ''}[{index}]"
        if not isinstance(item, dict):
            raise MetricsInputError(path, f"the entry is a JSON {type(item).__name__}, not an object",
                                    "write each entry as an object {...}", row=row)
        missing = [k for k in required if k not in item]
        if missing:
            fix = ('add "stop": null for an action still running at the end' if missing == ["stop"]
                   else f"give every entry the keys {', '.join(required)}")
            raise MetricsInputError(path, f"missing key(s) {', '.join(missing)}", fix, row=row, column=missing[0])
        out.append(_validate(model, item, path, row))
    return out
