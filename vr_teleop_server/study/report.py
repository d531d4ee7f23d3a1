"""The report across participants of a study folder: the long-format table, and per measure and condition the
descriptive statistics and the tests a reviewer expects (pingouin; see docs/guides/studies.md).

- Measures: each questionnaire score and subscale given after a condition (`sus`, `ssq.nausea` ...), and the
  trial's duration from the event log (`trial.duration_s`, completed trials). Questionnaires given before the
  first or after the last condition (QAM's phases) go into the long table without a condition: they are not
  compared across conditions.
- Within-subject: Friedman's test and Kendall's W, then pairwise Wilcoxon signed-rank tests with Holm's
  correction and the matched-pairs rank-biserial r; parametric: the repeated-measures ANOVA with the
  Greenhouse-Geisser correction, then paired t-tests (Holm) with Cohen's d. Two conditions: the pairwise test
  alone. Order effects: the same omnibus test on the measure by position (first, second ...).
- Between-subject: Kruskal-Wallis, then Mann-Whitney U (Holm) with the rank-biserial r; parametric: Welch's
  ANOVA, then Welch's t-tests with Cohen's d.
- Power (post hoc): per comparison, the n that would reach 80 % power at the observed effect (paired: d_z, the
  mean difference over its SD; between: Cohen's d, n per group), by the t-test's power function.
- QAM's objective items (`qam.P1` ... `qam.P6`), when the study gives QAM: measured from each completed trial's
  recording (qam_measured.py), one value per participant and condition with source `measured`; an item the
  recording cannot give is a missing value with its reason (`note`), never a guess.
- Missing data is never dropped silently: each measure counts its missing values per condition, and a
  participant missing a condition is excluded from the paired tests with the reason.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import combinations

import numpy as np
import pandas as pd
import pingouin as pg
from pydantic import BaseModel

from ..questionnaires.instrument import load_instrument
from ..questionnaires.stats import Describe, describe
from .folder import Participant, StudyFolder, Trial
from .kinds import measure_qam
from .qam_measured import ITEMS as QAM_ITEMS
from .qam_measured import UNITS as QAM_UNITS

POWER = 0.8
ALPHA = 0.05
CSV_COLUMNS = ("participant", "group", "condition", "position", "measure", "value", "source", "note")
ANSWERED, LOGGED, MEASURED = "answered", "event log", "measured"  # a row's source: a questionnaire, the folder's
# event log, or the trial's recording


@dataclass(frozen=True)
class Row:
    """One value of the long-format table; `value` None is a missing value, kept and counted."""

    participant: str
    group: str
    condition: str  # "" for what is not tied to a condition (QAM's phases)
    position: int | None  # the condition's place in the order the participant met them, 1-based
    measure: str
    value: float | None
    source: str = ANSWERED
    note: str = ""  # why a value is missing, where the source knows (a measured one); or what was measured


def _positions(participant) -> dict[str, int]:
    """Where each condition came for this participant: the order run (deviations included), then the plan's."""
    done = list(dict.fromkeys(participant.done()))
    rest = [c for c in participant.order if c not in done]
    return {c: i + 1 for i, c in enumerate(done + rest)}


def collect(folder: StudyFolder) -> list[Row]:
    """The long-format table of a study folder: every value a participant owes, present or missing."""
    plan = folder.plan.protocol.questionnaires
    instruments = {e.name: load_instrument(e.name) for e in (*plan.before_first, *plan.after_each, *plan.after_last)}
    uses_qam = "qam" in instruments
    rows: list[Row] = []
    for p in folder.participants.values():
        positions = _positions(p)
        for condition in p.order:
            position = positions[condition]
            trials = [t for t in p.trials if t.condition == condition and t.outcome == "completed"]
            duration = None
            if trials and trials[-1].ended is not None:
                duration = (pd.Timestamp(trials[-1].ended) - pd.Timestamp(trials[-1].started)).total_seconds()
            rows.append(Row(p.id, p.group, condition, position, "trial.duration_s", duration, LOGGED))
            if uses_qam:
                rows.extend(_qam_measured(folder, p, condition, position, trials[-1] if trials else None))
            for entry in plan.after_each:
                given = next((a for a in p.answers if a.questionnaire == entry.name and a.condition == condition),
                             None)
                for measure in instruments[entry.name].measures():
                    rows.append(Row(p.id, p.group, condition, position, measure,
                                    None if given is None else given.scores.get(measure)))
        for when, entries in (("before_first", plan.before_first), ("after_last", plan.after_last)):
            for entry in entries:
                instrument = instruments[entry.name]
                prefix = f"{entry.name}.{entry.phase or when}"
                given = next((a for a in p.answers if a.questionnaire == entry.name and a.condition is None
                              and a.phase == entry.phase), None)
                if instrument.measures():
                    values = {m: None if given is None else given.scores.get(m) for m in instrument.measures()}
                    names = {m: f"{prefix}{m.removeprefix(entry.name)}" for m in values}
                else:  # reported item by item (QAM)
                    values = {i.id: None if given is None else given.answers.get(i.id)
                              for i in instrument.all_items}
                    names = {k: f"{prefix}.{k}" for k in values}
                rows.extend(Row(p.id, p.group, "", None, names[k], v) for k, v in values.items())
    return rows


