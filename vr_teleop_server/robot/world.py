"""The stand-in's simulated world, as what plays its pupils sees it (features/bystanders.py): who is in the room, a
pupil's voice reaching the robot's microphone, and where a pupil looks. Only the stand-in's robot provides it; a
real classroom's children speak and look by themselves.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, runtime_checkable

if TYPE_CHECKING:
    from sim.pupils import Pupil

    from .interface import VoiceActivity


@runtime_checkable
class SimulatedWorld(Protocol):
    @property
    def pupils(self) -> tuple[Pupil, ...]:
        """The simulated pupils: names, places, and the direction the robot hears each one from."""

    def hear(self, pcm: bytes, sample_rate: int, channels: int) -> None:
        """On the loop: a piece of a pupil's voice (PCM S16LE) reaches the robot's microphone."""

    def report_voice(self, activity: VoiceActivity) -> None:
        """On the loop: the microphone array tells of a pupil's voice starting or stopping, as a real one would."""

    def pupil_looks(self, name: str, at_robot: bool) -> None:
        """A pupil turns their head to the robot or away: the head camera's next frame shows it."""
