"""Gesture files (LuxAI's XML), the gesture library behind /qt_robot/gesture/*, and recording from joint states.

File format, as LuxAI's gesture files:
    <gesture><name>bye</name><parts><part>right_arm</part></parts><duration>7.96</duration>
      <waypoints count="160"><point time="NANOSECONDS"><RightElbowRoll>-35.51</RightElbowRoll>...</point>...
Angles in degrees, point times in nanoseconds from the gesture's start, duration in seconds.

Reading is tolerant of what other tools write (whitespace anywhere, a missing `count` or `<parts>`, extra
elements and attributes, comments) and strict about what would make a gesture wrong. Errors
(GestureFormatError) name the file, the waypoint index and the fix:
- malformed XML, a DOCTYPE (gesture files never need one; refused so no entity tricks reach the parser),
  a root other than <gesture>, no waypoints, a point without joints;
- a point time missing, not a number, negative, or earlier than the point before (equal times are allowed);
- an unknown joint name, a value that is not a finite number;
- an unknown part, or a joint whose part is not declared in <parts>.
Warnings (GestureFormatWarning; errors when strict=True) for what LuxAI's player tolerates and ours does too:
- `count` differing from the number of points (the points win: count is redundant),
- a declared part none of whose joints appear,
- a value outside the joint's limits (the robot clamps it and reports the clamp when played).
Missing <parts>: inferred from the joints used. Missing <name>: the file's stem. <duration> is informational;
the point times rule.

Writing (gesture_to_xml) uses robot_models.gestures.format_gesture_xml, the same writer that made the shipped
files: 2 decimals of a degree, integer nanoseconds. A round trip therefore reproduces times to the nanosecond
and angles to within 0.005 degrees, and re-writing a parsed file reproduces its text exactly.
"""

from __future__ import annotations

import dataclasses
import difflib
import logging
import math
import os
import re
import tempfile
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from robot_models import RobotModel, load_qtrobot
from robot_models.gestures import GESTURE_DIR, format_gesture_xml

from .interface import Gesture, JointState, Waypoint

log = logging.getLogger(__name__)

LUXAI_PREFIX = "QT/"  # LuxAI addresses gestures as QT/<name>; the library accepts it and strips it
NAME_PATTERN = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}")
RECORD_RATE_HZ = 20.0  # LuxAI records gestures at about 20 waypoints a second


class GestureFormatError(ValueError):
    """A gesture file (or text) that cannot be used; the message names the source, the waypoint and the fix."""

    def __init__(self, source: str, message: str, index: int | None = None) -> None:
        where = f"{source}: waypoint {index}: " if index is not None else f"{source}: "
        super().__init__(where + message)
        self.source = source
        self.index = index


class GestureFormatWarning(UserWarning):
    """Something a gesture file gets wrong that does not stop it from playing."""


