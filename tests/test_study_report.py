"""`vr-teleop study report`: the statistics across participants checked against hand-computed cases and scipy /
statsmodels as independent references, missing data counted and participants excluded with the reason, the
long-format CSV, the JSON and the charts."""

from __future__ import annotations

import json
import math
import re
from datetime import UTC, datetime, timedelta

import numpy as np
import pandas as pd
import pytest
import yaml
from scipy import stats
from statsmodels.stats.power import TTestIndPower, TTestPower

from vr_teleop_server.cli import main
from vr_teleop_server.study.folder import StudyFolder
from vr_teleop_server.study.protocol import ProtocolFields, StudyPlan
from vr_teleop_server.study.report import analyse, collect

CONDITIONS = ("A", "B", "C")
FORM = "v1"


class Clock:
    def __init__(self):
        self.t = datetime(2026, 11, 29, 9, 0, tzinfo=UTC)

    def __call__(self):
        self.t += timedelta(seconds=1)
        return self.t


@pytest.fixture
def rating(tmp_path):
    """A lab's own one-item instrument: a 0-100 rating, so that each value is chosen exactly."""
    path = tmp_path / "rating.yaml"
    path.write_text(yaml.safe_dump({
        "id": "rating", "title": "A rating", "source": "this test",
        "scale": {"min": 0, "max": 100, "integer": False},
        "scoring": {"total": {"name": "rating", "rule": "mean"}},
        "items": [{"id": "R1", "text": "How good was it?"}]}))
    return str(path)


def build(tmp_path, rating, values: dict[str, dict[str, float | None]], design="within", order="latin",
          before=(), conditions=CONDITIONS):
    """A folder where participant i gave values[i][condition] after each condition (None: not submitted)."""
    protocol = ProtocolFields.model_validate({
        "design": design, "order": order, "consent_form": FORM,
        "questionnaires": {"after_each": [rating], "before_first": list(before)}})
    path = tmp_path / "study"
    with StudyFolder.open(path, StudyPlan("demo", conditions, 1, protocol), clock=Clock()) as folder:
        for wanted in values.values():
            p = folder.enrol("experimenter", consent=True, consent_form=FORM)
            for condition in p.order:
                folder.start_trial("experimenter", p.id)
                folder.end_trial("experimenter", "completed")
                value = wanted.get(condition)
                if value is not None:
                    folder.submit("participant", p.id, rating, condition, {"R1": value})
    return path


# P1..P4: C > B > A for everyone, with distinct absolute differences within each pair (exact Wilcoxon)
RANKED = {"P01": {"A": 40, "B": 50, "C": 70}, "P02": {"A": 45, "B": 60, "C": 67.5},
          "P03": {"A": 50, "B": 52.5, "C": 77.5}, "P04": {"A": 55, "B": 60, "C": 62.5}}


def report_of(path, parametric=False):
    folder = StudyFolder.read(path)
    return analyse(folder, collect(folder), parametric=parametric)


def test_friedman_wilcoxon_and_holm_hand_computed(tmp_path, rating):
    report = report_of(build(tmp_path, rating, RANKED))
    m = next(x for x in report.measures if x.measure == "rating")
    # every participant ranks A < B < C: rank sums 4, 8, 12; Q = 12 / (n k (k+1)) sum R^2 - 3 n (k+1)
    # = 12 / 48 x 224 - 48 = 8; W = Q / (n (k-1)) = 1; p = exp(-8 / 2) for chi2 with 2 df
    assert m.omnibus.test == "Friedman"
    assert (m.omnibus.statistic, m.omnibus.effect) == pytest.approx((8.0, 1.0))
    assert m.omnibus.p == pytest.approx(math.exp(-4))
    assert m.omnibus.text == "across conditions: chi2(2, N = 4) = 8.00, p = .018, W = 1.00"
    for pair in m.pairwise:
        # four positive differences: exact two-sided p = 2 / 2^4; r_rb = +1; Holm over three equal p: 3 x 0.125
        assert (pair.test, pair.n, pair.statistic) == ("Wilcoxon signed-rank", 4, 0.0)
        assert pair.p_unc == pytest.approx(0.125) and pair.p_holm == pytest.approx(0.375)
        assert pair.effect == pytest.approx(1.0)
    ab = m.pairwise[0]
    diff = np.array([10, 15, 2.5, 5])
    dz = diff.mean() / diff.std(ddof=1)
    assert ab.power_effect == pytest.approx(dz)
    assert ab.n_for_80_power == math.ceil(TTestPower().solve_power(effect_size=dz, power=0.8, alpha=0.05))
    assert m.conditions["A"].mean == pytest.approx(47.5) and m.conditions["C"].median == pytest.approx(68.75)
    assert m.missing == {"A": 0, "B": 0, "C": 0} and m.excluded == []
    duration = next(x for x in report.measures if x.measure == "trial.duration_s")
    assert duration.conditions["A"].mean == 1.0  # the test's clock: a second from start to end
    assert duration.omnibus.text == "across conditions: not run, every value is the same"
    assert [p.note for p in duration.pairwise] == ["not run: every difference is zero"] * 3


