"""Robot backends: implementations of vr_teleop_server.robot.interface.Robot, and the one table of them.

BACKENDS names each backend once: the settings' `backend` field, the CLI's choices and the app take their names
(and a real robot's default URL) from here. A backend's module loads only when it is chosen (MuJoCo, roslibpy and
LuxAI's SDK are heavy): its entry names a function that imports its class, and `load()` calls it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

if TYPE_CHECKING:  # the table itself stays light: the settings and the command line import it
    from robot_models import RobotModel
    from simclock import Clock

    from ...settings import ServerSettings
    from ..interface import Robot


@runtime_checkable
class BackendFactory(Protocol):
    """What the server asks of a backend's class (its classmethod and staticmethod)."""

    def from_settings(self, settings: ServerSettings, model: RobotModel, clock: Clock | None = None, /) -> Robot:
        """The robot, built without I/O (open() reaches it); the stand-in starts MuJoCo: call it off the loop."""

    def check_url(self, url: str, robot_id: str | None = None, /) -> object:
        """ValueError saying what to give when `url` (and `robot_id`) cannot name this backend's robot."""


def _sim() -> BackendFactory:
    from .sim import SimRobot
    return SimRobot


def _ros() -> BackendFactory:
    from .ros import RosRobot
    return RosRobot


def _luxai() -> BackendFactory:
    from .luxai import LuxaiRobot
    return LuxaiRobot


@dataclass(frozen=True)
class Backend:
    name: str
    summary: str
    factory: Callable[[], BackendFactory] | None = None  # imports and gives the backend's class; None: no robot
    default_url: str | None = None  # where a real robot is looked for when no robot_url is given

    def load(self) -> BackendFactory:
        """The backend's class (imports its module)."""
        if self.factory is None:
            raise ValueError(f"backend {self.name!r} has no robot")
        return self.factory()

    def check_url(self, url: str | None, robot_id: str | None = None) -> None:
        """ValueError naming what to give when the URL cannot name this backend's robot."""
        if self.factory is not None:
            self.load().check_url(url or self.default_url or "", robot_id)


BACKENDS: dict[str, Backend] = {b.name: b for b in (
    Backend("sim", "the embedded MuJoCo stand-in", _sim),
    Backend("ros", "a real QTrobot's own rosbridge (ROS 1) at the robot URL, ws://ROBOT:9090", _ros,
            "ws://127.0.0.1:9091"),
    Backend("luxai", "a QTrobot v3 through LuxAI's SDK at the robot URL: its service hub tcp://ROBOT:50500, or an "
            "MQTT broker (mqtt://, mqtts://, wss://) with the robot id", _luxai, "tcp://127.0.0.1:50500"),
    Backend("none", "no robot: the protocol server alone"),
)}
BACKEND_NAMES: tuple[str, ...] = tuple(BACKENDS)
