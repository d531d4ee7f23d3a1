"""The study file's fields for a study with people (design, order, consent form, demographics, questionnaires):
the shipped examples declare them and open as study folders; bad ones are refused naming the place."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from vr_teleop_server.study.design import williams_rows
from vr_teleop_server.study.folder import StudyFolder
from vr_teleop_server.study.protocol import plan_of
from vr_teleop_server.study.kinds import load_study
from vr_teleop_server.study.studyfile import StudyFileError

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = [ROOT / "examples" / "classroom.yaml", ROOT / "examples" / "toolbox.yaml"]


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_the_shipped_studies_declare_a_latin_within_design_and_their_questionnaires(path, tmp_path):
    plan = plan_of(load_study(path))
    protocol = plan.protocol
    assert (protocol.design, protocol.order) == ("within", "latin")
    q = protocol.questionnaires
    assert [(e.name, e.phase) for e in q.before_first] == [("qam", "expected")]
    assert [e.name for e in q.after_each] == ["sus", "tlx", "ssq"]
    assert q.after_each[2].who == "whoever wore the headset"
    assert [(e.name, e.phase) for e in q.after_last] == [("qam", "perceived")]
    assert protocol.consent_form and any(d.id == "age_group" for d in protocol.demographics)
    with StudyFolder.open(tmp_path / "study", plan) as folder:
        people = [folder.enrol("experimenter", consent=True, consent_form=protocol.consent_form) for _ in range(6)]
        rows = williams_rows(len(plan.conditions))
        assert [p.order for p in people] == [[plan.conditions[c] for c in rows[i]] for i in range(6)]
        assert folder.balance() is None


@pytest.mark.parametrize("change, message", [
    ({"design": "between"}, "order: latin is for design: within"),
    ({"order": "alphabetical"}, "order: Input should be 'latin', 'random' or 'fixed'"),
    ({"questionnaires": {"after_each": ["nasa"]}}, "questionnaires: Value error, after_each.0: nasa: not a "
                                                   "questionnaire"),
    ({"questionnaires": {"before_first": ["qam"]}}, "before_first.0: qam is given in phases (expected, perceived): "
                                                    "say which with phase:"),
    ({"questionnaires": {"after_each": [{"name": "sus", "phase": "expected"}]}}, "sus has no phases"),
    ({"demographics": [{"id": "birth date", "question": "?", "choices": ["a", "b"]}]},
     "demographics.0.id: String should match pattern"),
    ({"demographics": [{"id": "age", "question": "?", "choices": ["any"]}]},
     "demographics.0.choices: List should have at least 2 items"),
])
def test_bad_study_fields_are_refused_naming_the_place(tmp_path, change, message):
    document = yaml.safe_load(EXAMPLES[0].read_text())
    document.update(change)
    path = tmp_path / "study.yaml"
    path.write_text(yaml.safe_dump(document))
    with pytest.raises(StudyFileError) as info:
        load_study(path)
    assert str(info.value).startswith(f"{path}: ") and message.replace("Value error, ", "") in str(info.value)
