"""`vr-teleop study report DIR [--csv OUT] [--json OUT] [--plots DIR] [--parametric]`: the table across the
participants of a study folder, with the tests, effect sizes and post hoc power; a short summary on the
terminal, everything in the JSON."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from ..questionnaires import tables
from ..study.folder import FolderError, StudyFolder

if TYPE_CHECKING:
    from ..study.report import StudyReport


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("report", help="the statistics across participants of a study folder",
                       description="Per measure and condition: n, mean, SD, median, IQR and 95%% CI; the omnibus "
                                   "and pairwise tests with effect sizes (non-parametric unless --parametric), "
                                   "order effects, the n for 80%% power (post hoc), missing data and exclusions.")
    p.add_argument("dir", type=Path, metavar="DIR", help="the study folder")
    p.add_argument("--csv", type=Path, metavar="OUT",
                   help="write the long-format table (participant, group, condition, position, measure, value)")
    p.add_argument("--json", type=Path, metavar="OUT", help="write the full report as JSON ('-' for stdout only)")
    p.add_argument("--plots", type=Path, metavar="DIR", help="write one chart per measure (PNG) into DIR")
    p.add_argument("--parametric", action="store_true",
                   help="repeated-measures ANOVA (Greenhouse-Geisser) and paired t-tests (Cohen's d); between: "
                        "Welch's ANOVA and Welch's t-tests")
    p.set_defaults(func=run)


def _num(value: float | None, digits: int = 2) -> str:
    return tables.num(value, digits=digits)


def summary(report: StudyReport) -> str:
    from ..study.report import p_text

    out = [f"Study {report.study}: {report.design}-subject, {report.participants} participant(s), "
           f"conditions {', '.join(report.conditions)}; "
           + ("parametric tests" if report.parametric else "non-parametric tests (--parametric for ANOVA/t)")]
    if report.withdrawn:
        out.append(f"Withdrawn: {', '.join(report.withdrawn)} (their data is deleted).")
    if report.balance:
        out.append(f"Order: {report.balance}.")
    for d in report.deviations:
        out.append(f"Deviation: {d['participant']} ran {d['condition']} out of order (trial {d['trial']}): "
                   f"{d['reason']}")
    for u in report.unfinished:
        out.append(f"Not finished: {u}")
    for m in report.measures:
        out.append("")
        out.append(f"== {m.measure} ==" + (" (measured from the trial recordings, not answered)"
                                            if m.source == "measured" else ""))
        rows = []
        for c, d in m.conditions.items():
            ci = "-" if d.ci95_low is None else f"[{_num(d.ci95_low)}, {_num(d.ci95_high)}]"
            rows.append([c, str(d.n), str(m.missing[c]), _num(d.mean), _num(d.sd), ci, _num(d.median),
                         _num(d.iqr)])
        out.append(tables.table(["condition", "n", "missing", "mean", "SD", "95% CI", "median", "IQR"], rows))
        if m.omnibus is not None:
            out.append("  " + m.omnibus.text)
        for pair in m.pairwise:
            if pair.p_unc is None:
                out.append(f"  {pair.a} vs {pair.b}: {pair.note}")
                continue
            power = f", n for 80% power {pair.n_for_80_power}" if pair.n_for_80_power else ""
            out.append(f"  {pair.a} vs {pair.b}: {pair.test} (n = {pair.n}) {_num(pair.statistic)}, "
                       f"{p_text(pair.p_unc)}, Holm {p_text(pair.p_holm)}, "
                       f"{pair.effect_name} = {_num(pair.effect)}{power}")
        if m.order_effect is not None:
            out.append("  Order effect, " + m.order_effect.text)
        for e in m.excluded:
            out.append(f"  Excluded {e.participant}: {e.reason}")
        for gap in m.missing_reasons:
            out.append(f"  Missing {gap.participant} {gap.condition}: {gap.reason}")
    if report.without_condition:
        count = sum(report.without_condition.values())
        out.append("")
        out.append(f"{count} value(s) given before the first or after the last condition (e.g. QAM's phases) are in "
                   "the CSV and the JSON, not compared across conditions.")
    out.append("")
    out.append("Power: " + report.power_note + ".")
    return "\n".join(out)


def run(args: argparse.Namespace) -> int:
    # pandas and pingouin take a second to import: only for this command, not for every `vr-teleop` start
    from ..study.report import analyse, collect, write_csv
    from ..study.report_plots import plot_measures

    try:
        folder = StudyFolder.read(args.dir)
    except FolderError as exc:
        print(f"vr-teleop study report: error: {exc}", file=sys.stderr)
        return 2
    rows = collect(folder)
    report = analyse(folder, rows, parametric=args.parametric)
    to_stdout = args.json is not None and str(args.json) == "-"
    notes = sys.stderr if to_stdout else sys.stdout
    text = report.model_dump_json(indent=2)
    if to_stdout:
        print(text)
    else:
        print(summary(report), file=notes)
    try:
        if args.json is not None and not to_stdout:
            args.json.write_text(text + "\n", encoding="utf-8")
            print(f"wrote {args.json}", file=notes)
        if args.csv is not None:
            write_csv(rows, args.csv)
            print(f"wrote {args.csv} ({len(rows)} rows)", file=notes)
        if args.plots is not None:
            written = plot_measures(report, rows, args.plots)
            print(f"wrote {len(written)} chart(s) into {args.plots}", file=notes)
    except OSError as exc:
        print(f"vr-teleop study report: error: {exc.filename or 'output'}: cannot write ({exc.strerror})",
              file=sys.stderr)
        return 2
    return 0
