"""Answer-sheet validation: every error names file, row and column, and all errors are reported together."""

from __future__ import annotations

import json

import pytest

from vr_teleop_server.questionnaires.qam import load_qam_definition
from vr_teleop_server.questionnaires.sheets import SheetError, read_sheet, write_template
from vr_teleop_server.questionnaires.sus import load_sus_definition

HEADER = ["respondent_id", "phase", "role", "condition"] + [f"P{i}" for i in range(1, 34)]


@pytest.fixture(scope="module")
def spec():
    return load_qam_definition().sheet_spec()


def qam_row(respondent="R1", phase="expected", fill="3", **cells):
    row = {name: "" for name in HEADER}
    row.update({"respondent_id": respondent, "phase": phase})
    row.update({f"P{i}": fill for i in range(1, 34)})
    row.update({"P4": "-", "P5": "-", "P6": "-"})
    row.update(cells)
    return row


def write_csv(path, rows, header=HEADER, delimiter=","):
    lines = [delimiter.join(header)]
    for row in rows:
        lines.append(delimiter.join(row[name] if isinstance(row, dict) else row[i]
                                    for i, name in enumerate(header)))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def errors(path, spec):
    with pytest.raises(SheetError) as info:
        read_sheet(path, spec)
    return [str(issue) for issue in info.value.issues]


def test_valid_sheet_reads_values_and_counts_missing(tmp_path, spec):
    path = write_csv(tmp_path / "a.csv", [qam_row(P7="", P8="-", P9="4"), qam_row(phase="perceived")])
    sheet = read_sheet(path, spec)
    assert len(sheet.rows) == 2
    first = sheet.rows[0]
    assert first.row == 2 and first.respondent_id == "R1" and first.phase == "expected"
    assert first.values["P7"] is None and first.values["P8"] is None and first.values["P9"] == 4.0
    assert first.values["P1"] == 3.0


@pytest.mark.parametrize("cell, message", [
    ("7", '"7" is outside 1-5 (use 1-5, or "-" for missing)'),
    ("0", '"0" is outside 1-5 (use 1-5, or "-" for missing)'),
    ("abc", '"abc" is not a number (use 1-5, or "-" for missing)'),
    ("3.5", '"3.5" is not a whole number (use 1-5, or "-" for missing)'),
    ("nan", '"nan" is not a number (use 1-5, or "-" for missing)'),
    ("n/a", '"n/a" is not a number (use 1-5, or "-" for missing)'),
])
def test_bad_likert_cell_names_file_row_and_column(tmp_path, spec, cell, message):
    rows = [qam_row("R1"), qam_row("R2"), qam_row("R3"), qam_row("R4", P12=cell)]
    path = write_csv(tmp_path / "answers.csv", rows)
    assert errors(path, spec) == [f"{path}, row 5, column P12: {message}"]


def test_whole_number_written_as_decimal_is_accepted(tmp_path, spec):
    sheet = read_sheet(write_csv(tmp_path / "a.csv", [qam_row(P1="4.0")]), spec)
    assert sheet.rows[0].values["P1"] == 4.0


def test_objective_parameters_take_numbers_on_their_own_scale(tmp_path, spec):
    ok = read_sheet(write_csv(tmp_path / "ok.csv", [qam_row(P4="87.5", P5="312", P6="0")]), spec)
    assert ok.rows[0].values["P4"] == 87.5 and ok.rows[0].values["P5"] == 312.0
    path = write_csv(tmp_path / "bad.csv", [qam_row(P4="120", P5="-3", P6="x")])
    found = errors(path, spec)
    assert len(found) == 3
    assert found[0].startswith(f'{path}, row 2, column P4: "120" is outside 0-100 (use a number 0-100 (% of')
    assert found[1].startswith(f'{path}, row 2, column P5: "-3" is below 0 (use a number >= 0 (seconds')
    assert found[2].startswith(f'{path}, row 2, column P6: "x" is not a number')


def test_unknown_column_is_an_error_with_a_suggestion(tmp_path, spec):
    header = HEADER + ["P34"]
    path = write_csv(tmp_path / "a.csv", [{**qam_row(), "P34": "3"}], header=header)
    (message,) = errors(path, spec)
    assert message.startswith(f'{path}, row 1, column P34: unknown column "P34"')
    header = [("respondant_id" if h == "respondent_id" else h) for h in HEADER]
    path = write_csv(tmp_path / "b.csv", [list(qam_row().values())], header=header)
    found = errors(path, spec)
    assert any('column respondant_id: unknown column "respondant_id" (did you mean "respondent_id"?' in m
               for m in found)
    assert any("column respondent_id: is missing" in m for m in found)


def test_duplicate_and_missing_columns(tmp_path, spec):
    header = HEADER[:-1] + ["P1"]  # P33 replaced by a second P1
    path = write_csv(tmp_path / "a.csv", [list(qam_row().values())], header=header)
    found = errors(path, spec)
    assert f"{path}, row 1, column P1: appears twice in the header (columns 5 and 37); keep one" in found
    assert any(m.startswith(f"{path}, row 1, column P33: is missing") for m in found)


