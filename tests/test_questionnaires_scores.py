"""SUS, NASA-TLX and Godspeed: each published scoring rule against hand-computed cases, plus their validation."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
import yaml

from vr_teleop_server.questionnaires.definitions import DefinitionError, data_file
from vr_teleop_server.questionnaires.godspeed import (load_godspeed_definition, score_godspeed,
                                                      series_means)
from vr_teleop_server.questionnaires.sheets import SheetError, read_sheet
from vr_teleop_server.questionnaires.sus import load_sus_definition, score_sus, sus_score
from vr_teleop_server.questionnaires.tlx import load_tlx_definition, raw_tlx, score_tlx, weighted_tlx


def answers(*values):
    return {f"Q{i}": v for i, v in enumerate(values, start=1)}


def write_rows(path: Path, header: list[str], rows: list[list[str]]) -> Path:
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        writer.writerows(rows)
    return path


# ---- SUS ---------------------------------------------------------------------------------------------------------

def test_sus_brooke_worked_example():
    # Brooke (1996), scoring example: item contributions 4,1,1,4,1,2,1,1,4,3 (total 22) -> SUS 22 x 2.5 = 55.
    # Answers giving those contributions: odd items answer = contribution + 1, even items answer = 5 - contribution.
    assert sus_score(answers(5, 4, 2, 1, 2, 3, 2, 4, 5, 2)) == 55.0


@pytest.mark.parametrize("values, expected", [
    ((5, 1, 5, 1, 5, 1, 5, 1, 5, 1), 100.0),  # best answer everywhere: 10 x 4 x 2.5
    ((1, 5, 1, 5, 1, 5, 1, 5, 1, 5), 0.0),
    ((3,) * 10, 50.0),  # every contribution 2
    ((2, 1, 4, 1, 4, 3, 4, 2, 3, 3), 67.5),  # odd: 1+3+3+3+2 = 12, even: 4+4+2+3+2 = 15; 27 x 2.5
    ((4, 2, 4, 2, 4, 2, 4, 2, 4, 2), 75.0),  # all contributions 3: 30 x 2.5
])
def test_sus_hand_computed(values, expected):
    assert sus_score(answers(*values)) == expected


def test_sus_items_follow_brookes_keying():
    definition = load_sus_definition()
    assert [i.positive for i in definition.items] == [True, False] * 5


def test_sus_sheet_scores_complete_rows_and_lists_incomplete(tmp_path):
    header = ["respondent_id", "condition"] + [f"Q{i}" for i in range(1, 11)]
    path = write_rows(tmp_path / "sus.csv", header, [
        ["A", "VR", "5", "1", "5", "1", "5", "1", "5", "1", "5", "1"],
        ["B", "VR", "3", "3", "3", "3", "3", "3", "3", "3", "3", "3"],
        ["C", "VR", "3", "3", "-", "3", "3", "3", "", "3", "3", "3"],
        ["D", "tablet", "1", "5", "1", "5", "1", "5", "1", "5", "1", "5"],
    ])
    report = score_sus(read_sheet(path, load_sus_definition().sheet_spec()), by="condition")
    assert [r.score for r in report.respondents] == [100.0, 50.0, None, 0.0]
    assert report.respondents[2].missing_items == ["Q3", "Q7"]
    vr, tablet = report.subsets
    assert (vr.label, vr.rows, vr.incomplete, vr.score.n, vr.score.mean) == ("VR", 3, 1, 2, 75.0)
    assert tablet.score.mean == 0.0 and tablet.score.sd is None


def test_sus_sheet_validation(tmp_path):
    header = ["respondent_id"] + [f"Q{i}" for i in range(1, 11)]
    path = write_rows(tmp_path / "sus.csv", header, [["A"] + ["6"] + ["3"] * 9, ["A"] + ["3"] * 10])
    with pytest.raises(SheetError) as info:
        read_sheet(path, load_sus_definition().sheet_spec())
    assert [str(i) for i in info.value.issues] == [
        f'{path}, row 2, column Q1: "6" is outside 1-5 (use 1-5, or "-" for missing)',
        f'{path}, row 3, column respondent_id: "A" appears twice for this sheet (also on row 2); '
        "a respondent has one row per condition",
    ]


# ---- NASA-TLX ----------------------------------------------------------------------------------------------------

RATINGS = {"mental_demand": 70, "physical_demand": 20, "temporal_demand": 55, "performance": 30, "effort": 60,
           "frustration": 45}
WEIGHTS = {"mental_demand": 5, "physical_demand": 0, "temporal_demand": 3, "performance": 2, "effort": 4,
           "frustration": 1}


def test_tlx_hand_computed():
    assert raw_tlx(RATINGS) == pytest.approx(280 / 6)  # 70+20+55+30+60+45 = 280
    # 5x70 + 0x20 + 3x55 + 2x30 + 4x60 + 1x45 = 350 + 0 + 165 + 60 + 240 + 45 = 860
    assert weighted_tlx(RATINGS, WEIGHTS) == pytest.approx(860 / 15)
    with pytest.raises(ValueError, match="sum to 15"):
        weighted_tlx(RATINGS, {**WEIGHTS, "effort": 3})


def tlx_header():
    ids = list(RATINGS)
    return ["respondent_id"] + ids + [f"w_{k}" for k in ids]


def test_tlx_sheet_raw_and_weighted(tmp_path):
    ids = list(RATINGS)
    path = write_rows(tmp_path / "tlx.csv", tlx_header(), [
        ["A"] + [str(RATINGS[k]) for k in ids] + [str(WEIGHTS[k]) for k in ids],
        ["B"] + ["50"] * 6 + [""] * 6,
        ["C"] + ["50"] * 5 + ["-"] + ["-"] * 6,
    ])
    report = score_tlx(read_sheet(path, load_tlx_definition().sheet_spec()))
    a, b, c = report.respondents
    assert a.raw == pytest.approx(280 / 6) and a.weighted == pytest.approx(860 / 15)
    assert b.raw == 50 and b.weighted is None and b.weights is None
    assert c.raw is None and c.missing_ratings == ["frustration"]
    (subset,) = report.subsets
    assert subset.raw.n == 2 and subset.raw.missing == 1 and subset.weighted.n == 1
    assert subset.subscales["mental_demand"].mean == pytest.approx(170 / 3)


def test_tlx_weight_errors(tmp_path):
    ids = list(RATINGS)
    ratings = [str(RATINGS[k]) for k in ids]
    path = write_rows(tmp_path / "tlx.csv", tlx_header(), [
        ["A"] + ratings + ["5", "0", "3", "2", "4", "2"],  # sums to 16
        ["B"] + ratings + ["5", "0", "3", "2", "", ""],  # partial
        ["C"] + ratings + ["6", "0", "3", "2", "3", "1"],  # a weight above 5
        ["D"] + ["101"] + ratings[1:] + [""] * 6,
    ])
    with pytest.raises(SheetError) as info:
        read_sheet(path, load_tlx_definition().sheet_spec())
    assert [str(i) for i in info.value.issues] == [
        f"{path}, row 2, column w_mental_demand..w_frustration: the weights sum to 16, but the 15 pairwise "
        "comparisons give weights that sum to 15 (each weight is how often that subscale was chosen)",
        f"{path}, row 3, column w_effort: weights must be given for all six subscales or for none "
        "(missing: w_effort, w_frustration)",
        f'{path}, row 4, column w_mental_demand: "6" is outside 0-5 (use 0-5, or "-" for missing)',
        f'{path}, row 5, column mental_demand: "101" is outside 0-100 (use a number 0-100, or "-" for missing)',
    ]


# ---- Godspeed ----------------------------------------------------------------------------------------------------

def test_godspeed_items_are_the_published_five_series():
    definition = load_godspeed_definition()
    counts = {s.id: len(s.items) for s in definition.series}
    assert counts == {"anthropomorphism": 5, "animacy": 6, "likeability": 5, "perceived_intelligence": 5,
                      "perceived_safety": 3}
    assert [(i.left, i.right) for i in definition.series[4].items] == [
        ("Anxious", "Relaxed"), ("Agitated", "Calm"), ("Quiescent", "Surprised")]
    assert not any(i.reverse for i in definition.items)  # the published English form reverses none


def godspeed_answers(definition, value=3, **overrides):
    result = {i.id: value for i in definition.items}
    result.update(overrides)
    return result


def test_godspeed_series_means_hand_computed():
    definition = load_godspeed_definition()
    values = godspeed_answers(definition, ANT1=1, ANT2=2, ANT3=3, ANT4=4, ANT5=5, SAF1=5, SAF2=4, SAF3=None)
    means = series_means(values, definition)
    assert means["anthropomorphism"] == 3.0  # (1+2+3+4+5) / 5
    assert means["animacy"] == 3.0
    assert means["perceived_safety"] is None  # a missing item leaves the series unscored


def test_godspeed_reverse_keyed_items(tmp_path):
    document = yaml.safe_load(data_file("godspeed.yaml").read_text())
    document["series"][4]["items"][2]["reverse"] = True  # SAF3 read with "surprised" as the unsafe pole
    document["series"][0]["items"][0].update(left="Natural", right="Fake", reverse=True)
    items = tmp_path / "items.yaml"
    items.write_text(yaml.safe_dump(document))
    definition = load_godspeed_definition(items)
    values = godspeed_answers(definition, SAF1=5, SAF2=4, SAF3=1, ANT1=2, ANT2=4, ANT3=4, ANT4=4, ANT5=4)
    means = series_means(values, definition)
    assert means["perceived_safety"] == pytest.approx((5 + 4 + (6 - 1)) / 3)
    assert means["anthropomorphism"] == pytest.approx(((6 - 2) + 4 + 4 + 4 + 4) / 5)


def test_godspeed_bad_item_file_is_reported(tmp_path):
    document = yaml.safe_load(data_file("godspeed.yaml").read_text())
    document["series"][1]["items"][0]["id"] = "ANT1"
    document["series"][2]["items"][0]["reverse"] = "maybe"
    items = tmp_path / "items.yaml"
    items.write_text(yaml.safe_dump(document))
    with pytest.raises(DefinitionError) as info:
        load_godspeed_definition(items)
    assert str(info.value).startswith(f"{items}: series.2.items.0.reverse: Input should be a valid boolean")
    document["series"][2]["items"][0]["reverse"] = False
    items.write_text(yaml.safe_dump(document))
    with pytest.raises(DefinitionError, match="item ids must be unique, repeated: ANT1"):
        load_godspeed_definition(items)


def test_godspeed_sheet_summary_and_alpha(tmp_path):
    definition = load_godspeed_definition()
    ids = [i.id for i in definition.items]
    rows = [["A"] + ["4"] * len(ids), ["B"] + ["2"] * len(ids), ["C"] + ["3"] * len(ids)]
    rows[2][1 + ids.index("LIK2")] = "-"
    path = write_rows(tmp_path / "g.csv", ["respondent_id"] + ids, rows)
    report = score_godspeed(read_sheet(path, definition.sheet_spec()), definition)
    series = {s.id: s for s in report.subsets[0].series}
    assert series["animacy"].score.mean == 3.0 and series["animacy"].score.n == 3
    like = series["likeability"]
    assert like.score.n == 2 and like.score.missing == 1 and like.score.mean == 3.0
    assert report.respondents[2].missing_items == {"likeability": ["LIK2"]}
    # perfectly consistent items: every item equals the total / k, so alpha = 1
    assert series["animacy"].cronbach_alpha == pytest.approx(1.0)
