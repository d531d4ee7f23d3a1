"""`vr-teleop qam|sus|tlx|godspeed template|score`: answer sheets in, tables, JSON and charts out.

Exit codes: 0 on success; 2 when a sheet, item file or output path is unusable (every problem is listed on
stderr, as `FILE, row R, column C: what is wrong (how to fix it)`).
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from ..questionnaires import godspeed, plots, qam, sus, tables, tlx
from ..questionnaires.definitions import DefinitionError, data_file
from ..questionnaires.sheets import SheetError, ValueColumn, read_sheet, write_template
from ..questionnaires.stats import DEFAULT_MIN_NONZERO

EXAMPLE_NAME = "qam_paper_table1.csv"
EXIT_USAGE = 2


@dataclass(frozen=True)
class Tool:
    """How one questionnaire plugs into the shared template/score commands."""

    name: str
    title: str
    load: Callable[[argparse.Namespace], Any]  # args -> definition
    score: Callable[[Any, Any, argparse.Namespace], BaseModel]  # (sheet, definition, args) -> report
    render: Callable[[BaseModel, Any, argparse.Namespace], str]
    plot: Callable[[BaseModel, Any, Path], Path]
    legend: Callable[[Any], str]


def _qam_legend(definition: qam.QAMDefinition) -> str:
    groups = {g.id: g.name for g in definition.groups}
    rows = [[p.column, groups[p.group], p.name,
             f"{definition.likert.min}-{definition.likert.max}" if p.scale is None else
             f"{ValueColumn(p.column, p.scale.min, p.scale.max).range_text()} {p.scale.unit}"]
            for p in definition.parameters]
    return tables.table(["column", "group", "parameter", "answer"], rows, left=(0, 1, 2, 3))


def _sus_legend(definition: sus.SUSDefinition) -> str:
    rows = [[i.id, "+" if i.positive else "-", i.text] for i in definition.items]
    return (f"Answers {definition.scale.min} ({definition.scale.low}) to {definition.scale.max} "
            f"({definition.scale.high}); keying: + answer-1, - 5-answer.\n"
            + tables.table(["column", "key", "statement"], rows, left=(0, 1, 2)))


def _tlx_legend(definition: tlx.TLXDefinition) -> str:
    rows = [[s.id, definition.weight_column(s.id), s.label, f"{s.low} (0) - {s.high} (100)"]
            for s in definition.subscales]
    return ("Ratings 0-100. Weights (optional): how often each subscale was chosen in the 15 pairwise "
            "comparisons, 0-5 each, all six summing to 15; leave all six empty for raw TLX only.\n"
            + tables.table(["rating", "weight", "subscale", "anchors"], rows, left=(0, 1, 2, 3)))


def _godspeed_legend(definition: godspeed.GodspeedDefinition) -> str:
    rows = [[i.id, s.name, f"{i.left} (1) - {i.right} (5)", "yes" if i.reverse else ""]
            for s in definition.series for i in s.items]
    return tables.table(["column", "series", "anchors", "reversed"], rows, left=(0, 1, 2, 3))


TOOLS = (
    Tool("qam", "QAM (Quick Assessment Method)",
         load=lambda args: qam.load_qam_definition(),
         score=lambda sheet, d, args: qam.score_qam(sheet, d, by=args.by, min_nonzero=args.min_pairs),
         render=lambda report, d, args: qam.format_qam_report(report, d),
         plot=lambda report, d, out: plots.plot_qam(report, d, out),
         legend=_qam_legend),
    Tool("sus", "SUS (System Usability Scale)",
         load=lambda args: sus.load_sus_definition(),
         score=lambda sheet, d, args: sus.score_sus(sheet, d, by=args.by),
         render=lambda report, d, args: sus.format_sus_report(report, args.per_respondent),
         plot=lambda report, d, out: plots.plot_sus(report, out),
         legend=_sus_legend),
    Tool("tlx", "NASA-TLX (raw and weighted)",
         load=lambda args: tlx.load_tlx_definition(),
         score=lambda sheet, d, args: tlx.score_tlx(sheet, d, by=args.by),
         render=lambda report, d, args: tlx.format_tlx_report(report, args.per_respondent),
         plot=lambda report, d, out: plots.plot_tlx(report, out),
         legend=_tlx_legend),
    Tool("godspeed", "Godspeed questionnaire series",
         load=lambda args: godspeed.load_godspeed_definition(args.items),
         score=lambda sheet, d, args: godspeed.score_godspeed(sheet, d, by=args.by),
         render=lambda report, d, args: godspeed.format_godspeed_report(report, args.per_respondent),
         plot=lambda report, d, out: plots.plot_godspeed(report, out),
         legend=_godspeed_legend),
)


def _fail(message: str) -> int:
    print(message, file=sys.stderr)
    return EXIT_USAGE


def _template(tool: Tool, args: argparse.Namespace) -> int:
    out = Path(args.out)
    if out.exists() and not args.force:
        return _fail(f"{out}: already exists; choose another name, or pass --force to overwrite it "
                     "(an answer sheet in use would be lost)")
    try:
        definition = tool.load(args)
        count = write_template(out, definition.sheet_spec(), args.respondents)
    except ValueError as exc:  # DefinitionError, or an unknown sheet format
        return _fail(str(exc))
    except OSError as exc:
        return _fail(f"{out}: cannot write ({exc.strerror})")
    print(f"Wrote {out}: {count} empty row{'s' if count != 1 else ''} for {tool.title}. "
          'Leave a cell empty or write "-" for a missing answer.')
    print(tool.legend(definition))
    return 0


def _score(tool: Tool, args: argparse.Namespace) -> int:
    try:
        definition = tool.load(args)
    except DefinitionError as exc:
        return _fail(str(exc))
    with contextlib.ExitStack() as stack:
        if getattr(args, "example", False):
            if args.file is not None:
                return _fail("give either a sheet or --example, not both")
            path = stack.enter_context(resources.as_file(data_file("examples", EXAMPLE_NAME)))
            shown = f"{EXAMPLE_NAME} (packaged example: the paper's Table 1)"
        elif args.file is None:
            return _fail(f"no sheet given: vr-teleop {tool.name} score FILE.csv"
                         + (" (or --example for the paper's Table 1)" if tool.name == "qam" else ""))
        else:
            path, shown = Path(args.file), args.file
        try:
            sheet = read_sheet(path, definition.sheet_spec(), display_name=shown)
        except SheetError as exc:
            for issue in exc.issues:
                print(issue, file=sys.stderr)
            count = len(exc.issues)
            print(f"{count} problem{'s' if count != 1 else ''} in {shown}; nothing was scored.", file=sys.stderr)
            return EXIT_USAGE
    report = tool.score(sheet, definition, args)
    text = report.model_dump_json(indent=2)
    if args.json == "-":
        print(text)
    else:
        print(tool.render(report, definition, args))
    written = []
    try:
        if args.json and args.json != "-":
            Path(args.json).write_text(text + "\n", encoding="utf-8")
            written.append(f"Wrote JSON: {args.json}")
        if args.plot:
            tool.plot(report, definition, Path(args.plot))
            written.append(f"Wrote chart: {args.plot}")
    except OSError as exc:
        return _fail(f"{exc.filename or 'output'}: cannot write ({exc.strerror})")
    except ValueError as exc:  # e.g. an image format matplotlib does not know
        return _fail(f"{args.plot}: {exc}")
    if written:
        print("\n" + "\n".join(written), file=sys.stderr if args.json == "-" else sys.stdout)
    return 0


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError("must be at least 1")
    return value


def _non_negative_int(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError("must be 0 or more")
    return value


def register(subparsers: argparse._SubParsersAction) -> None:
    for tool in TOOLS:
        parser = subparsers.add_parser(tool.name, help=f"{tool.title}: answer-sheet template and scoring",
                                       description=f"{tool.title}: write an empty answer sheet, or score one.")
        actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)

        template = actions.add_parser("template", help="write an empty answer sheet (.csv or .json)")
        template.add_argument("--out", required=True, metavar="FILE",
                              help="sheet to write; .csv or .json decides the format")
        template.add_argument("--respondents", type=_non_negative_int, default=1, metavar="N",
                              help="pre-fill N blank respondent rows with ids R01.. (default 1; 0 = header only)")
        template.add_argument("--force", action="store_true", help="overwrite FILE if it exists")
        template.set_defaults(func=lambda args, tool=tool: _template(tool, args))

        score = actions.add_parser("score", help="validate and score a sheet; print tables, write JSON/chart")
        score.add_argument("file", nargs="?" if tool.name == "qam" else None, metavar="FILE",
                           help="answer sheet, .csv or .json")
        if tool.name == "qam":
            score.add_argument("--example", action="store_true",
                               help="score the packaged example (the paper's Table 1) instead of FILE")
            score.add_argument("--min-pairs", type=_positive_int, default=DEFAULT_MIN_NONZERO, metavar="N",
                               help="run the Wilcoxon test only with at least N non-zero paired differences "
                                    f"(default {DEFAULT_MIN_NONZERO})")
        else:
            score.add_argument("--per-respondent", action="store_true", help="also list every respondent's score")
        score.add_argument("--json", metavar="OUT", help='write the full results as JSON ("-" for stdout only)')
        score.add_argument("--plot", metavar="OUT.png", help="write the chart (PNG; .svg and .pdf also work)")
        score.add_argument("--by", choices=("condition", "role"), help="score each condition (or role) apart")
        for sub in (template, score) if tool.name == "godspeed" else ():
            sub.add_argument("--items", metavar="FILE.yaml",
                             help="item definitions to use instead of the packaged ones (e.g. a translation "
                                  "with reverse-keyed items)")
        if tool.name != "godspeed":
            template.set_defaults(items=None)
            score.set_defaults(items=None)
        score.set_defaults(func=lambda args, tool=tool: _score(tool, args))