def _qam_measured(folder: StudyFolder, p: Participant, condition: str, position: int, trial: Trial | None) \
        -> list[Row]:
    """QAM's objective items of the participant's completed trial of `condition`, from its recording."""
    if trial is None:
        measured = [(item, None, f"no completed trial of {condition}") for item in QAM_ITEMS]
    else:
        measured = [(m.item, m.value, f"{trial.recording}: {m.how}")
                    for m in measure_qam(folder.path / trial.recording)]
    return [Row(p.id, p.group, condition, position, f"qam.{item}", value, MEASURED, note)
            for item, value, note in measured]


def write_csv(rows: Sequence[Row], out) -> None:
    frame = pd.DataFrame([r.__dict__ for r in rows], columns=list(CSV_COLUMNS))
    frame["position"] = frame["position"].astype("Int64")
    frame.to_csv(out, index=False)


# ---- results --------------------------------------------------------------------------------------------------

class Test(BaseModel):
    """One omnibus test, or why it was not run."""

    test: str
    n: int
    statistic: float | None = None
    df: list[float] = []
    p: float | None = None
    effect_name: str | None = None
    effect: float | None = None
    detail: dict[str, float | bool | None] = {}
    text: str  # APA-style, or the reason it was not run


class Pair(BaseModel):
    a: str
    b: str
    test: str
    n: int
    statistic: float | None = None
    p_unc: float | None = None
    p_holm: float | None = None
    effect_name: str | None = None
    effect: float | None = None
    power_effect: float | None = None  # d_z (paired) or Cohen's d (between) used for the power analysis
    n_for_80_power: int | None = None  # per group for a between design; post hoc
    note: str = ""


class Excluded(BaseModel):
    participant: str
    reason: str


class Missing(BaseModel):
    participant: str
    condition: str
    reason: str


class MeasureReport(BaseModel):
    measure: str
    source: str = ANSWERED  # answered (a questionnaire), event log, or measured (the trial's recording)
    missing_reasons: list[Missing] = []  # why a value is missing, where its source says
    conditions: dict[str, Describe]
    missing: dict[str, int]
    n_complete: int
    excluded: list[Excluded]
    omnibus: Test | None
    pairwise: list[Pair]
    order_effect: Test | None = None
    by_position: dict[str, dict[str, float | None]] = {}  # condition -> position -> mean


class MeasuredValue(BaseModel):
    """One value measured from a trial's recording, or None with the reason it is missing."""

    participant: str
    condition: str
    measure: str
    value: float | None
    unit: str
    note: str  # the recording and what was measured, or why the value is missing


class StudyReport(BaseModel):
    study: str
    design: str
    parametric: bool
    conditions: list[str]
    participants: int
    withdrawn: list[str]
    balance: str | None
    deviations: list[dict[str, str | int]]
    unfinished: list[str]  # trials still running or interrupted and not run again
    power_note: str = ("n_for_80_power is post hoc: the participants the observed effect would need for 80 % "
                       "power at alpha .05 (t-test based), not a claim that the effect is real")
    measures: list[MeasureReport]
    without_condition: dict[str, int]  # measure -> values in the long table not compared across conditions
    measured: list[MeasuredValue] = []  # each trial's values read from its recording (QAM's objective items)