def test_two_conditions_take_the_pairwise_test_alone(tmp_path, rating):
    values = {p: {"A": v["A"], "B": v["B"]} for p, v in RANKED.items()}
    report = report_of(build(tmp_path, rating, values, conditions=("A", "B")))
    m = next(x for x in report.measures if x.measure == "rating")
    assert m.omnibus is None and len(m.pairwise) == 1
    pair = m.pairwise[0]
    reference = stats.wilcoxon([v["B"] for v in values.values()], [v["A"] for v in values.values()])
    assert (pair.statistic, pair.p_unc, pair.p_holm) == pytest.approx((reference.statistic, reference.pvalue,
                                                                       reference.pvalue))
    # by position: P01 and P03 met A first, P02 and P04 B first (Latin rows 01, 10)
    first = [40, 60, 50, 60]
    second = [50, 45, 52.5, 55]
    reference = stats.wilcoxon(second, first)
    assert m.order_effect.p == pytest.approx(reference.pvalue)


def test_parametric_against_scipy_and_a_hand_anova(tmp_path, rating):
    rng = np.random.default_rng(5)
    values = {f"P{i:02d}": {c: float(np.round(50 + 8 * j + rng.normal(0, 6), 1)) for j, c in enumerate(CONDITIONS)}
              for i in range(1, 9)}
    report = report_of(build(tmp_path, rating, values), parametric=True)
    m = next(x for x in report.measures if x.measure == "rating")
    table = np.array([[v[c] for c in CONDITIONS] for v in values.values()])
    n, k = table.shape
    grand = table.mean()
    ss_cond = n * ((table.mean(axis=0) - grand) ** 2).sum()
    ss_subj = k * ((table.mean(axis=1) - grand) ** 2).sum()
    ss_error = ((table - grand) ** 2).sum() - ss_cond - ss_subj
    f = (ss_cond / (k - 1)) / (ss_error / ((n - 1) * (k - 1)))
    assert m.omnibus.test == "repeated-measures ANOVA"
    assert m.omnibus.statistic == pytest.approx(f) and m.omnibus.df == [2, 14]
    assert m.omnibus.p == pytest.approx(stats.f.sf(f, 2, 14))
    assert m.omnibus.detail["p_GG_corr"] >= m.omnibus.p  # the correction never makes p smaller
    for pair, (i, j) in zip(m.pairwise, [(0, 1), (0, 2), (1, 2)]):
        reference = stats.ttest_rel(table[:, j], table[:, i])
        assert pair.test == "paired t"
        assert (pair.statistic, pair.p_unc) == pytest.approx((reference.statistic, reference.pvalue))
    ps = sorted(p.p_unc for p in m.pairwise)
    holm = np.maximum.accumulate([min(1, p * (3 - r)) for r, p in enumerate(ps)])
    assert sorted(p.p_holm for p in m.pairwise) == pytest.approx(holm)
    nonparametric = report_of(tmp_path / "study")
    q = next(x for x in nonparametric.measures if x.measure == "rating").omnibus
    reference = stats.friedmanchisquare(*table.T)
    assert (q.statistic, q.p) == pytest.approx((reference.statistic, reference.pvalue))


def test_missing_values_are_counted_and_participants_excluded_with_the_reason(tmp_path, rating):
    values = dict(RANKED, P05={"A": 30, "B": None, "C": 90})
    report = report_of(build(tmp_path, rating, values))
    m = next(x for x in report.measures if x.measure == "rating")
    assert m.missing == {"A": 0, "B": 1, "C": 0}
    assert m.conditions["B"].n == 4 and m.conditions["B"].missing == 1 and m.conditions["C"].n == 5
    assert [(e.participant, e.reason) for e in m.excluded] == [
        ("P05", "no value for B: left out of the paired tests")]
    assert m.n_complete == 4 and m.omnibus.n == 4
    assert report.balance.startswith("unbalanced: 5 participants")