class UnknownGestureError(KeyError):
    """A gesture name the library does not have; the message lists those it has."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else "unknown gesture"


@dataclass(frozen=True)
class GestureDocument:
    """Everything a gesture file says: the trajectory plus the parts it declares."""

    gesture: Gesture
    parts: tuple[str, ...]
    declared_duration_s: float | None
    warnings: tuple[str, ...]  # what was tolerated (also issued as GestureFormatWarning)
    source: str


# ------------------------------------------------------------------------------------------------------ parsing
def _read_source(text_or_path: str | bytes | os.PathLike[str], source: str | None) -> tuple[str, str, str | None]:
    """(text, label for messages, file stem or None). Strings starting with '<' are XML text, others paths."""
    if isinstance(text_or_path, bytes):
        return text_or_path.decode("utf-8"), source or "<gesture text>", None
    if isinstance(text_or_path, str) and text_or_path.lstrip().startswith("<"):
        return text_or_path, source or "<gesture text>", None
    path = Path(text_or_path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise GestureFormatError(source or str(path), "no such file; check the path (or pass the XML text itself, "
                                 "which must start with '<')") from None
    except UnicodeDecodeError as exc:
        raise GestureFormatError(source or str(path), f"not UTF-8 text ({exc.reason}); save it as UTF-8") from None
    return text, source or str(path), path.stem


def _local(tag: object) -> str:
    """Tag name without a namespace; comments and processing instructions have non-string tags."""
    return tag.rsplit("}", 1)[-1] if isinstance(tag, str) else ""


def _parts_declared(root: ET.Element) -> list[str] | None:
    parts_el = next((c for c in root if _local(c.tag) == "parts"), None)
    if parts_el is None:
        return None
    named = [(p.text or "").strip() for p in parts_el if _local(p.tag) == "part"]
    if not named and (parts_el.text or "").strip():  # tolerate <parts>head, right_arm</parts>
        named = re.split(r"[\s,]+", parts_el.text.strip())
    return [p for p in named if p]


def parse_gesture_document(text_or_path: str | bytes | os.PathLike[str], model: RobotModel, *,
                           source: str | None = None, strict: bool = False) -> GestureDocument:
    """Read and validate one gesture file or XML text (see the module docstring for the rules)."""
    text, label, stem = _read_source(text_or_path, source)
    notes: list[str] = []

    def tolerate(message: str, index: int | None = None) -> None:
        if strict:
            raise GestureFormatError(label, message + " (strict mode)", index)
        where = f"waypoint {index}: " if index is not None else ""
        notes.append(where + message)
        warnings.warn(f"{label}: {where}{message}", GestureFormatWarning, stacklevel=3)

    if re.search(r"<!\s*(DOCTYPE|ENTITY)", text, re.IGNORECASE):
        raise GestureFormatError(label, "contains a DOCTYPE or ENTITY declaration, which gesture files never "
                                 "need; remove it")
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        line, col = exc.position
        raise GestureFormatError(label, f"not well-formed XML at line {line}, column {col + 1} ({exc}); "
                                 "fix the markup there") from None
    if _local(root.tag) != "gesture":
        raise GestureFormatError(label, f"root element is <{_local(root.tag)}>, expected <gesture>; this is not "
                                 "a LuxAI gesture file")

    name_el = next((c for c in root if _local(c.tag) == "name"), None)
    name = (name_el.text or "").strip() if name_el is not None else ""
    name = name or stem or ""
    if not name:
        raise GestureFormatError(label, "has no <name>; add <name>your_gesture</name> under <gesture>")

    duration_el = next((c for c in root if _local(c.tag) == "duration"), None)
    declared_duration = None
    if duration_el is not None and (duration_el.text or "").strip():
        try:
            declared_duration = float(duration_el.text)
        except ValueError:
            tolerate(f"<duration> {duration_el.text.strip()!r} is not a number of seconds; ignored")

    wps_el = next((c for c in root if _local(c.tag) == "waypoints"), None)
    points = [p for p in wps_el if _local(p.tag) == "point"] if wps_el is not None else []
    if not points:
        raise GestureFormatError(label, "has no waypoints; expected <waypoints><point time=\"NANOSECONDS\">"
                                 "<JointName>degrees</JointName>...</point>...</waypoints>")

    waypoints: list[Waypoint] = []
    last_ns = -math.inf
    for i, point in enumerate(points):
        raw_time = point.get("time")
        if raw_time is None or not raw_time.strip():
            raise GestureFormatError(label, "has no time attribute; add time=\"NANOSECONDS from the start\"", i)
        try:
            ns = float(raw_time)
        except ValueError:
            raise GestureFormatError(label, f"time {raw_time.strip()!r} is not a number; times are integer "
                                     "nanoseconds from the start", i) from None
        if not math.isfinite(ns) or ns < 0:
            raise GestureFormatError(label, f"time {raw_time.strip()} must be a finite number of nanoseconds "
                                     ">= 0", i)
        if ns < last_ns:
            raise GestureFormatError(label, f"time {ns:.0f} ns is earlier than the previous point's {last_ns:.0f} ns; "
                                     "points must be in time order (sort them, or fix the time)", i)
        last_ns = ns
        targets: dict[str, float] = {}
        for el in point:
            joint_name = _local(el.tag)
            if not joint_name:
                continue  # a comment
            try:
                joint = model.joint(joint_name)
            except KeyError:
                raise GestureFormatError(label, f"unknown joint <{joint_name}>; valid joints: "
                                         f"{', '.join(model.names)} (the wrists and hands are not motorised)",
                                         i) from None
            raw = (el.text or "").strip()
            try:
                value = float(raw)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                raise GestureFormatError(label, f"{joint_name} value {raw!r} is not a finite number of degrees; "
                                         f"write a number in [{joint.lower:g}, {joint.upper:g}]", i)
            if joint_name in targets:
                raise GestureFormatError(label, f"{joint_name} appears twice in one point; keep one", i)
            if not joint.lower <= value <= joint.upper:
                tolerate(f"{joint_name} {value:g} deg is outside [{joint.lower:g}, {joint.upper:g}]; "
                         "the robot will clamp it", i)
            targets[joint_name] = value
        if not targets:
            raise GestureFormatError(label, "has no joint values; add <JointName>degrees</JointName> elements "
                                     "or remove the point", i)
        waypoints.append(Waypoint(ns / 1e9, targets))

    used = list(dict.fromkeys(n for wp in waypoints for n in wp.targets))
    used_parts = list(dict.fromkeys(model.joint(n).part for n in used))
    declared = _parts_declared(root)
    if not declared:
        parts = tuple(p for p in model.parts if p in used_parts)  # inferred, in the model's order
    else:
        for p in declared:
            if p not in model.parts:
                raise GestureFormatError(label, f"unknown part {p!r} in <parts>; valid parts: "
                                         f"{', '.join(model.parts)}")
        for n in used:
            part = model.joint(n).part
            if part not in declared:
                first = next(i for i, wp in enumerate(waypoints) if n in wp.targets)
                raise GestureFormatError(label, f"joint {n} belongs to part {part!r}, which <parts> does not "
                                         f"declare ({', '.join(declared)}); add <part>{part}</part> or remove "
                                         f"the {n} values", first)
        for p in declared:
            if p not in used_parts:
                tolerate(f"part {p!r} is declared but none of its joints ({', '.join(model.part_joints(p))}) "
                         "appear; it will not move")
        parts = tuple(dict.fromkeys(declared))

    if wps_el is not None and wps_el.get("count") is not None:
        raw_count = wps_el.get("count", "").strip()
        if not raw_count.isdigit() or int(raw_count) != len(points):
            tolerate(f"count=\"{raw_count}\" but there are {len(points)} points; the points are used")

    gesture = Gesture(name, tuple(waypoints))
    gesture.validate(model)  # the Robot's own check, so a parsed gesture always plays
    return GestureDocument(gesture, parts, declared_duration, tuple(notes), label)


def parse_gesture_xml(text_or_path: str | bytes | os.PathLike[str], model: RobotModel, *,
                      source: str | None = None, strict: bool = False) -> Gesture:
    """A Gesture from a LuxAI gesture file (path) or its XML text (a string starting with '<')."""
    return parse_gesture_document(text_or_path, model, source=source, strict=strict).gesture


# ------------------------------------------------------------------------------------------------------ writing
def gesture_to_xml(gesture: Gesture, parts: Sequence[str] | None = None, *, model: RobotModel | None = None) -> str:
    """LuxAI gesture XML for `gesture`; `parts` default to those its joints belong to (model order).

    Raises ValueError if the gesture would not parse back (bad times, unknown joints, undeclared parts).
    """
    model = model or load_qtrobot()
    gesture.validate(model)
    used_parts = {model.joint(n).part for wp in gesture.waypoints for n in wp.targets}
    if parts is None:
        parts = [p for p in model.parts if p in used_parts]
    parts = list(dict.fromkeys(parts))
    for p in parts:
        model.part_joints(p)  # KeyError naming the valid parts
    missing = sorted(used_parts - set(parts), key=list(model.parts).index)
    if missing:
        raise ValueError(f"gesture {gesture.name!r} moves part(s) {', '.join(missing)} but parts="
                         f"{parts}; pass every part it moves (or parts=None to infer them)")
    for i, wp in enumerate(gesture.waypoints):
        for n, v in wp.targets.items():
            if not math.isfinite(float(v)):
                raise ValueError(f"gesture {gesture.name!r} waypoint {i}: {n} is {v!r}, not a finite number")
    return format_gesture_xml(gesture.name, parts, [(wp.time_s, wp.targets) for wp in gesture.waypoints])


# ------------------------------------------------------------------------------------------------------ library
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


# ------------------------------------------------------------------------------------------------------ recording
class GestureRecorder:
    """Turns a stream of joint states into a Gesture, keeping about `rate_hz` samples a second.

    Pure: it never reads the robot or the clock itself. The caller passes each JointState (e.g. from an asyncio
    task polling robot.joint_state()); times come from its stamp_monotonic, or from `t` when given, and the
    gesture starts at 0. A sample is kept when it comes at least 3/4 of a period after the last one kept, so a
    caller polling at the rate keeps every sample despite a quarter period of jitter, and one polling faster
    (e.g. at the 30 or 60 Hz of a joint-state stream) is thinned to about the rate. The newest state at stop()
    is always kept, so the gesture ends where the robot did.
    """

    MIN_SPACING = 0.75  # of a period, between kept samples

    def __init__(self, model: RobotModel, rate_hz: float = RECORD_RATE_HZ) -> None:
        if not (math.isfinite(rate_hz) and 0 < rate_hz <= 1000):
            raise ValueError(f"rate_hz must be in (0, 1000], got {rate_hz!r}")
        self.model = model
        self.period_s = 1.0 / rate_hz
        self._joints: tuple[str, ...] | None = None
        self._parts: tuple[str, ...] = ()
        self._name = "recording"
        self._t0 = 0.0
        self._last_kept_t = -math.inf
        self._kept: list[Waypoint] = []
        self._pending: Waypoint | None = None  # newest state not kept (yet)
        self._last_t = -math.inf

    @property
    def recording(self) -> bool:
        return self._joints is not None

    @property
    def parts(self) -> tuple[str, ...]:
        """The parts of the current (or last) recording; pass them to GestureLibrary.save()."""
        return self._parts

    @property
    def sample_count(self) -> int:
        return len(self._kept) + (self._pending is not None)

    def start(self, parts: Sequence[str], name: str = "recording") -> None:
        if self.recording:
            raise RuntimeError("already recording; stop() or cancel() the current recording first")
        parts = tuple(dict.fromkeys(parts))
        if not parts:
            raise ValueError(f"record at least one part; valid parts: {', '.join(self.model.parts)}")
        self._joints = tuple(n for p in parts for n in self.model.part_joints(p))  # KeyError naming valid parts
        self._parts, self._name = parts, name
        self._kept, self._pending, self._last_kept_t, self._last_t = [], None, -math.inf, -math.inf

    def sample(self, state: JointState, t: float | None = None) -> bool:
        """Offer one joint state; True if it was kept as a waypoint. Repeated stamps are ignored."""
        if self._joints is None:
            raise RuntimeError("sample() called while not recording; call start(parts) first")
        now = state.stamp_monotonic if t is None else float(t)
        if not math.isfinite(now):
            raise ValueError(f"sample time must be finite, got {now!r}")
        if now == self._last_t:
            return False
        if now < self._last_t:
            raise ValueError(f"sample time {now} is earlier than the previous {self._last_t}; pass times from one "
                             "monotonic clock (time.monotonic())")
        positions = state.as_dict()
        missing = [n for n in self._joints if n not in positions]
        if missing:
            raise ValueError(f"joint state lacks {', '.join(missing)}; it must cover parts {', '.join(self._parts)}")
        if self._last_t == -math.inf:
            self._t0 = now
        self._last_t = now
        wp = Waypoint(now - self._t0, {n: float(positions[n]) for n in self._joints})
        if now - self._last_kept_t >= self.MIN_SPACING * self.period_s:
            self._kept.append(wp)
            self._pending = None
            self._last_kept_t = now
            return True
        self._pending = wp
        return False

    def stop(self, name: str | None = None) -> Gesture:
        """End the recording and return it; ValueError if it has fewer than 2 samples (nothing to play)."""
        if self._joints is None:
            raise RuntimeError("stop() called while not recording; call start(parts) first")
        kept = self._kept + ([self._pending] if self._pending is not None else [])
        self._joints, self._kept, self._pending = None, [], None
        if len(kept) < 2:
            raise ValueError(f"the recording has {len(kept)} sample(s); a gesture needs at least 2. Call sample() "
                             f"with the joint state while recording, for at least {self.period_s:.2f} s")
        return Gesture(name or self._name, tuple(kept))

    def cancel(self) -> None:
        """Drop the current recording, if any."""
        self._joints, self._kept, self._pending = None, [], None


__all__ = [
    "GestureDocument", "GestureFormatError", "GestureFormatWarning", "GestureLibrary", "GestureRecorder",
    "LUXAI_PREFIX", "NAME_PATTERN", "RECORD_RATE_HZ", "UnknownGestureError", "canonical_name", "check_save_name",
    "default_user_gesture_dir",
    "gesture_to_xml", "packaged_gesture_dir", "parse_gesture_document", "parse_gesture_xml",
]