def test_sheet_of_another_questionnaire_gets_one_clear_message(tmp_path, spec):
    header = ["respondent_id"] + [f"Q{i}" for i in range(1, 11)]
    path = write_csv(tmp_path / "sus.csv", [["R1"] + ["3"] * 10], header=header)
    found = errors(path, spec)
    assert any("none of the QAM answer columns is in the header; is this a QAM sheet?" in m for m in found)
    assert sum("is missing" in m for m in found) == 1  # only the phase column, not 33 P-columns


def test_duplicate_respondent_and_phase(tmp_path, spec):
    rows = [qam_row("R1"), qam_row("R1", "perceived"), qam_row("R1")]
    path = write_csv(tmp_path / "a.csv", rows)
    assert errors(path, spec) == [
        f'{path}, row 4, column respondent_id: "R1" appears twice for phase expected (also on row 2); '
        "a respondent has one expected and one perceived row per condition"]


def test_duplicate_respondent_within_a_condition(tmp_path, spec):
    rows = [qam_row("R1", condition="VR"), qam_row("R1", condition="tablet"), qam_row("R1", condition="VR")]
    path = write_csv(tmp_path / "a.csv", rows)
    assert errors(path, spec) == [
        f'{path}, row 4, column respondent_id: "R1" appears twice for phase expected, condition VR '
        "(also on row 2); a respondent has one expected and one perceived row per condition"]


def test_same_respondent_in_two_conditions_is_not_a_duplicate(tmp_path, spec):
    rows = [qam_row("R1", condition="VR"), qam_row("R1", condition="tablet")]
    sheet = read_sheet(write_csv(tmp_path / "a.csv", rows), spec)
    assert [r.condition for r in sheet.rows] == ["VR", "tablet"]


def test_missing_and_unknown_phase(tmp_path, spec):
    rows = [qam_row("R1", phase=""), qam_row("R2", phase="Before"), qam_row("R3", phase=" Perceived ")]
    path = write_csv(tmp_path / "a.csv", rows)
    assert errors(path, spec) == [
        f"{path}, row 2, column phase: the phase is missing (use expected or perceived)",
        f'{path}, row 3, column phase: "Before" is not a phase (use expected or perceived)',
    ]


def test_missing_phase_column(tmp_path, spec):
    header = [h for h in HEADER if h != "phase"]
    row = qam_row()
    path = write_csv(tmp_path / "a.csv", [[row[h] for h in header]], header=header)
    assert any(m.startswith(f"{path}, row 1, column phase: is missing") for m in errors(path, spec))


def test_empty_respondent_id(tmp_path, spec):
    path = write_csv(tmp_path / "a.csv", [qam_row("")])
    assert errors(path, spec) == [
        f"{path}, row 2, column respondent_id: is empty (every row needs a respondent id)"]


def test_all_errors_are_collected(tmp_path, spec):
    rows = [qam_row("R1", P1="9", P2="x"), qam_row("R1", phase=""), qam_row("R2", P33="6")]
    path = write_csv(tmp_path / "a.csv", rows)
    found = errors(path, spec)
    assert [m.split(":")[0] for m in found] == [
        f"{path}, row 2, column P1", f"{path}, row 2, column P2", f"{path}, row 3, column phase",
        f"{path}, row 4, column P33"]


def test_extra_cells_and_data_under_an_empty_header(tmp_path, spec):
    path = tmp_path / "a.csv"
    values = list(qam_row().values())
    path.write_text(",".join(HEADER) + ",\n" + ",".join(values) + ",5\n" + ",".join(values[:1] + ["perceived"]
                    + values[2:]) + ",,7\n", encoding="utf-8")
    found = errors(path, spec)
    assert found == [
        f'{path}, row 2, column #38: holds "5" under an empty header (name the column or clear the cell)',
        f"{path}, row 3: has 39 cells but the header has 38 columns (remove the extra cells or name their column)",
    ]


def test_blank_rows_are_skipped_and_reported(tmp_path, spec):
    path = tmp_path / "a.csv"
    empty = "," * (len(HEADER) - 1)
    values = ",".join(qam_row().values())
    path.write_text("\n".join([",".join(HEADER), values, empty, "", values.replace("expected", "perceived")])
                    + "\n", encoding="utf-8")
    sheet = read_sheet(path, spec)
    assert [r.row for r in sheet.rows] == [2, 5]
    assert sheet.blank_rows == (3, 4)


def test_semicolon_csv_with_bom_and_loose_header_case(tmp_path, spec):
    header = [h.upper() if h.startswith("P") else f" {h} " for h in HEADER]
    row = qam_row(P3="5")
    path = tmp_path / "excel.csv"
    path.write_text("\ufeff" + ";".join(header) + "\n" + ";".join(row.values()) + "\n", encoding="utf-8")
    sheet = read_sheet(path, spec)
    assert sheet.rows[0].values["P3"] == 5.0 and sheet.rows[0].respondent_id == "R1"


