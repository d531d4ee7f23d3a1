"""The composition root: builds the server's parts from one settings object and starts and stops them."""

from __future__ import annotations

import json
import logging

from client_protocol.registry import TypeRegistry
from menus import load_menus
from robot_models import load_qtrobot

from .access import AccessPolicy, Role, is_loopback, tokens_from
from .bus import Bus
from .explicit_control import ExplicitControl, publish_event
from .gestures import GestureLibrary, default_user_gesture_dir, packaged_gesture_dir
from .luxai_api import LuxaiApi
from .media import MediaService
from .menu_service import MenuService, check_commands_implemented
from .motivation import Motivation
from .motivation import load_config as load_motivation_config
from .recording import Recorder
from .robot import Robot
from .rosapi import RosApi
from .session import Session
from .settings import ServerSettings
from .speech import OperatorAudioLog, Speaker, default_audio_dir
from .status import StatusPublisher
from .study.perception.faces import FacePublisher
from .transport import WebSocketTransport

log = logging.getLogger(__name__)
DESCRIPTION_TOPIC = "/vr_teleop/robot_description"
LABELS_TOPIC = "/study/labels"


class TeleopServer:
    def __init__(self, settings: ServerSettings) -> None:
        self.settings = settings
        self.registry = TypeRegistry(time_style=settings.time_style)
        self.bus = Bus(self.registry)
        self.bus.reporter = self._report
        self.model = load_qtrobot()
        self.sessions: dict[str, Session] = {}
        self.rosapi = RosApi(self.bus)
        self.robot: Robot | None = None
        self.luxai: LuxaiApi | None = None
        self.control: ExplicitControl | None = None
        self.speaker: Speaker | None = None
        self.operator_audio: OperatorAudioLog | None = None
        self.status: StatusPublisher | None = None
        self.motivation: Motivation | None = None
        self.faces: FacePublisher | None = None
        self.menu: MenuService | None = None
        self.recorder: Recorder | None = None
        self.media: MediaService | None = None
        # Data files are checked before anything starts, so that a bad one stops `serve` with its name.
        tokens = tokens_from({"operator": settings.operator_token, "supervisor": settings.supervisor_token,
                              "spectator": settings.spectator_token})
        self.access = AccessPolicy(tokens)
        if self.access.open and not is_loopback(settings.host) and not settings.insecure:
            raise ValueError(f"refusing to serve {settings.host} without tokens: anyone on the network could drive "
                             "the robot. Give --operator-token/--supervisor-token (or --generate-tokens), or pass "
                             "--insecure")
        check_commands_implemented()
        self.menus = load_menus(settings.menu_dir)
        self.motivation_config = load_motivation_config(settings.motivation_config)
        self.transport = WebSocketTransport(settings, self._open_session, self._close_session)

    def _open_session(self, name: str, peer: str) -> Session:
        session = Session(name, self.bus, self.settings, peer)
        session.policy = self.access
        self.sessions[name] = session
        if self.recorder is not None:
            session.tap = self.recorder.on_frame
            self.recorder.on_connection(name, "connect", peer)
        return session

    def _close_session(self, session: Session) -> None:
        session.close()
        self.sessions.pop(session.name, None)
        if self.recorder is not None:
            self.recorder.on_connection(session.name, "disconnect", session.peer)

    def _role(self, owner: str) -> Role | None:
        session = self.sessions.get(owner)
        return session.role if session is not None else None

    def _publish_description(self) -> None:
        """The robot's joints and limits, latched, so that clients (the dashboard's gauges) hard-code none."""
        self.bus.declare_topic(DESCRIPTION_TOPIC, "std_msgs/String", latched=True, persistent=True)
        joints = [{"name": n, "part": part, "lower": self.model.joint(n).lower, "upper": self.model.joint(n).upper,
                   "home": self.model.joint(n).home, "max_velocity": self.model.joint(n).max_velocity}
                  for part, names in self.model.parts.items() for n in names]
        self.bus.publish(DESCRIPTION_TOPIC, {"data": json.dumps({"robot": "QTrobot", "joints": joints})}, latch=True)

    def _report(self, owner: str, level: str, text: str) -> None:
        session = self.sessions.get(owner)
        if session is not None:
            session.status(level, text)
        else:
            log.log(logging.ERROR if level == "error" else logging.WARNING, "%s: %s", owner, text)

    async def _start_robot(self) -> None:
        s = self.settings
        if s.backend == "none":
            return
        if s.backend == "ros":
            from .backends.ros import RosRobot

            self.robot = robot = await RosRobot.create(s.robot_url, self.model)
            robot.connection_changed.append(lambda up: publish_event(
                self.bus, "backend", "reconnected" if up else "disconnected", "info" if up else "danger",
                {"robot_url": s.robot_url}))
        else:
            from .backends.sim import SimRobot  # MuJoCo and EGL load only when the stand-in is wanted

            self.robot = await SimRobot.create(self.model, camera_width=s.camera_width,
                                               camera_height=s.camera_height, camera_fps=s.camera_fps)
        gestures = GestureLibrary([packaged_gesture_dir()], self.model,
                                  user_dir=s.gesture_dir or default_user_gesture_dir())
        audio_dir = s.audio_dir or default_audio_dir()
        self.speaker = Speaker(self.bus, self.robot, audio_dir)
        self.luxai = LuxaiApi(self.bus, self.robot, gestures, self.speaker)
        self.luxai.start()
        self.control = ExplicitControl(self.bus, self.robot, s.teleop)
        self.control.may_override = lambda caller: self.access.may_override_control(self._role(caller))
        self.control.start()
        self.operator_audio = OperatorAudioLog(self.bus, audio_dir)
        self.operator_audio.start()
        self.status = StatusPublisher(self.bus, self.robot)
        self.status.start()
        self.motivation = Motivation(self.bus, self.motivation_config)
        self.motivation.start()
        self.faces = FacePublisher(self.bus, self.robot)
        self.faces.start()
        panels = {"hardware": self.status.hardware, "motors": self.status.motors, "dialog": self.status.dialog,
                  "motivation": self.motivation.message}
        self.menu = MenuService(self.bus, self.menus, gestures=gestures.names, emotions=self.model.emotions,
                                status=lambda which: panels[which](), recorder=self.luxai)
        self.luxai.gestures_changed.append(self.menu.publish)
        self.menu.start()

    async def start(self) -> None:
        if self.settings.record is not None:
            self.recorder = Recorder(self.settings.record, self.registry, self.settings.record_camera_fps)
            self.recorder.attach(self.bus)
            log.info("recording to %s", self.settings.record)
        self.rosapi.start()
        self._publish_description()
        self.bus.declare_topic(LABELS_TOPIC, "vr_teleop_msgs/Event", persistent=True)  # the experimenter's labels
        await self._start_robot()
        self._start_media()
        try:
            await self.transport.start()
        except BaseException:
            if self.media is not None:
                await self.media.stop()
            await self._stop_robot()
            raise

    async def stop(self) -> None:
        await self.transport.stop()
        for session in list(self.sessions.values()):
            self._close_session(session)
        if self.media is not None:
            await self.media.stop()
            self.media = None
        await self._stop_robot()
        if self.recorder is not None:
            await self.recorder.close(self.bus)
            self.recorder = None

    def _start_media(self) -> None:
        """WebRTC (media/): the camera as video, the robot's audio out, the operator's voice in, telemetry."""
        speaker = self.speaker
        render_line = None
        if speaker is not None and self.settings.backend == "sim":  # the stand-in's classroom has bystanders
            async def render_line(text: str) -> tuple[bytes, int, int]:
                wav = await speaker.tts.render(text)
                return wav.pcm, wav.sample_rate, wav.channels
        self.media = MediaService(self.bus, self.robot, self.access, lambda: self.sessions,
                                  camera_fps=self.settings.camera_fps, render_line=render_line,
                                  bystander_interval=self.settings.bystander_interval,
                                  ice_servers=list(self.settings.ice_servers))
        self.media.start()

    async def _stop_robot(self) -> None:
        for part in (self.faces, self.motivation, self.status, self.control):
            if part is not None:
                await part.stop()
        if self.operator_audio is not None:
            self.operator_audio.close()
        if self.speaker is not None:
            self.speaker.close()
        if self.luxai is not None:
            await self.luxai.stop()
        if self.robot is not None:
            await self.robot.aclose()

    @property
    def url(self) -> str:
        scheme = "wss" if self.settings.certfile else "ws"
        return f"{scheme}://{self.settings.host}:{self.transport.port}"

    async def __aenter__(self) -> "TeleopServer":
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()
