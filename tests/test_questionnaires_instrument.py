"""Instruments as data: the one YAML format, the SSQ's published scoring against hand-computed cases, answers
checked item by item, and a lab's own instrument added as a file."""

from __future__ import annotations

import pytest
import yaml

from vr_teleop_server.questionnaires.definitions import DefinitionError, data_file
from vr_teleop_server.questionnaires.instrument import (PACKAGED, PREFER_NOT, AnswerError, check_answers,
                                                        load_instrument, score)

SSQ_ITEMS = ["general_discomfort", "fatigue", "headache", "eyestrain", "difficulty_focusing",
             "increased_salivation", "sweating", "nausea", "difficulty_concentrating", "fullness_of_head",
             "blurred_vision", "dizzy_eyes_open", "dizzy_eyes_closed", "vertigo", "stomach_awareness", "burping"]


def ssq_answers(values):
    return dict(zip(SSQ_ITEMS, values, strict=True))


@pytest.mark.parametrize("name, measures", [
    ("qam", []),  # reported item by item
    ("sus", ["sus"]),
    ("tlx", ["tlx"]),
    ("godspeed", ["godspeed.anthropomorphism", "godspeed.animacy", "godspeed.likeability",
                  "godspeed.perceived_intelligence", "godspeed.perceived_safety"]),
    ("ssq", ["ssq", "ssq.nausea", "ssq.oculomotor", "ssq.disorientation"]),
])
def test_every_packaged_instrument_is_one_format(name, measures):
    instrument = load_instrument(name)
    assert instrument.id == name and name in PACKAGED
    assert instrument.measures() == measures


def test_ssq_is_kennedys_sixteen_symptoms_on_0_to_3():
    ssq = load_instrument("ssq")
    assert [i.id for i in ssq.all_items] == SSQ_ITEMS
    assert (ssq.scale.min, ssq.scale.max) == (0, 3)
    assert {s.id: (len(ssq.members(s)), s.multiplier) for s in ssq.subscales} == {
        "nausea": (7, 9.54), "oculomotor": (7, 7.58), "disorientation": (7, 13.92)}


@pytest.mark.parametrize("values, expected", [
    ([0] * 16, {"ssq": 0.0, "ssq.nausea": 0.0, "ssq.oculomotor": 0.0, "ssq.disorientation": 0.0}),
    # every symptom severe: raw sums 21, 21, 21 -> 21 x 9.54, 21 x 7.58, 21 x 13.92; total 63 x 3.74
    ([3] * 16, {"ssq": 235.62, "ssq.nausea": 200.34, "ssq.oculomotor": 159.18, "ssq.disorientation": 292.32}),
    # nausea: discomfort 2 + salivation 0 + sweating 1 + nausea 2 + concentrating 0 + stomach 1 + burping 0 = 6
    # oculomotor: discomfort 2 + fatigue 1 + headache 0 + eyestrain 3 + focusing 1 + concentrating 0 + blurred 2 = 9
    # disorientation: focusing 1 + nausea 2 + fullness 1 + blurred 2 + eyes open 0 + eyes closed 1 + vertigo 0 = 7
    ([2, 1, 0, 3, 1, 0, 1, 2, 0, 1, 2, 0, 1, 0, 1, 0],
     {"ssq": 22 * 3.74, "ssq.nausea": 6 * 9.54, "ssq.oculomotor": 9 * 7.58, "ssq.disorientation": 7 * 13.92}),
    # one symptom counted in two subscales: only blurred vision (oculomotor and disorientation)
    ([0] * 10 + [1] + [0] * 5, {"ssq": 2 * 3.74, "ssq.nausea": 0.0, "ssq.oculomotor": 7.58,
                                "ssq.disorientation": 13.92}),
])
def test_ssq_scores_hand_computed(values, expected):
    assert score(load_instrument("ssq"), ssq_answers(values)) == pytest.approx(expected)


def test_a_declined_item_leaves_the_scores_that_need_it_unscored():
    ssq = load_instrument("ssq")
    answers = ssq_answers([1] * 16)
    answers["vertigo"] = PREFER_NOT
    checked = check_answers(ssq, answers)
    assert checked["vertigo"] is None
    scores = score(ssq, checked)
    assert scores["ssq.disorientation"] is None and scores["ssq"] is None
    assert scores["ssq.nausea"] == pytest.approx(7 * 9.54)


