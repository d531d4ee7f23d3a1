"""Robot backends: implementations of vr_teleop_server.robot.interface.Robot, and the one table of them.

BACKENDS names each backend once: the settings' `backend` field, the CLI's choices and the app take their names
(and a real robot's default URL) from here. A backend's module loads only when it is chosen (MuJoCo, roslibpy and
LuxAI's SDK are heavy), through `load()`.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Backend:
    name: str
    summary: str
    module: str = ""  # "module:Class" with `from_settings(settings, model, clock)`; "" for no robot
    default_url: str | None = None  # where a real robot is looked for when no robot_url is given

    def load(self) -> Any:
        """The backend's class (imports its module)."""
        module, _, cls = self.module.partition(":")
        return getattr(importlib.import_module(module, __package__), cls)

    def check_url(self, url: str | None, robot_id: str | None = None) -> None:
        """ValueError naming what to give when the URL cannot name this backend's robot."""
        if self.default_url is not None:
            self.load().check_url(url or self.default_url, robot_id)


BACKENDS: dict[str, Backend] = {b.name: b for b in (
    Backend("sim", "the embedded MuJoCo stand-in", ".sim:SimRobot"),
    Backend("ros", "a real QTrobot's own rosbridge (ROS 1) at the robot URL, ws://ROBOT:9090", ".ros:RosRobot",
            "ws://127.0.0.1:9091"),
    Backend("luxai", "a QTrobot v3 through LuxAI's SDK at the robot URL: its service hub tcp://ROBOT:50500, or an "
            "MQTT broker (mqtt://, mqtts://, wss://) with the robot id", ".luxai:LuxaiRobot", "tcp://127.0.0.1:50500"),
    Backend("none", "no robot: the protocol server alone"),
)}
BACKEND_NAMES: tuple[str, ...] = tuple(BACKENDS)