def p_text(p: float | None) -> str:
    """APA style: p = .018, p < .001."""
    if p is None or (isinstance(p, float) and math.isnan(p)):
        return "p = -"
    return "p < .001" if p < 0.001 else f"p = {p:.3f}".replace("0.", ".", 1)


def _finite(value) -> float | None:
    try:
        value = float(value)
    except (TypeError, ValueError):
        return None
    return value if math.isfinite(value) else None


def _n_for_power(effect: float | None, contrast: str) -> int | None:
    if effect is None or effect == 0:
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            n = pg.power_ttest(d=abs(effect), power=POWER, alpha=ALPHA, contrast=contrast)
        except (ValueError, RuntimeError):
            return None
    n = _finite(n)
    return None if n is None else math.ceil(n)


def _holm(pairs: list[Pair]) -> None:
    tested = [p for p in pairs if p.p_unc is not None]
    if tested:
        _, corrected = pg.multicomp([p.p_unc for p in tested], alpha=ALPHA, method="holm")
        for pair, p in zip(tested, corrected):
            pair.p_holm = float(p)


def _paired(a: str, b: str, x: np.ndarray, y: np.ndarray, parametric: bool) -> Pair:
    diff = y - x
    n = len(diff)
    sd = float(np.std(diff, ddof=1)) if n >= 2 else 0.0
    dz = float(np.mean(diff)) / sd if sd > 0 else None
    base = dict(a=a, b=b, n=n, power_effect=dz, n_for_80_power=_n_for_power(dz, "paired"))
    if n < 2:
        return Pair(test="-", **base, note=f"not run: {n} participant(s) with both")
    if not np.any(diff):
        return Pair(test="-", **base, note="not run: every difference is zero")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if parametric:
            if sd == 0:
                return Pair(test="-", **base, note="not run: the differences do not vary")
            result = pg.ttest(y, x, paired=True).iloc[0]
            return Pair(test="paired t", statistic=_finite(result["T"]), p_unc=_finite(result["p_val"]),
                        effect_name="Cohen's d", effect=_finite(result["cohen_d"]), **base)
        result = pg.wilcoxon(y, x).iloc[0]
        return Pair(test="Wilcoxon signed-rank", statistic=_finite(result["W_val"]), p_unc=_finite(result["p_val"]),
                    effect_name="rank-biserial r", effect=_finite(result["RBC"]), **base)


def _within_omnibus(wide: pd.DataFrame, parametric: bool, what: str) -> Test | None:
    """Friedman (or rm-ANOVA) on a complete participants x levels table; None for fewer than 3 levels."""
    n, k = wide.shape
    if k < 3:
        return None
    if n < 2:
        return Test(test="-", n=n, text=f"{what}: not run, {n} complete participant(s)")
    if np.allclose(wide.to_numpy(float), wide.to_numpy(float)[0, 0]):
        return Test(test="-", n=n, text=f"{what}: not run, every value is the same")
    long = wide.reset_index().melt(id_vars="participant", var_name="level", value_name="value")
    long["level"] = long["level"].astype(str)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if parametric:
            r = pg.rm_anova(long, dv="value", within="level", subject="participant", correction=True).iloc[0]
            if _finite(r.get("F")) is None:
                return Test(test="-", n=n, text=f"{what}: not run, no variance left within participants")
            p_gg = _finite(r.get("p_GG_corr", r["p_unc"]))
            df = [float(r["ddof1"]), float(r["ddof2"])]
            text = (f"F({df[0]:g}, {df[1]:g}) = {r['F']:.2f}, {p_text(_finite(r['p_unc']))}, "
                    f"Greenhouse-Geisser {p_text(p_gg)} (epsilon = {r['eps']:.2f}), eta_G^2 = {r['ng2']:.2f}")
            return Test(test="repeated-measures ANOVA", n=n, statistic=_finite(r["F"]), df=df,
                        p=_finite(r["p_unc"]), effect_name="generalised eta squared", effect=_finite(r["ng2"]),
                        detail={"p_GG_corr": p_gg, "epsilon": _finite(r["eps"]),
                                "sphericity": bool(r["sphericity"]) if "sphericity" in r else None,
                                "p_mauchly": _finite(r.get("p_spher"))},
                        text=f"{what}: {text}")
        r = pg.friedman(long, dv="value", within="level", subject="participant").iloc[0]
        q, w, p = _finite(r["Q"]), _finite(r["W"]), _finite(r["p_unc"])
        text = f"chi2({int(r['ddof1'])}, N = {n}) = {r['Q']:.2f}, {p_text(p)}, W = {r['W']:.2f}"
        return Test(test="Friedman", n=n, statistic=q, df=[float(r["ddof1"])], p=p, effect_name="Kendall's W",
                    effect=w, text=f"{what}: {text}")


