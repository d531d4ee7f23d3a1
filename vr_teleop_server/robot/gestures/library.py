"""The gesture library behind /qt_robot/gesture/*: the packaged gestures and the user's recordings, by name."""

from __future__ import annotations

import dataclasses
import difflib
import logging
import os
import re
import tempfile
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from robot_models import RobotModel, load_qtrobot
from robot_models.gestures import GESTURE_DIR

from ..interface import Gesture
from .file_format import GestureFormatError, GestureFormatWarning, gesture_to_xml, parse_gesture_document

log = logging.getLogger(__name__)

LUXAI_PREFIX = "QT/"  # LuxAI addresses gestures as QT/<name>; the library accepts it and strips it
NAME_PATTERN = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}")


class UnknownGestureError(KeyError):
    """A gesture name the library does not have; the message lists those it has."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else "unknown gesture"


def packaged_gesture_dir() -> Path:
    """The directory of the gestures we ship (robot_models/gestures: wave, nod, point_forward)."""
    return GESTURE_DIR


def default_user_gesture_dir() -> Path:
    """Where recordings are saved when serve gets no --gesture-dir (XDG's data directory)."""
    base = os.environ.get("XDG_DATA_HOME") or os.path.join(os.path.expanduser("~"), ".local", "share")
    return Path(base) / "vr-teleop" / "gestures"


def canonical_name(name: str) -> str:
    """The library key for `name`: surrounding space and one leading 'QT/' removed ("QT/wave" -> "wave")."""
    key = str(name).strip()
    return key[len(LUXAI_PREFIX):] if key.startswith(LUXAI_PREFIX) else key


def check_save_name(name: str) -> str:
    """The name a recording may be saved under, or ValueError saying why not and what would do."""
    if any(sep in name for sep in {"/", "\\", os.sep, os.altsep or "/"}):
        hint = (f"drop the {LUXAI_PREFIX!r} prefix, which names gestures on the robot"
                if name.startswith(LUXAI_PREFIX) else "use a plain name such as 'my_wave'")
        raise ValueError(f"gesture name {name!r} contains a path separator; {hint}")
    if not NAME_PATTERN.fullmatch(name):
        raise ValueError(f"gesture name {name!r} is not allowed; use 1-64 letters, digits, '_', '-' or '.', "
                         "not starting with '.' or '-' (e.g. 'my_wave')")
    return name


@dataclass(frozen=True)
class _Entry:
    gesture: Gesture
    parts: tuple[str, ...]
    path: Path


class GestureLibrary:
    """The gestures the robot can play by name: the packaged ones plus the user's recordings.

    Names are file stems of `*.xml` files (not recursive). `dirs` (default: the packaged robot_models/gestures)
    are read-only; `user_dir` is read last and is where save() writes, so a user file shadows a packaged one of
    the same name. Lookups accept "wave" and LuxAI's "QT/wave" alike and are case-sensitive. A played gesture
    carries its library name, whatever its file's <name> says. Files that fail to load are left out, logged,
    and listed in `errors` (strict=True raises instead), so one bad recording cannot stop the server.
    Call reload() to pick up files changed on disk; save() updates the library itself.
    """

    def __init__(self, dirs: Iterable[str | os.PathLike[str]] | None = None, model: RobotModel | None = None, *,
                 user_dir: str | os.PathLike[str] | None = None, strict: bool = False) -> None:
        self.model = model or load_qtrobot()
        self.dirs = tuple(Path(d) for d in (dirs if dirs is not None else (GESTURE_DIR,)))
        self.user_dir = Path(user_dir) if user_dir is not None else None
        self.strict = strict
        self._entries: dict[str, _Entry] = {}
        self.errors: dict[Path, str] = {}
        self.reload()

    def reload(self) -> None:
        """Re-read every directory (the in-memory library is replaced only when all reading is done)."""
        entries: dict[str, _Entry] = {}
        errors: dict[Path, str] = {}
        for d in self.dirs:
            if not d.is_dir():
                raise FileNotFoundError(f"gesture directory {d} does not exist; fix the path (the packaged "
                                        f"gestures are in {GESTURE_DIR})")
        search = self.dirs + ((self.user_dir,) if self.user_dir is not None and self.user_dir.is_dir() else ())
        for d in search:
            for path in sorted(d.glob("*.xml")):
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore", GestureFormatWarning)
                        doc = parse_gesture_document(path, self.model, strict=self.strict)
                except GestureFormatError as exc:
                    if self.strict:
                        raise
                    errors[path] = str(exc)
                    log.warning("gesture file skipped: %s", exc)
                    continue
                for note in doc.warnings:
                    log.info("gesture %s: %s", path, note)
                gesture = dataclasses.replace(doc.gesture, name=path.stem)
                entries[path.stem] = _Entry(gesture, doc.parts, path)
        self._entries, self.errors = entries, errors

    def names(self) -> list[str]:
        return sorted(self._entries)

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and canonical_name(name) in self._entries

    def __len__(self) -> int:
        return len(self._entries)

    def _entry(self, name: str) -> _Entry:
        key = canonical_name(name)
        try:
            return self._entries[key]
        except KeyError:
            pass
        broken = [f"{p}: {msg}" for p, msg in self.errors.items() if p.stem == key]
        if broken:
            raise UnknownGestureError(f"gesture {name!r} failed to load ({broken[0]})")
        close = difflib.get_close_matches(key, self._entries, n=3)
        hint = f"did you mean {', '.join(close)}? " if close else ""
        raise UnknownGestureError(f"unknown gesture {name!r}; {hint}available: {', '.join(self.names()) or 'none'} "
                                  f"(also as {LUXAI_PREFIX}<name>)")

    def get(self, name: str) -> Gesture:
        return self._entry(name).gesture

    def parts(self, name: str) -> tuple[str, ...]:
        """The parts the gesture's file declares."""
        return self._entry(name).parts

    def path(self, name: str) -> Path:
        return self._entry(name).path

    def save(self, gesture: Gesture, parts: Sequence[str] | None = None, *, overwrite: bool = False) -> Path:
        """Write `gesture` as <user_dir>/<gesture.name>.xml and add it to the library; returns the path.

        Refuses names with path separators (or outside NAME_PATTERN) and, unless overwrite=True, names the
        library already has (including packaged ones, which a user file would shadow).
        """
        if self.user_dir is None:
            raise ValueError("this gesture library has no user directory to save into; create it with "
                             "GestureLibrary(..., user_dir=PATH)")
        name = check_save_name(gesture.name)
        if name in self._entries and not overwrite:
            raise FileExistsError(f"gesture {name!r} already exists ({self._entries[name].path}); choose another "
                                  "name or pass overwrite=True")
        text = gesture_to_xml(gesture, parts, model=self.model)
        with warnings.catch_warnings():  # e.g. out-of-limit values: logged, as on loading
            warnings.simplefilter("ignore", GestureFormatWarning)
            doc = parse_gesture_document(text, self.model, source=name)  # serve exactly what the file holds
        for note in doc.warnings:
            log.info("gesture %s: %s", name, note)
        self.user_dir.mkdir(parents=True, exist_ok=True)
        path = self.user_dir / f"{name}.xml"
        fd, tmp = tempfile.mkstemp(prefix=f".{name}.", suffix=".tmp", dir=self.user_dir)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(text)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        self._entries[name] = _Entry(dataclasses.replace(doc.gesture, name=name), doc.parts, path)
        self.errors.pop(path, None)
        return path
