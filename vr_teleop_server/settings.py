"""The server's settings: one validated object, built by the CLI and passed to every component."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field

from .core.settings import MIB, CoreSettings
from .teleop.settings import TeleopSettings

__all__ = ["MIB", "CoreSettings", "ServerSettings"]


class ServerSettings(CoreSettings):
    backend: Literal["sim", "ros", "none"] = Field(
        "sim", description="the robot: 'sim', the embedded MuJoCo stand-in; 'ros', a real QTrobot through its own "
                           "rosbridge at robot_url; 'none', the protocol server alone")
    robot_url: str = Field("ws://127.0.0.1:9091", description="the real robot's rosbridge, for backend 'ros'")
    camera_width: int = Field(640, ge=16, le=4096)
    camera_height: int = Field(480, ge=16, le=4096)
    camera_fps: float = Field(30.0, gt=0, le=120, description="head-camera frames a second while someone watches")
    gesture_dir: Path | None = Field(
        None, description="where recorded gestures are saved and extra gesture files are loaded from")
    menu_dir: Path | None = Field(None, description="the radial menu files (*.yaml); default: the packaged menus")
    audio_dir: Path | None = Field(None, description="where operator audio is logged; default: a directory in "
                                                     "the system's temporary directory")
    motivation_config: Path | None = Field(None, description="motivation variables file; default: the packaged")
    bystander_interval: float = Field(20.0, ge=0, description="seconds between the stand-in's bystanders' lines "
                                                              "in the robot's WebRTC audio (0: none)")
    ice_servers: tuple[str, ...] = Field((), description="STUN servers for WebRTC (stun:HOST:PORT); none on a "
                                                       "LAN, where host candidates reach the client")
    record: Path | None = Field(None, description="record the session to this MCAP file")
    record_camera_fps: float = Field(2.0, ge=0, le=120, description="camera frames a second kept in the "
                                                                     "recording (0: none)")
    operator_token: str | None = Field(None, description="token of the operator role (auth op)")
    supervisor_token: str | None = Field(None, description="token of the supervisor role")
    spectator_token: str | None = Field(None, description="token of the spectator role")
    insecure: bool = Field(False, description="allow open access (no tokens) on a non-loopback address")
    teleop: TeleopSettings = Field(default_factory=TeleopSettings, description="explicit control (teleop/settings.py)")
