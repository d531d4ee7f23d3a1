"""The table of study kinds (kind.py says what a kind is): a study file's `kind:` names one (none: task)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from client_protocol import names
from client_protocol.files import load_model_file, read_document

from ..recording.format import NotARecording
from .classroom_kind import ClassroomKind
from .kind import StudyKind
from .qam_measured import Measured, all_missing, recording_kind
from .studyfile import StudyFileError
from .task_kind import TaskKind

KINDS: dict[str, StudyKind] = {kind.name: kind for kind in (TaskKind(), ClassroomKind())}


def load_study(path: Path | str) -> Any:
    """A study file of any kind: `kind: classroom` (a lesson, classroom.py) or none/`task` (a task study)."""
    path = Path(path)
    document = read_document(path, error=StudyFileError)
    name = document.get("kind", "task") if isinstance(document, dict) else "task"
    if name not in KINDS:
        raise StudyFileError(f"{path}: kind: {name!r} is not a kind of study; give classroom (a lesson with "
                             "simulated pupils and teacher) or leave it out (a task study such as toolbox.yaml)")
    return load_model_file(KINDS[name].model, path, error=StudyFileError)


def kind_of(study: Any) -> StudyKind:
    """The kind of a loaded study file."""
    return KINDS[study.kind]


def measure_qam(path: Path) -> list[Measured]:
    """QAM's items P1-P6 from one trial recording, by the kind its /study/session names; each missing one with
    its reason."""
    if not path.is_file():
        return all_missing(f"no recording: {path.name} was not found")
    try:
        name = recording_kind(path)
    except (NotARecording, OSError, ValueError) as exc:
        return all_missing(f"the recording cannot be read ({exc})")
    if name is None:
        return all_missing(f"the recording has no {names.STUDY_SESSION_TOPIC}, so the kind of study is unknown")
    if name not in KINDS:
        return all_missing(f"the recording's study is of kind {name!r}, which this version does not know")
    return KINDS[name].qam_items(path)