def _within(measure: str, frame: pd.DataFrame, conditions: Sequence[str], parametric: bool) -> MeasureReport:
    wide = frame.set_index(["participant", "condition"])["value"].unstack().reindex(columns=list(conditions))
    present = frame.dropna(subset=["value"])
    excluded = []
    for participant, row in wide.iterrows():
        lacking = [c for c in conditions if pd.isna(row[c])]
        if lacking:
            excluded.append(Excluded(participant=str(participant),
                                     reason=f"no value for {', '.join(lacking)}: left out of the paired tests"))
    complete = wide.dropna()
    complete.index.name = "participant"
    pairs = [_paired(a, b, complete[a].to_numpy(float), complete[b].to_numpy(float), parametric)
             for a, b in combinations(conditions, 2)]
    _holm(pairs)
    positions = frame.set_index(["participant", "position"])["value"].unstack().dropna()
    positions.index.name = "participant"
    order = _within_omnibus(positions, parametric, "by position") if positions.shape[1] >= 3 else None
    if order is None and positions.shape[1] == 2 and len(positions) >= 2:
        first, second = positions.columns[:2]
        pair = _paired("1", "2", positions[first].to_numpy(float), positions[second].to_numpy(float), parametric)
        order = Test(test=pair.test, n=pair.n, statistic=pair.statistic, p=pair.p_unc, effect_name=pair.effect_name,
                     effect=pair.effect, text=f"by position: {pair.test} {p_text(pair.p_unc)}" + (
                         f" ({pair.note})" if pair.note else ""))
    by_position = {c: {str(int(pos)): _finite(g["value"].mean())
                       for pos, g in present[present["condition"] == c].groupby("position")}
                   for c in conditions}
    return MeasureReport(
        measure=measure, conditions={c: describe(_values(frame, c)) for c in conditions},
        missing={c: int(frame[(frame["condition"] == c)]["value"].isna().sum()) for c in conditions},
        n_complete=len(complete), excluded=excluded, omnibus=_within_omnibus(complete, parametric, "across conditions"),
        pairwise=pairs, order_effect=order, by_position=by_position)


def _values(frame: pd.DataFrame, condition: str) -> list[float | None]:
    return [None if pd.isna(v) else float(v) for v in frame[frame["condition"] == condition]["value"]]


