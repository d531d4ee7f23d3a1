"""Gestures: LuxAI's gesture files (file_format.py), the library behind /qt_robot/gesture/* (library.py), and
recording from joint states (recorder.py)."""

from .file_format import (
    GestureDocument,
    GestureFormatError,
    GestureFormatWarning,
    gesture_to_xml,
    parse_gesture_document,
    parse_gesture_xml,
)
from .library import (
    LUXAI_PREFIX,
    NAME_PATTERN,
    GestureLibrary,
    UnknownGestureError,
    canonical_name,
    check_save_name,
    default_user_gesture_dir,
    packaged_gesture_dir,
)
from .recorder import RECORD_RATE_HZ, GestureRecorder

__all__ = [
    "LUXAI_PREFIX", "NAME_PATTERN", "RECORD_RATE_HZ", "GestureDocument", "GestureFormatError", "GestureFormatWarning",
    "GestureLibrary", "GestureRecorder", "UnknownGestureError", "canonical_name", "check_save_name",
    "default_user_gesture_dir", "gesture_to_xml", "packaged_gesture_dir", "parse_gesture_document",
    "parse_gesture_xml",
]
