"""Gesture files (LuxAI's XML): reading them, tolerant and exact about what matters, and writing them.

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

import math
import os
import re
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from robot_models import RobotModel, load_qtrobot
from robot_models.gestures import format_gesture_xml

from ..interface import Gesture, Waypoint


class GestureFormatError(ValueError):
    """A gesture file (or text) that cannot be used; the message names the source, the waypoint and the fix."""

    def __init__(self, source: str, message: str, index: int | None = None) -> None:
        where = f"{source}: waypoint {index}: " if index is not None else f"{source}: "
        super().__init__(where + message)
        self.source = source
        self.index = index


class GestureFormatWarning(UserWarning):
    """Something a gesture file gets wrong that does not stop it from playing."""


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
