"""QTrobot gestures shipped as data (LuxAI's gesture XML), and the one writer of that file format.

The writer lives here rather than in the server so that `make_gestures.py`, which generates the shipped files,
and `vr_teleop_server.robot.gestures.gesture_to_xml`, which saves recordings, cannot drift apart: robot_models
depends on nothing of ours, the server depends on robot_models. Parsing and validation live in the server.

Format (as LuxAI's gesture files): degrees written with 2 decimals, waypoint times as integer nanoseconds from
the gesture's start, `<duration>` in seconds (2 decimals), joints of each point in the order given.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from pathlib import Path

GESTURE_DIR = Path(__file__).resolve().parent  # the packaged *.xml files sit next to this module
DEGREE_DECIMALS = 2  # LuxAI writes joint angles with two decimals


def format_degrees(value: float) -> str:
    text = f"{float(value):.{DEGREE_DECIMALS}f}"
    return "0.00" if text == "-0.00" else text


def format_gesture_xml(name: str, parts: Sequence[str], points: Sequence[tuple[float, Mapping[str, float]]]) -> str:
    """Serialise (time in seconds, {joint: degrees}) points; no validation here (the callers validate)."""
    root = ET.Element("gesture")
    ET.SubElement(root, "name").text = name
    parts_el = ET.SubElement(root, "parts")
    for part in parts:
        ET.SubElement(parts_el, "part").text = part
    duration = points[-1][0] if points else 0.0
    ET.SubElement(root, "duration").text = f"{duration:.2f}"
    waypoints = ET.SubElement(root, "waypoints", count=str(len(points)))
    for time_s, targets in points:
        point = ET.SubElement(waypoints, "point", time=str(round(time_s * 1e9)))
        for joint, deg in targets.items():
            ET.SubElement(point, joint).text = format_degrees(deg)
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="unicode") + "\n"


__all__ = ["DEGREE_DECIMALS", "GESTURE_DIR", "format_degrees", "format_gesture_xml"]
