"""The stand-in's simulated pupils: the classroom's bystander figures (sim/scene.py draws them from this table), with
names, places and what a microphone array would hear of them. Simulation only: a real classroom has real children.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

TABLE_HEIGHT = 0.72  # metres: the robot stands on a classroom table (sim/scene.py)

# name, floor position in the world (x, y; the robot's base is above the origin), height, shirt, skin, hair
FIGURES: tuple[tuple[str, tuple[float, float], float, tuple[float, ...], tuple[float, ...], tuple[float, ...]], ...] = (
    ("child_left", (1.65, 0.65), 1.25, (0.3, 0.5, 0.85, 1), (0.96, 0.80, 0.69, 1), (0.35, 0.22, 0.1, 1)),
    ("adult_centre", (2.05, -0.1), 1.72, (0.55, 0.25, 0.3, 1), (0.76, 0.57, 0.45, 1), (0.1, 0.08, 0.06, 1)),
    ("child_right", (1.55, -0.8), 1.35, (0.3, 0.65, 0.4, 1), (0.55, 0.38, 0.27, 1), (0.05, 0.05, 0.05, 1)),
)


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
