"""`vr-teleop examples list` and `vr-teleop examples copy DIR`: the example study files, the menus and the sample
sheets installed with the package, so that the guides' commands work from any folder (`study run --example
toolbox`) and a lab gets editable copies to start from."""

from __future__ import annotations

import argparse
import shutil
import sys
from dataclasses import dataclass
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path


@dataclass(frozen=True)
class Example:
    name: str  # what `--example` takes, and the copy's file (or folder) name
    kind: str
    what: str
    use: str  # the command that uses it

    @property
    def source(self) -> Traversable:
        if self.kind == "menus":
            return resources.files("menus").joinpath("data")
        return resources.files("vr_teleop_server").joinpath("data", "examples", self.name)


EXAMPLES = (
    Example("toolbox.yaml", "study", "a robot hands over six toolbox parts; three trials compared on fluency",
            "vr-teleop study run --example toolbox --all --speed max"),
    Example("classroom.yaml", "study", "a three-minute lesson at three autonomy levels",
            "vr-teleop study run --example classroom --all --speed max"),
    Example("menus", "menus", "the headset's radial menus and the dashboard's buttons (one YAML file a menu)",
            "vr-teleop serve --menu-dir menus"),
    Example("qam_paper_table1.csv", "sheet", "QAM answers: the paper's Table 1",
            "vr-teleop qam score qam_paper_table1.csv"),
    Example("fluency_example.csv", "sheet", "a task's human and robot actions, for the fluency metrics",
            "vr-teleop metrics fluency_example.csv --interventions fluency_example_interventions.csv"),
    Example("fluency_example_interventions.csv", "sheet", "the experimenter's interventions in that task",
            "(with fluency_example.csv)"),
)
STUDIES = {e.name.removesuffix(".yaml"): e for e in EXAMPLES if e.kind == "study"}


def study_file(name: str) -> Traversable:
    """A packaged example study by name (toolbox, classroom); KeyError names the ones there are."""
    try:
        return STUDIES[name].source
    except KeyError:
        raise KeyError(f"no example study {name!r}; the examples are {', '.join(STUDIES)} "
                       "(vr-teleop examples list)") from None


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("examples", help="the example studies, menus and sheets installed with the package",
                              description="List the examples installed with the package, or copy them into a "
                                          "folder to edit: study files, the menus, questionnaire and fluency sheets.")
    sub = p.add_subparsers(dest="examples_command", metavar="ACTION", required=True)
    sub.add_parser("list", help="what there is, and the command that uses each").set_defaults(func=run_list)
    c = sub.add_parser("copy", help="copy every example into DIR (created if needed) to edit")
    c.add_argument("dir", type=Path, metavar="DIR")
    c.add_argument("--force", action="store_true", help="overwrite files already in DIR")
    c.set_defaults(func=run_copy)


def run_list(_args: argparse.Namespace) -> int:
    width = max(len(e.name) for e in EXAMPLES)
    for e in EXAMPLES:
        print(f"{e.name:<{width}}  {e.kind:<5}  {e.what}\n{'':<{width}}         {e.use}")
    print("\nvr-teleop examples copy DIR: editable copies of them all in DIR")
    return 0


def _copy(source: Traversable, target: Path, force: bool, written: list[Path]) -> list[Path]:
    """Copies a file or folder; returns the files that were already there (and were kept, without --force)."""
    if source.is_dir():
        target.mkdir(parents=True, exist_ok=True)
        kept: list[Path] = []
        for child in sorted(source.iterdir(), key=lambda c: c.name):
            if child.name != "__init__.py" and not child.name.startswith(("_", ".")):
                kept += _copy(child, target / child.name, force, written)
        return kept
    if target.exists() and not force:
        return [target]
    with resources.as_file(source) as path:
        shutil.copyfile(path, target)
    written.append(target)
    return []


def run_copy(args: argparse.Namespace) -> int:
    args.dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    kept = [path for e in EXAMPLES for path in _copy(e.source, args.dir / e.name, args.force, written)]
    print(f"copied {len(written)} file{'' if len(written) == 1 else 's'} into {args.dir}")
    if kept:
        print(f"kept {len(kept)} file{'' if len(kept) == 1 else 's'} already there (--force overwrites them): "
              + ", ".join(str(p) for p in kept), file=sys.stderr)
    print(f"e.g. vr-teleop study run {args.dir / 'toolbox.yaml'} --all --speed max")
    return 0
