"""The server's settings: one validated object, built by the CLI and passed to every component."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from .teleop.settings import TeleopSettings

MIB = 1024 * 1024


class ServerSettings(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    host: str = "127.0.0.1"
    port: int = Field(9090, ge=0, le=65535)
    time_style: Literal["ros1", "ros2"] = Field(
        "ros1", description="time fields sent as {secs, nsecs} (ROS 1 clients) or {sec, nanosec} (ROS 2)")
    max_message_size: int = Field(16 * MIB, ge=1024, description="frames larger than this get a status error")
    hard_frame_factor: int = Field(
        4, ge=1, description="frames over max_message_size x this close the connection (code 1009), so that a "
                             "hostile client cannot make the server buffer without bound")
    service_timeout: float = Field(10.0, gt=0, description="seconds a call waits when the caller sets no timeout")
    queue_bound: int = Field(100, ge=1, description="messages kept per subscription for a slow reader when the "
                                                    "subscriber set no queue_length")
    control_queue_bound: int = Field(1000, ge=10, description="replies and status messages kept for a slow reader")
    fragment_timeout: float = Field(10.0, gt=0, description="seconds an incomplete fragment set is kept")
    max_pending_calls: int = Field(100, ge=1, description="service calls one client may have in progress")
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
    certfile: Path | None = Field(None, description="TLS certificate (PEM): serve wss:// and https://")
    keyfile: Path | None = Field(None, description="TLS private key (PEM), with certfile")
    teleop: TeleopSettings = Field(default_factory=TeleopSettings, description="explicit control (teleop/settings.py)")

    @property
    def max_frame_size(self) -> int:
        return self.max_message_size * self.hard_frame_factor