def test_answers_out_of_scale_unknown_or_missing_are_refused_naming_the_item():
    sus = load_instrument("sus")
    answers = {f"Q{i}": 3 for i in range(1, 11)}
    assert check_answers(sus, answers) == {k: 3.0 for k in answers}
    bad = dict(answers, Q3=6, Q4=2.5, Q5="often", Q11=1)
    del bad["Q9"]
    with pytest.raises(AnswerError) as info:
        check_answers(sus, bad)
    problems = info.value.problems
    assert any(p.startswith("unknown item Q11") for p in problems)
    assert "Q3: 6 is outside its scale 1-5" in problems
    assert "Q4: 2.5 is not a whole number (1-5)" in problems
    assert any(p.startswith("Q5: 'often' is not an answer") for p in problems)
    with pytest.raises(AnswerError, match="Q1: True is not an answer"):
        check_answers(sus, dict(answers, Q1=True))
    assert f'Q9: no answer (give one, or "{PREFER_NOT}")' in problems
    tlx = load_instrument("tlx")  # a continuous 0-100 scale takes 42.5, not 101
    ratings = {i.id: 42.5 for i in tlx.all_items}
    assert check_answers(tlx, ratings)["effort"] == 42.5
    with pytest.raises(AnswerError, match="effort: 101 is outside its scale 0-100"):
        check_answers(tlx, dict(ratings, effort=101))


def test_the_format_carries_the_published_rules_of_sus_tlx_and_godspeed():
    sus = load_instrument("sus")
    # Brooke's worked example: contributions 4,1,1,4,1,2,1,1,4,3 = 22 -> 55
    assert score(sus, {f"Q{i}": v for i, v in enumerate((5, 4, 2, 1, 2, 3, 2, 4, 5, 2), 1)}) == {"sus": 55.0}
    tlx = load_instrument("tlx")
    assert score(tlx, dict(zip([i.id for i in tlx.all_items], (10, 20, 30, 40, 50, 60))))["tlx"] == 35.0


def test_a_lab_adds_its_own_instrument_as_a_file(tmp_path):
    own = tmp_path / "trust.yaml"
    own.write_text(yaml.safe_dump({
        "id": "trust", "title": "Trust in the robot (lab's own)", "source": "our lab, 2026",
        "scale": {"min": 1, "max": 7, "anchors": {1: "not at all", 7: "completely"}},
        "scoring": {"subscales": "mean", "total": {"name": "trust", "of": "items", "rule": "mean"}},
        "subscales": [
            {"id": "reliability", "name": "Reliability",
             "items": [{"id": "T1", "text": "The robot is reliable."},
                       {"id": "T2", "text": "The robot fails me.", "reverse": True}]},
            {"id": "intent", "name": "Intent", "items": [{"id": "T3", "text": "The robot means well."}]}],
    }))
    trust = load_instrument(own)
    assert trust.measures() == ["trust", "trust.reliability", "trust.intent"]
    # T2 reversed on 1-7: 8 - 2 = 6
    assert score(trust, check_answers(trust, {"T1": 7, "T2": 2, "T3": 4})) == pytest.approx(
        {"trust": (7 + 6 + 4) / 3, "trust.reliability": 6.5, "trust.intent": 4.0})
    with pytest.raises(AnswerError, match="T1: 8 is outside its scale 1-7"):
        check_answers(trust, {"T1": 8, "T2": 2, "T3": 4})


def test_bad_instrument_files_name_the_file_and_the_place(tmp_path):
    own = tmp_path / "bad.yaml"
    ssq = yaml.safe_load(data_file("ssq.yaml").read_text())
    ssq["subscales"][0]["includes"].append("yawning")
    own.write_text(yaml.safe_dump(ssq))
    with pytest.raises(DefinitionError, match=f"{own}: .*subscale nausea includes unknown items: yawning"):
        load_instrument(own)
    ssq = yaml.safe_load(data_file("ssq.yaml").read_text())
    ssq["scale"] = {"min": 3, "max": 0}
    own.write_text(yaml.safe_dump(ssq))
    with pytest.raises(DefinitionError, match=r"scale: scale max \(0\) must be above its min \(3\)"):
        load_instrument(own)
    with pytest.raises(DefinitionError, match="nasa: not a questionnaire .*qam, sus, tlx, godspeed, ssq"):
        load_instrument("nasa")
