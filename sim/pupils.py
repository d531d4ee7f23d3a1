"""The stand-in's simulated pupils: the classroom's bystander figures (sim/scene.py draws them from this table), with
names, places and what a microphone array would hear of them. Simulation only: a real classroom has real children.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

TABLE_HEIGHT = 0.72  # metres: the robot stands on a classroom table (sim/scene.py)

# Skin tones span the range a classroom holds, so that a face detector's bias shows (bench/faces.py): three tones
# of the Monk Skin Tone scale (Monk, 2019), light (MST 2), medium (MST 6) and deep (MST 9), in sRGB.
SKIN_TONES = {"light": (0.953, 0.906, 0.859, 1), "medium": (0.627, 0.494, 0.337, 1), "deep": (0.227, 0.192, 0.165, 1)}

# name, floor position in the world (x, y; the robot's base is above the origin), height, shirt, skin, hair
FIGURES: tuple[tuple[str, tuple[float, float], float, tuple[float, ...], tuple[float, ...], tuple[float, ...]], ...] = (
    ("child_left", (1.65, 0.65), 1.25, (0.3, 0.5, 0.85, 1), SKIN_TONES["light"], (0.35, 0.22, 0.1, 1)),
    ("adult_centre", (2.05, -0.1), 1.72, (0.55, 0.25, 0.3, 1), SKIN_TONES["medium"], (0.1, 0.08, 0.06, 1)),
    ("child_right", (1.55, -0.8), 1.35, (0.3, 0.65, 0.4, 1), SKIN_TONES["deep"], (0.05, 0.05, 0.05, 1)),
)


def skin_tone(name: str) -> str:
    """The skin tone (a key of SKIN_TONES) of a figure."""
    skin = next(f[4] for f in FIGURES if f[0] == name)
    return next(tone for tone, rgba in SKIN_TONES.items() if rgba == skin)


AWAY_DEG = 110.0  # a pupil looking away turns its head this far: its eyes and mouth go round out of the robot's view


def neck_joint(name: str) -> str:
    """The scene's joint that turns a pupil's head (0: facing the robot, positive: to the pupil's left)."""
    return f"{name}_neck"


def head_radius(height: float) -> float:
    return 0.085 if height < 1.5 else 0.1


@dataclass(frozen=True)
class Pupil:
    """One figure as the robot meets it: its head's centre in the robot's base frame (metres)."""

    name: str
    x: float
    y: float
    z: float

    @property
    def yaw_deg(self) -> float:
        """Its direction from the robot's base, degrees, positive to the left (what a microphone array reports)."""
        return math.degrees(math.atan2(self.y, self.x))

    @property
    def distance_m(self) -> float:
        return math.hypot(self.x, self.y)


PUPILS: tuple[Pupil, ...] = tuple(
    Pupil(name, x, y, height - head_radius(height) - TABLE_HEIGHT) for name, (x, y), height, *_ in FIGURES)


def pupil(name: str) -> Pupil:
    for p in PUPILS:
        if p.name == name:
            return p
    raise KeyError(f"no pupil {name!r}; the pupils are {', '.join(p.name for p in PUPILS)}")
