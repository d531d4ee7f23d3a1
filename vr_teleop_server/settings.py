"""The server's settings: one validated object, built by the CLI and passed to every component."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, SecretStr, ValidationInfo, field_validator

from .core.settings import MIB, CoreSettings
from .media.turn import DEFAULT_TTL_S, IceConfig, check_url
from .teleop.settings import TeleopSettings

__all__ = ["MIB", "CoreSettings", "ServerSettings"]


class ServerSettings(CoreSettings):
    backend: Literal["sim", "ros", "luxai", "none"] = Field(
        "sim", description="the robot: 'sim', the embedded MuJoCo stand-in; 'ros', a real QTrobot through its own "
                           "rosbridge at robot_url; 'luxai', a QTrobot v3 through LuxAI's SDK at robot_url; 'none', "
                           "the protocol server alone")
    robot_url: str | None = Field(
        None, description="the real robot: its rosbridge for backend 'ros' (default ws://127.0.0.1:9091); for "
                          "'luxai' its service hub, tcp://HOST:50500 (the default, on 127.0.0.1), or an MQTT broker "
                          "(mqtt://, mqtts://, wss://) with robot_id")
    robot_id: str | None = Field(None, description="the QTrobot v3's id (e.g. QTRD000320), for 'luxai' over MQTT")
    mqtt_ca_file: Path | None = Field(None, description="for 'luxai' through a TLS broker (mqtts://, wss://): the CA "
                                                        "certificate (PEM) to trust; default: the system's")
    mqtt_username: str | None = Field(None, description="for 'luxai' through a broker that wants a login")
    mqtt_password: str | None = Field(None, description="its password (the CLI reads $VR_TELEOP_MQTT_PASSWORD)")
    camera_url: str | None = Field(
        None, description="the QTrobot v3's realsense-driver plugin over ZeroMQ, tcp://HOST:PORT (default: the "
                          "robot's host, port 50655); over MQTT it is found under its node id")
    camera_width: int = Field(640, ge=16, le=4096)
    camera_height: int = Field(480, ge=16, le=4096)
    camera_fps: float = Field(30.0, gt=0, le=120, description="head-camera frames a second while someone watches")
    gesture_dir: Path | None = Field(
        None, description="where recorded gestures are saved and extra gesture files are loaded from")
    menu_dir: Path | None = Field(None, description="the radial menu files (*.yaml); default: the packaged menus")
    audio_dir: Path | None = Field(None, description="where operator audio is logged; default: a directory in "
                                                     "the system's temporary directory")
    motivation_config: Path | None = Field(None, description="motivation variables file; default: the packaged")
    bystander_interval: float = Field(20.0, ge=0, description="the stand-in's simulated pupils take turns saying a "
                                                              "line every this many seconds, heard in the robot's "
                                                              "microphone and reported as voice activity (0: never)")
    autonomy: Literal["teleoperated", "supervised", "autonomous"] = Field(
        "supervised", description="the robot's autonomy level at start (changed live with /vr_teleop/autonomy/level): "
                                  "'teleoperated', nothing moves unless someone moves it; 'supervised', the robot "
                                  "looks at who speaks and proposes actions the teacher accepts, rejects or lets "
                                  "time out (then done); 'autonomous', it does what it proposes")
    autonomy_rules: Path | None = Field(None, description="the proposal rules (YAML: situations to menu items); "
                                                          "default: the packaged rules")
    autonomy_memory: Path | None = Field(None, description="the JSON file where autonomy keeps what it learned from "
                                                           "the teacher (loaded at start, written on each "
                                                           "decision); default: nothing kept between runs")
    autonomy_attention: Path | None = Field(None, description="the attention configuration (YAML: focus times, "
                                                              "switching, speed); default: the packaged one")
    turn_urls: tuple[str, ...] = Field((), description="TURN relays for WebRTC (turn:HOST:3478?transport=udp, "
                                                     "turns:HOST:443?transport=tcp...); need turn_secret")
    turn_secret: SecretStr | None = Field(None, description="the relay's shared secret (coturn static-auth-secret): "
                                                            "time-limited TURN credentials are made from it")
    turn_ttl: float = Field(DEFAULT_TTL_S, gt=0, description="seconds a TURN credential stays valid")
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

    @field_validator("ice_servers", "turn_urls")
    @classmethod
    def _urls(cls, urls: tuple[str, ...]) -> tuple[str, ...]:
        return tuple(check_url(u) for u in urls)

    @field_validator("turn_secret")
    @classmethod
    def _secret_with_turn(cls, secret: SecretStr | None, info: ValidationInfo) -> SecretStr | None:
        # (the error shows the input: it is raised only when there is no secret to show)
        if (secret is None or not secret.get_secret_value()) and info.data.get("turn_urls"):
            raise ValueError("the TURN URLs need the relay's shared secret: give --turn-secret (coturn's "
                             "static-auth-secret) or $VR_TELEOP_TURN_SECRET")
        return secret

    def ice_config(self) -> IceConfig:
        """The ICE servers every peer gets (STUN as given, TURN with credentials from the secret)."""
        secret = self.turn_secret.get_secret_value() if self.turn_secret is not None else ""
        return IceConfig(urls=(*self.ice_servers, *self.turn_urls), secret=secret, ttl_s=self.turn_ttl)

    @property
    def resolved_robot_url(self) -> str:
        """robot_url, or the backend's default."""
        if self.robot_url:
            return self.robot_url
        return "tcp://127.0.0.1:50500" if self.backend == "luxai" else "ws://127.0.0.1:9091"
