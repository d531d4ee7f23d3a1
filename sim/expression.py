"""What the stand-in's face screen should show: the emotion, speech and the operator's voice (face.py draws it).

The state lives under the render thread's condition (`cond`): every change wakes that thread, which redraws the
face texture and marks the change applied (wait_applied).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

import numpy as np

from .face import normalise_emotion


class Expression:
    ANIMATION_HZ = 12.0  # talking-mouth frames a second
    VOICE_HOLD_S = 0.25  # the mouth closes this long after the last piece of voice

    def __init__(self, cond: threading.Condition, monotonic: Callable[[], float], emotion: str) -> None:
        self.cond = cond
        self.monotonic = monotonic  # the server's clock
        self.emotion = normalise_emotion(emotion)
        self.talking_until = 0.0
        self.voice = (0.0, -math.inf)  # (level, monotonic time it was set)
        self.version = 0  # bumped on every request that changes the face
        self.applied = -1
        self.image: np.ndarray | None = None
        self.image_voice: float | None = None  # the voice level `image` shows (None: drawn with no voice)

    def set_emotion(self, name: str) -> None:
        emotion = normalise_emotion(name)
        with self.cond:
            self.emotion = emotion
            self.version += 1
            self.cond.notify_all()

    def speak(self, duration_s: float) -> None:
        if not (math.isfinite(duration_s) and duration_s >= 0):
            raise ValueError(f"speech duration must be a finite number of seconds >= 0, got {duration_s!r}")
        with self.cond:
            self.talking_until = self.monotonic() + duration_s
            self.version += 1
            self.cond.notify_all()

    def is_talking(self) -> bool:
        return self.monotonic() < self.talking_until

    def set_voice_level(self, level: float) -> None:
        level = min(1.0, max(0.0, float(level))) if math.isfinite(level) else 0.0
        with self.cond:
            self.voice = (level, self.monotonic())
            self.cond.notify_all()

    def voice_level(self) -> float:
        level, at = self.voice
        return level if self.monotonic() - at < self.VOICE_HOLD_S else 0.0

    def voice_at(self, now: float) -> float | None:
        """The voice level at `now`, None once it has stopped (the caller holds cond)."""
        return self.voice[0] if now - self.voice[1] < self.VOICE_HOLD_S else None

    def drawn(self, image: np.ndarray, version: int, voice: float | None) -> None:
        """The render thread uploaded `image`, drawn for the state as of `version` with the voice level `voice`."""
        with self.cond:
            self.image, self.image_voice = image, voice
            self.applied = max(self.applied, version)
            self.cond.notify_all()

    def copy_image(self) -> np.ndarray | None:
        with self.cond:
            return None if self.image is None else self.image.copy()

    def copy_image_with_voice(self) -> tuple[np.ndarray | None, float | None]:
        with self.cond:
            return None if self.image is None else self.image.copy(), self.image_voice

    def wait_applied(self, timeout: float, stop: threading.Event) -> bool:
        """Block until every change requested so far is drawn (False on timeout, or once `stop` is set)."""
        deadline = time.monotonic() + timeout
        with self.cond:
            target = self.version
            while self.applied < target:
                left = deadline - time.monotonic()
                if left <= 0 or stop.is_set():
                    return False
                self.cond.wait(left)
            return True
