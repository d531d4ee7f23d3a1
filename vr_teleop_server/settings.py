"""The server's settings: one validated object, built by the CLI and passed to every component."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from client_protocol.vocabulary import AutonomyLevel
from pydantic import Field, SecretStr, ValidationInfo, field_validator

from .core.settings import MIB, Cli, CoreSettings
from .media.turn import DEFAULT_TTL_S, IceConfig, check_url
from .robot.backends import BACKEND_NAMES, BACKENDS
from .teleop.settings import TeleopSettings

__all__ = ["MIB", "Cli", "CoreSettings", "ServerSettings"]


class ServerSettings(CoreSettings):
    backend: Annotated[Literal[BACKEND_NAMES], Cli("robot")] = Field(  # type: ignore[valid-type]
        "sim", description="the robot: " + "; ".join(f"'{b.name}', {b.summary}" for b in BACKENDS.values()))
    robot_url: Annotated[str | None, Cli("robot", metavar="URL")] = Field(
        None, description="the real robot. --backend ros: its rosbridge, ws://ROBOT:9090 (default "
                          f"{BACKENDS['ros'].default_url}). --backend luxai: its service hub, tcp://ROBOT:50500 "
                          f"(default {BACKENDS['luxai'].default_url}), or an MQTT broker, mqtt://BROKER:1883 (also "
                          "mqtts://, wss://), with --robot-id")
    robot_id: Annotated[str | None, Cli("luxai", metavar="QTRD000320")] = Field(
        None, description="the QTrobot v3's id, for --backend luxai through an MQTT broker")
    mqtt_ca_file: Annotated[Path | None, Cli("luxai", metavar="CA.pem")] = Field(
        None, description="through a TLS broker (mqtts://, wss://): the CA certificate to trust (default: the "
                          "system's)")
    mqtt_username: Annotated[str | None, Cli("luxai", metavar="NAME")] = Field(
        None, description="through a broker that wants a login; the password is read from $VR_TELEOP_MQTT_PASSWORD "
                          "(never from the command line, where other users could read it)")
    mqtt_password: Annotated[str | None, Cli("luxai", flag="", env="VR_TELEOP_MQTT_PASSWORD")] = Field(
        None, description="the broker login's password")
    camera_url: Annotated[str | None, Cli("luxai", metavar="tcp://ROBOT:50655")] = Field(
        None, description="the QTrobot v3's realsense-driver plugin over ZeroMQ (default: the robot's host, port "
                          "50655); through MQTT it is found under its node id qtrobot-realsense-driver")
    camera_width: int = Field(640, ge=16, le=4096)  # `serve --camera-size WxH`
    camera_height: int = Field(480, ge=16, le=4096)
    camera_fps: Annotated[float, Cli("robot")] = Field(
        30.0, gt=0, le=120, description="head-camera frames a second while someone watches")
    gesture_dir: Annotated[Path | None, Cli("files")] = Field(
        None, description="directory for recorded gestures and extra LuxAI gesture files")
    menu_dir: Annotated[Path | None, Cli("files", metavar="DIR")] = Field(
        None, description="radial menu files (*.yaml) to use instead of the packaged ones (see menus/data)")
    audio_dir: Annotated[Path | None, Cli("files", metavar="DIR")] = Field(
        None, description="where the operator's voice is logged, one WAV per client (default: a temporary "
                          "directory)")
    clips: Annotated[Path | None, Cli("files", metavar="DIR")] = Field(
        None, description="the voices from home: a directory of recorded clips (WAV, Ogg or MP3, at most 60 s) the "
                          "robot plays from the speech menu and the dashboard, where a supervisor adds them; none: "
                          "no clips are kept")
    motivation_config: Annotated[Path | None, Cli("files", metavar="FILE")] = Field(
        None, description="motivation variables: limits and dynamics (default: the packaged motivation.yaml)")
    teacher_name: Annotated[str, Cli("server", metavar="NAME")] = Field(
        "", max_length=100, description="the teacher's name, which {teacher} in the speech menu's sentences says "
                                        "(a sentence with {teacher} is refused while it is empty)")
    bystander_interval: Annotated[float, Cli("sim", metavar="S")] = Field(
        20.0, ge=0, description="the stand-in's simulated pupils take turns saying a line every S seconds, heard in "
                                "the robot's microphone and reported as voice activity; 0: never")
    perception: Annotated[Literal["rendered", "modelled"], Cli("sim")] = Field(
        "rendered", description="where the stand-in's face boxes (/perception/faces) come from: 'rendered', its head "
                                "camera's frames searched by the face detector (about 0.4 CPU s a frame); "
                                "'modelled', each pupil's head projected from the scene and found with the recall "
                                "the detector measured (bench/faces.py --calibrate), no frame drawn: for studies")
    perception_seed: int = Field(0, description="the seed of modelled perception's draws (a study run's seed)")
    autonomy: Annotated[AutonomyLevel, Cli("autonomy")] = Field(
        AutonomyLevel.SUPERVISED,
        description="the robot's autonomy level at start (changed live with /vr_teleop/autonomy/level): "
                    "'teleoperated', nothing moves unless someone moves it; 'supervised', the robot looks at who "
                    "speaks and proposes actions the teacher accepts, rejects or lets time out (then done); "
                    "'autonomous', it does what it proposes")
    autonomy_rules: Annotated[Path | None, Cli("autonomy", metavar="FILE")] = Field(
        None, description="the proposal rules (YAML: situations to menu items); default: the packaged rules")
    autonomy_memory: Annotated[Path | None, Cli("autonomy", metavar="PATH")] = Field(
        None, description="the JSON file where autonomy keeps what it learned from the teacher (loaded at start, "
                          "written on each decision); default: nothing kept between runs")
    autonomy_attention: Annotated[Path | None, Cli("autonomy", metavar="FILE")] = Field(
        None, description="the attention configuration (YAML: focus times, switching, speed); default: the packaged "
                          "one")
    turn_urls: Annotated[tuple[str, ...], Cli("media", metavar="URL", flag="--turn-url")] = Field(
        (), description="a TURN relay for WebRTC media (repeatable): turn:HOST:3478?transport=udp, "
                        "turn:HOST:3478?transport=tcp, turns:HOST:443?transport=tcp. Clients get them with fresh "
                        "credentials from /vr_teleop/media/ice_servers; the server's own peer uses the first one "
                        "(put first the one the server can reach: turns:...:443 behind a firewall that blocks UDP)")
    turn_secret: Annotated[SecretStr | None, Cli("media", metavar="SECRET", env="VR_TELEOP_TURN_SECRET")] = Field(
        None, description="the relay's shared secret (coturn: use-auth-secret, static-auth-secret=SECRET), or "
                          "$VR_TELEOP_TURN_SECRET; TURN credentials are made from it, valid for --turn-ttl")
    turn_ttl: Annotated[float, Cli("media", metavar="S")] = Field(
        DEFAULT_TTL_S, gt=0, description="seconds a TURN credential stays valid")
    ice_servers: Annotated[tuple[str, ...], Cli("media", metavar="URL", flag="--ice-server")] = Field(
        (), description="a STUN server for WebRTC media, e.g. stun:stun.example.org:3478 (repeatable; default "
                        "none: host candidates, enough on a LAN)")
    record: Annotated[Path | None, Cli("recording", metavar="FILE.mcap")] = Field(
        None, description="record every message of the session, both ways, per client, to an MCAP file")
    record_camera_fps: Annotated[float, Cli("recording", metavar="FPS")] = Field(
        2.0, ge=0, le=120, description="camera frames a second kept in the recording; 0 keeps none")
    study: Annotated[Path | None, Cli("study", metavar="FILE")] = Field(
        None, description="host a live study with people (a study file with a consent_form): participants, "
                          "their trials on this robot and their questionnaires, through the /study/* services; "
                          "needs --study-dir")
    study_dir: Annotated[Path | None, Cli("study", metavar="DIR")] = Field(
        None, description="the live study's folder, its whole state (participants, event log, recordings, "
                          "answers): a restart with the same folder carries on")
    operator_token: Annotated[str | None, Cli("access")] = Field(
        None, description="token of the operator role (or $VR_TELEOP_OPERATOR_TOKEN)")
    supervisor_token: Annotated[str | None, Cli("access")] = Field(
        None, description="token of the supervisor role (or $VR_TELEOP_SUPERVISOR_TOKEN)")
    spectator_token: Annotated[str | None, Cli("access")] = Field(
        None, description="token of the read-only spectator role (or $VR_TELEOP_SPECTATOR_TOKEN)")
    blur_faces: Annotated[bool, Cli("access")] = Field(
        False, description="blur every face the detector finds in the recordings and in the camera the spectators "
                           "see (topic and WebRTC video); the operator and the supervisor see it as it is")
    insecure: Annotated[bool, Cli("access")] = Field(
        False, description="allow open access (no tokens) on a non-loopback address")
    teleop: TeleopSettings = Field(default_factory=TeleopSettings, description="explicit control (teleop/settings.py)")

    @field_validator("ice_servers", "turn_urls")
    @classmethod
    def _urls(cls, urls: tuple[str, ...]) -> tuple[str, ...]:
        return tuple(check_url(u) for u in urls)

    @field_validator("perception")
    @classmethod
    def _modelled_on_sim(cls, perception: str, info: ValidationInfo) -> str:
        if perception == "modelled" and info.data.get("backend") != "sim":
            raise ValueError("perception 'modelled' models the stand-in's scene: it needs --backend sim")
        return perception

    @field_validator("blur_faces")
    @classmethod
    def _blur_needs_frames(cls, blur: bool, info: ValidationInfo) -> bool:
        if blur and info.data.get("perception") == "modelled":
            raise ValueError("--blur-faces blurs the boxes found in the camera's own frames: it needs --perception "
                             "rendered")
        return blur

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
        """robot_url, or the backend's default (robot/backends' table; empty for a backend without a robot URL)."""
        return self.robot_url or BACKENDS[self.backend].default_url or ""