def test_between_subject_against_scipy(tmp_path, rating):
    values = {f"P{i:02d}": {c: 4.0 * i + (0 if c == "A" else 30 if c == "B" else 60) for c in CONDITIONS}
              for i in range(1, 10)}
    path = build(tmp_path, rating, values, design="between", order="fixed")
    folder = StudyFolder.read(path)
    groups = {c: [float(values[p.id][c]) for p in folder.participants.values() if p.order == [c]]
              for c in CONDITIONS}
    report = report_of(path)
    m = next(x for x in report.measures if x.measure == "rating")
    reference = stats.kruskal(*groups.values())
    assert m.omnibus.test == "Kruskal-Wallis"
    assert (m.omnibus.statistic, m.omnibus.p) == pytest.approx((reference.statistic, reference.pvalue))
    ab = m.pairwise[0]
    u = stats.mannwhitneyu(groups["B"], groups["A"])
    assert (ab.test, ab.statistic, ab.p_unc) == ("Mann-Whitney U", pytest.approx(u.statistic),
                                                 pytest.approx(u.pvalue))
    assert u.statistic == 9 and ab.effect == pytest.approx(2 * u.statistic / 9 - 1)  # every B above every A: +1
    x, y = np.array(groups["A"]), np.array(groups["B"])
    d = (y.mean() - x.mean()) / math.sqrt(((len(x) - 1) * x.var(ddof=1) + (len(y) - 1) * y.var(ddof=1))
                                          / (len(x) + len(y) - 2))
    assert ab.power_effect == pytest.approx(d)
    assert ab.n_for_80_power == math.ceil(TTestIndPower().solve_power(effect_size=d, power=0.8, alpha=0.05))
    assert m.order_effect is None
    welch = report_of(path, parametric=True)
    assert next(x for x in welch.measures if x.measure == "rating").omnibus.test == "Welch's ANOVA"


def test_cli_report_writes_csv_json_and_one_chart_per_measure(tmp_path, rating, capsys):
    path = build(tmp_path, rating, RANKED, before=[{"name": "qam", "phase": "expected"}])
    out = tmp_path / "out"
    assert main(["study", "report", str(path), "--csv", str(out / "long.csv"), "--json", str(out / "r.json"),
                 "--plots", str(out / "plots")]) == 2  # out/ does not exist: refused with the reason
    assert "cannot write" in capsys.readouterr().err
    out.mkdir()
    assert main(["study", "report", str(path), "--csv", str(out / "long.csv"), "--json", str(out / "r.json"),
                 "--plots", str(out / "plots")]) == 0
    text = capsys.readouterr().out
    assert "== rating ==" in text and "chi2(2, N = 4) = 8.00, p = .018, W = 1.00" in text
    assert "Order effect, by position: chi2(2, N = 4)" in text
    assert "post hoc" in text and '"measures"' not in text  # the full JSON only in the file
    frame = pd.read_csv(out / "long.csv")
    assert list(frame.columns) == ["participant", "group", "condition", "position", "measure", "value", "source",
                                   "note"]
    rating_rows = frame[frame["measure"] == "rating"]
    assert len(rating_rows) == 12 and set(rating_rows["position"]) == {1, 2, 3}
    assert rating_rows.set_index(["participant", "condition"])["value"][("P03", "C")] == 77.5
    qam = frame[frame["measure"].str.startswith("qam.expected.")]
    assert len(qam) == 4 * 33 and qam["value"].isna().all()  # owed, not given: shown as missing
    document = json.loads((out / "r.json").read_text())
    qam_items = [f"qam.P{i}" for i in range(1, 7)]  # QAM's objective items, measured from each trial's recording
    assert [m["measure"] for m in document["measures"]] == ["trial.duration_s", *qam_items, "rating"]
    measured = frame[frame["measure"].isin(qam_items)]
    assert len(measured) == 4 * 3 * 6 and set(measured["source"]) == {"measured"} and measured["value"].isna().all()
    assert set(frame[frame["measure"] == "rating"]["source"]) == {"answered"}
    p4 = next(m for m in document["measures"] if m["measure"] == "qam.P4")  # these trials wrote no recording
    assert sum(p4["missing"].values()) == 12 and len(p4["missing_reasons"]) == 12
    assert all(re.fullmatch(rf"{g['participant']}/{g['condition']}\.mcap: no recording: {g['condition']}\.mcap "
                            "was not found", g["reason"]) for g in p4["missing_reasons"])
    assert "Missing P01 " in text and "(measured from the trial recordings, not answered)" in text
    charts = sorted(p.name for p in (out / "plots").iterdir())
    assert charts == sorted(["rating.png", "trial.duration_s.png", *(f"{q}.png" for q in qam_items)])
    assert (out / "plots" / "rating.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["study", "report", str(path), "--json", "-"]) == 0
    assert json.loads(capsys.readouterr().out)["study"] == "demo"
    assert main(["study", "report", str(tmp_path / "nowhere")]) == 2
    assert "not a study folder" in capsys.readouterr().err