def _between(measure: str, frame: pd.DataFrame, conditions: Sequence[str], parametric: bool) -> MeasureReport:
    present = frame.dropna(subset=["value"])
    groups = {c: present[present["condition"] == c]["value"].to_numpy(float) for c in conditions}
    excluded = [Excluded(participant=r.participant, reason=f"no value for {r.condition}: left out of the tests")
                for r in frame[frame["value"].isna()].itertuples()]
    omnibus = None
    if len(conditions) >= 3:
        sizes = [len(g) for g in groups.values()]
        if min(sizes) < 2:
            omnibus = Test(test="-", n=len(present), text="across conditions: not run, a group has fewer than 2")
        elif parametric and any(np.var(g) == 0 for g in groups.values()):
            omnibus = Test(test="-", n=len(present),
                           text="across conditions: not run, a group's values do not vary (Welch's weights)")
        elif np.ptp(present["value"].to_numpy(float)) == 0:
            omnibus = Test(test="-", n=len(present), text="across conditions: not run, every value is the same")
        else:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                if parametric:
                    r = pg.welch_anova(present, dv="value", between="condition").iloc[0]
                    df = [float(r["ddof1"]), float(r["ddof2"])]
                    omnibus = Test(test="Welch's ANOVA", n=len(present), statistic=_finite(r["F"]), df=df,
                                   p=_finite(r["p_unc"]), effect_name="partial eta squared", effect=_finite(r["np2"]),
                                   text=f"across conditions: Welch F({df[0]:g}, {df[1]:.2f}) = {r['F']:.2f}, "
                                        f"{p_text(_finite(r['p_unc']))}, eta_p^2 = {r['np2']:.2f}")
                else:
                    r = pg.kruskal(present, dv="value", between="condition").iloc[0]
                    omnibus = Test(test="Kruskal-Wallis", n=len(present), statistic=_finite(r["H"]),
                                   df=[float(r["ddof1"])], p=_finite(r["p_unc"]),
                                   text=f"across conditions: H({int(r['ddof1'])}, N = {len(present)}) = "
                                        f"{r['H']:.2f}, {p_text(_finite(r['p_unc']))}")
    pairs = []
    for a, b in combinations(conditions, 2):
        x, y = groups[a], groups[b]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # no variance: d is undefined (None)
            d = _finite(pg.compute_effsize(y, x, eftype="cohen")) if len(x) >= 2 and len(y) >= 2 else None
        base = dict(a=a, b=b, n=len(x) + len(y), power_effect=d, n_for_80_power=_n_for_power(d, "two-samples"))
        if len(x) < 2 or len(y) < 2:
            pairs.append(Pair(test="-", **base, note="not run: a group has fewer than 2"))
            continue
        if np.ptp(np.concatenate([x, y])) == 0:
            pairs.append(Pair(test="-", **base, note="not run: every value is the same"))
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if parametric:
                r = pg.ttest(y, x, correction=True).iloc[0]
                pairs.append(Pair(test="Welch t", statistic=_finite(r["T"]), p_unc=_finite(r["p_val"]),
                                  effect_name="Cohen's d", effect=_finite(r["cohen_d"]), **base))
            else:
                r = pg.mwu(y, x).iloc[0]
                pairs.append(Pair(test="Mann-Whitney U", statistic=_finite(r["U_val"]), p_unc=_finite(r["p_val"]),
                                  effect_name="rank-biserial r", effect=_finite(r["RBC"]), **base))
    _holm(pairs)
    return MeasureReport(
        measure=measure, conditions={c: describe(_values(frame, c)) for c in conditions},
        missing={c: int(frame[frame["condition"] == c]["value"].isna().sum()) for c in conditions},
        n_complete=len(present), excluded=excluded, omnibus=omnibus, pairwise=pairs)


def analyse(folder: StudyFolder, rows: Sequence[Row], parametric: bool = False) -> StudyReport:
    """Per measure compared across conditions: descriptives, omnibus and pairwise tests (Holm), effect sizes, order
    effects, post hoc power, missing values and exclusions; with the folder's deviations, unfinished trials,
    withdrawals and balance."""
    design = folder.plan.protocol.design
    conditions = list(folder.plan.conditions)
    frame = pd.DataFrame([r.__dict__ for r in rows], columns=list(CSV_COLUMNS))
    frame["value"] = frame["value"].astype(float)
    compared = frame[frame["condition"] != ""]
    measures = []
    for measure in dict.fromkeys(compared["measure"]):
        subset = compared[compared["measure"] == measure]
        used = [c for c in conditions if (subset["condition"] == c).any()]
        build = _within if design == "within" else _between
        result = build(measure, subset, used, parametric)
        result.source = str(subset["source"].iloc[0])
        if result.source == MEASURED:
            result.missing_reasons = [Missing(participant=r.participant, condition=r.condition, reason=r.note)
                                      for r in subset[subset["value"].isna()].itertuples()]
        measures.append(result)
    deviations = [{"participant": p.id, "trial": t.number, "condition": t.condition, "reason": t.deviation}
                  for p in folder.participants.values() for t in p.trials if t.deviation]
    unfinished = [f"{p.id} {t.condition}: {t.outcome or 'running'}" for p in folder.participants.values()
                  for t in p.trials if t.outcome in (None, "interrupted")]
    others = frame[frame["condition"] == ""]
    return StudyReport(
        study=folder.plan.study, design=design, parametric=parametric, conditions=conditions,
        participants=len(folder.participants), withdrawn=sorted(folder.withdrawn), balance=folder.balance(),
        deviations=deviations, unfinished=unfinished, measures=measures,
        without_condition={m: int(others[others["measure"] == m]["value"].notna().sum())
                           for m in dict.fromkeys(others["measure"])},
        measured=[MeasuredValue(participant=r.participant, condition=r.condition, measure=r.measure, value=r.value,
                                unit=QAM_UNITS[r.measure.removeprefix("qam.")], note=r.note)
                  for r in rows if r.source == MEASURED])