def test_file_level_errors(tmp_path, spec):
    assert errors(tmp_path / "nope.csv", spec)[0].startswith(f"{tmp_path / 'nope.csv'}: file not found")
    xlsx = tmp_path / "a.xlsx"
    xlsx.write_bytes(b"PK")
    assert errors(xlsx, spec) == [f'{xlsx}: unknown sheet format ".xlsx" (save the sheet as .csv or .json)']
    latin = tmp_path / "latin.csv"
    latin.write_bytes(",".join(HEADER).encode() + b"\nR\xe9,expected\n")
    assert "is not UTF-8 text" in errors(latin, spec)[0]
    empty = tmp_path / "empty.csv"
    empty.write_text("", encoding="utf-8")
    assert errors(empty, spec) == [f"{empty}, row 1: the sheet is empty (it needs a header row)"]
    header_only = write_csv(tmp_path / "header.csv", [])
    assert errors(header_only, spec) == [
        f"{header_only}: the sheet has no answer rows (add one row per respondent under the header)"]


def json_row(**cells):
    row = {f"P{i}": 3 for i in range(1, 34)}
    row.update({"respondent_id": "R1", "phase": "expected", "P4": None, "P5": "-", "P6": None})
    row.update(cells)
    return row


def test_json_sheet_reads_numbers_strings_and_nulls(tmp_path, spec):
    path = tmp_path / "a.json"
    path.write_text(json.dumps({"rows": [json_row(P1="4"), json_row(phase="perceived", P2=5.0)]}))
    sheet = read_sheet(path, spec)
    assert sheet.rows[0].values["P1"] == 4.0 and sheet.rows[0].values["P4"] is None
    assert sheet.rows[1].values["P2"] == 5.0 and sheet.rows[1].row == 2
    plain_list = tmp_path / "b.json"
    plain_list.write_text(json.dumps([json_row()]))
    assert len(read_sheet(plain_list, spec).rows) == 1


def test_json_errors_name_row_and_key(tmp_path, spec):
    path = tmp_path / "a.json"
    bad = json_row(P3=True, P7=8, Extra=1)
    del bad["P9"]
    path.write_text(json.dumps({"rows": [json_row(), bad, "oops"]}))
    found = errors(path, spec)
    assert found[0].startswith(f'{path}, row 2, column Extra: unknown column "Extra"')
    assert found[1].startswith(f"{path}, row 2, column P9: is missing")
    assert f'{path}, row 3: is str, expected an object of column: value' in found
    assert f'{path}, row 2, column P3: true is not a number (use 1-5, or "-" for missing)' in found
    assert f'{path}, row 2, column P7: "8" is outside 1-5 (use 1-5, or "-" for missing)' in found


def test_json_document_errors(tmp_path, spec):
    broken = tmp_path / "broken.json"
    broken.write_text('{"rows": [')
    assert errors(broken, spec)[0].startswith(f"{broken}: is not valid JSON")
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"questionnaire": "sus", "rows": [json_row()]}))
    assert f'{other}: this is a "sus" sheet, not a "qam" sheet (score it with `vr-teleop sus score`)' \
        in errors(other, spec)
    extra = tmp_path / "extra.json"
    extra.write_text(json.dumps({"rows": [json_row()], "meta": {}}))
    assert errors(extra, spec) == [
        f'{extra}: unknown top-level key "meta" (a JSON sheet is {{"rows": [...]}} or a list of rows)']
    twice = tmp_path / "twice.json"
    twice.write_text(json.dumps([{**json_row(), " p1 ": 2}]))
    assert errors(twice, spec) == [
        f"{twice}, row 1, column P1: is given twice in this row (keys differ only in case or spaces)"]
    shape = tmp_path / "shape.json"
    shape.write_text(json.dumps({"rows": {"a": 1}}))
    assert errors(shape, spec) == [f'{shape}: a JSON sheet must be a list of row objects, or {{"rows": [...]}}']


def test_templates_round_trip_through_the_reader(tmp_path, spec):
    for name in ("t.csv", "t.json"):
        count = write_template(tmp_path / name, spec, respondents=3)
        sheet = read_sheet(tmp_path / name, spec)
        assert count == 6 and len(sheet.rows) == 6
        assert [r.respondent_id for r in sheet.rows] == ["R01", "R01", "R02", "R02", "R03", "R03"]
        assert {r.phase for r in sheet.rows} == {"expected", "perceived"}
        assert all(v is None for r in sheet.rows for v in r.values.values())
    sus_spec = load_sus_definition().sheet_spec()
    write_template(tmp_path / "s.csv", sus_spec, respondents=2)
    header = (tmp_path / "s.csv").read_text().splitlines()[0]
    assert header == "respondent_id,role,condition," + ",".join(f"Q{i}" for i in range(1, 11))
