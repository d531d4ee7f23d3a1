"""QAM scoring: the paper's Table 1 round-trips, statistics match hand computations."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from vr_teleop_server.questionnaires.definitions import data_file
from vr_teleop_server.questionnaires.qam import format_qam_report, load_qam_definition, score_qam
from vr_teleop_server.questionnaires.sheets import read_sheet, write_template
from vr_teleop_server.questionnaires.stats import cronbach_alpha, describe, rank_biserial, wilcoxon_paired

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "qam_paper_table1.csv"

# Botev and Rodriguez Lera (HCII 2020), Table 1: id -> (group, expected, perceived); None is the paper's "-".
TABLE1 = {
    1: ("hri_system", 1, 1), 2: ("hri_system", 4, 5), 3: ("hri_system", 3, 4), 4: ("hri_system", None, None),
    5: ("hri_system", None, None), 6: ("hri_system", None, None), 7: ("hri_system", 5, 5),
    8: ("hri_system", 5, 5), 9: ("hri_system", 5, 5), 10: ("hri_system", 3, 2), 11: ("robot", 1, 3),
    12: ("robot", 1, 1), 13: ("robot", 1, 3), 14: ("remote_operator", 5, 5), 15: ("remote_operator", 2, 1),
    16: ("remote_operator", 5, 5), 17: ("remote_operator", 1, 1), 18: ("remote_operator", 3, 5),
    19: ("remote_operator", 1, 1), 20: ("remote_operator", 3, 3), 21: ("remote_operator", 5, 5),
    22: ("bystander", 1, 1), 23: ("bystander", 1, 1), 24: ("bystander", 3, 5), 25: ("bystander", 1, 1),
    26: ("bystander", 3, 5), 27: ("bystander", 5, 5), 28: ("bystander", 5, 5), 29: ("bystander", 3, 5),
    30: ("bystander", 1, 1), 31: ("bystander", 1, 1), 32: ("bystander", 3, 5), 33: ("bystander", 5, 5),
}


@pytest.fixture(scope="module")
def definition():
    return load_qam_definition()


def test_definition_is_the_papers_33_parameters_in_4_groups(definition):
    assert [g.name for g in definition.groups] == ["HRI system", "Robot", "Remote operator", "Bystander"]
    assert {p.id: p.group for p in definition.parameters} == {k: v[0] for k, v in TABLE1.items()}
    assert [p.id for p in definition.parameters if p.objective] == [4, 5, 6]
    assert definition.parameters[13].name == "Human-robot situation awareness"
    assert definition.parameters[25].name == "Social acceptance"


def test_shipped_example_is_packaged_unchanged():
    assert EXAMPLE.read_bytes() == data_file("examples", "qam_paper_table1.csv").read_bytes()


def test_paper_table_round_trips(definition):
    report = score_qam(read_sheet(EXAMPLE, definition.sheet_spec()), definition)
    (subset,) = report.subsets
    assert (subset.expected_rows, subset.perceived_rows, subset.paired_raters) == (1, 1, 1)
    for p in subset.parameters:
        _, expected, perceived = TABLE1[p.id]
        assert p.expected.median == expected and p.perceived.median == perceived, p.id
        assert p.expected.n == (0 if expected is None else 1)
        assert p.expected.missing == (1 if expected is None else 0)
        assert p.difference == (None if expected is None else perceived - expected)
        assert not p.test.tested
        assert p.test.note.startswith("no pairs" if expected is None else "n too small: 1 pair, ")
    # the parameters the paper discusses
    by_id = {p.id: p for p in subset.parameters}
    assert by_id[14].difference == 0 and by_id[26].difference == 2 and by_id[29].difference == 2


def test_group_summary_of_the_paper_table(definition):
    report = score_qam(read_sheet(EXAMPLE, definition.sheet_spec()), definition)
    groups = {g.id: g for g in report.subsets[0].groups}
    hri = groups["hri_system"]
    # expected Likert answers 1,4,3,5,5,5,3 -> sorted 1,3,3,4,5,5,5: median 4, Q1 3, Q3 5
    assert hri.likert_parameters == [1, 2, 3, 7, 8, 9, 10] and hri.objective_parameters == [4, 5, 6]
    assert (hri.expected.median, hri.expected.q1, hri.expected.q3) == (4, 3, 5)
    assert (hri.perceived.median, hri.perceived.iqr) == (5, 2)
    assert (hri.higher, hri.lower, hri.unchanged) == ([2, 3], [10], [1, 7, 8, 9])
    by = groups["bystander"]
    assert by.higher == [24, 26, 29, 32] and by.lower == [] and by.difference == 2
    assert groups["remote_operator"].higher == [18] and groups["remote_operator"].lower == [15]
    assert not by.test.tested and by.test.n_pairs == 1


def test_text_report_says_the_test_was_not_run(definition):
    report = score_qam(read_sheet(EXAMPLE, definition.sheet_spec()), definition)
    text = format_qam_report(report, definition)
    assert "Wilcoxon signed-rank test: not run, n too small. 1 rater answered both phases" in text
    line = next(l for l in text.splitlines() if l.strip().startswith("26 "))
    assert line.split() == ["26", "Social", "acceptance", "1", "3", "0", "1", "5", "0", "+2", "0/0"]
    assert "Bystander (Student, Educational Professional)" in text


def test_json_sheet_gives_the_same_result_as_csv(tmp_path, definition):
    spec = definition.sheet_spec()
    path = tmp_path / "table1.json"
    write_template(path, spec, respondents=1)
    document = json.loads(path.read_text())
    for row in document["rows"]:
        column = 1 if row["phase"] == "expected" else 2
        row.update({f"P{i}": TABLE1[i][column] for i in TABLE1})  # None -> null -> missing
    path.write_text(json.dumps(document))
    from_json = score_qam(read_sheet(path, spec), definition)
    from_csv = score_qam(read_sheet(EXAMPLE, spec), definition)
    strip = lambda report: [p.model_dump() for p in report.subsets[0].parameters]  # noqa: E731
    assert strip(from_json) == strip(from_csv)
    # and the JSON report itself round-trips through the model
    assert type(from_csv).model_validate_json(from_csv.model_dump_json()) == from_csv


def write_sheet(path: Path, rows: list[dict]) -> Path:
    header = ["respondent_id", "phase", "role", "condition"] + [f"P{i}" for i in range(1, 34)]
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=header, restval="-")
        writer.writeheader()
        writer.writerows(rows)
    return path


def test_several_raters_medians_and_wilcoxon(tmp_path, definition):
    # P1: expected 1 for all 7 raters, perceived 2,3,2,4,2,3,5 -> all 7 differences positive
    perceived = [2, 3, 2, 4, 2, 3, 5]
    rows = []
    for i, value in enumerate(perceived):
        rows.append({"respondent_id": f"S{i}", "phase": "expected", "P1": "1", "P2": "3"})
        rows.append({"respondent_id": f"S{i}", "phase": "perceived", "P1": str(value), "P2": "3"})
    rows.append({"respondent_id": "only-before", "phase": "expected", "P1": "5", "P2": "-"})
    report = score_qam(read_sheet(write_sheet(tmp_path / "a.csv", rows), definition.sheet_spec()), definition)
    (subset,) = report.subsets
    assert (subset.expected_rows, subset.perceived_rows, subset.paired_raters) == (8, 7, 7)
    p1, p2 = subset.parameters[0], subset.parameters[1]
    assert p1.expected.n == 8 and p1.expected.median == 1  # 1,1,1,1,1,1,1,5
    assert p1.perceived.median == 3 and p1.perceived.q1 == 2 and p1.perceived.q3 == 3.5
    assert p1.difference == 2
    assert p1.test.tested and p1.test.n_pairs == 7 and p1.test.n_nonzero == 7
    assert p1.test.statistic == 0 and p1.test.rank_biserial == 1
    assert 0 < p1.test.p_value < 0.05
    assert p2.expected.missing == 1 and not p2.test.tested and p2.test.n_nonzero == 0
    # group test on per-rater means over P1, P2 (both answered): still 7 positive differences
    hri = subset.groups[0]
    assert hri.test.tested and hri.test.n_pairs == 7 and hri.test.rank_biserial == 1
    text = format_qam_report(report, definition)
    assert "Wilcoxon signed-rank, perceived vs expected" in text and "too few (0 differ)" in text


def test_by_condition_scores_each_condition_apart(tmp_path, definition):
    rows = [{"respondent_id": "S1", "phase": "expected", "condition": "VR", "P1": "2"},
            {"respondent_id": "S1", "phase": "perceived", "condition": "VR", "P1": "4"},
            {"respondent_id": "S1", "phase": "expected", "condition": "tablet", "P1": "3"},
            {"respondent_id": "S2", "phase": "perceived", "condition": "", "P1": "1"}]
    sheet = read_sheet(write_sheet(tmp_path / "a.csv", rows), definition.sheet_spec())
    report = score_qam(sheet, definition, by="condition")
    labels = [s.label for s in report.subsets]
    assert labels == ["VR", "tablet", "(no condition)"]
    vr, tablet, none = report.subsets
    assert vr.parameters[0].difference == 2 and vr.paired_raters == 1
    assert tablet.parameters[0].expected.median == 3 and tablet.parameters[0].difference is None
    assert tablet.paired_raters == 0 and none.perceived_rows == 1
    whole = score_qam(sheet, definition)
    assert whole.subsets[0].paired_raters == 1  # pairs never cross conditions
    assert "Note: no perceived rows here" in format_qam_report(report, definition)


def test_wilcoxon_hand_computed():
    # differences 1..6, all positive: W = 0, exact two-sided p = 2 / 2**6
    result = wilcoxon_paired([0] * 6, [1, 2, 3, 4, 5, 6])
    assert result.tested and result.statistic == 0 and result.p_value == pytest.approx(2 / 64)
    assert result.rank_biserial == 1
    # differences 1,-2,3,4,5,6: R- = 2, R+ = 19; p = 2 * #{sign sets with R- <= 2} / 64 = 2 * 3 / 64
    result = wilcoxon_paired([0] * 6, [1, -2, 3, 4, 5, 6])
    assert result.statistic == 2 and result.p_value == pytest.approx(6 / 64)
    assert result.rank_biserial == pytest.approx(17 / 21)
    assert result.median_difference == 3.5


def test_wilcoxon_says_when_n_is_too_small():
    result = wilcoxon_paired([1, 1, 1, 1, 1], [2, 3, 2, 4, 2])
    assert not result.tested and result.p_value is None
    assert result.note == "n too small: 5 pairs, 5 with a difference; the test needs at least 6"
    assert wilcoxon_paired([], []).note == "no pairs: no rater gave both an expected and a perceived answer"
    zeros = wilcoxon_paired([3] * 10, [3] * 9 + [4])
    assert not zeros.tested and zeros.n_pairs == 10 and zeros.n_nonzero == 1


def test_rank_biserial_with_ties():
    # |d| = 1,1,2 -> ranks 1.5,1.5,3; d = +1,-1,+2: R+ = 4.5, R- = 1.5 -> (4.5 - 1.5) / 6
    assert rank_biserial([1, -1, 2, 0]) == pytest.approx(0.5)


def test_describe_hand_computed():
    d = describe([1, 2, None, 4, 5, None])
    assert (d.n, d.missing, d.median, d.q1, d.q3, d.iqr) == (4, 2, 3, 1.75, 4.25, 2.5)
    assert d.mean == 3 and d.sd == pytest.approx(np.std([1, 2, 4, 5], ddof=1))
    assert describe([None, None]).model_dump(exclude_none=True) == {"n": 0, "missing": 2}


def test_cronbach_alpha_hand_computed():
    # item variances 1 and 1/3, total variance 7/3: alpha = 2 * (1 - (4/3) / (7/3)) = 6/7
    assert cronbach_alpha(np.array([[1, 2], [2, 3], [3, 3]])) == pytest.approx(6 / 7)
    assert cronbach_alpha(np.array([[3, 3], [3, 3]])) is None
