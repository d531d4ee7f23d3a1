"""The composition root: builds the server's parts from one settings object and starts and stops them."""

from __future__ import annotations

import asyncio
import functools
import json
import logging
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from client_protocol import names
from client_protocol.registry import TypeRegistry
from menus import load_menus
from robot_models import load_qtrobot
from simclock import WALL, Clock

from .core.access import AccessPolicy, Role, is_loopback, tokens_from
from .core.bus import Bus
from .core.events import declare_event_topic, publish_event
from .core.rosapi import RosApi
from .core.ownership import Ownership
from .features.autonomy import Autonomy, Learner, check_actions, load_config as load_attention_config, load_rules
from .features.avatar import Avatar
from .features.whoami import WhoAmI
from .core.session import Session
from .core.transport import Ping, WebSocketTransport
from .features import Feature
from .features.explicit_control import ExplicitControl
from .features.face_blur import FaceBlur
from .features.faces import FacePublisher, Perception, RenderedFaces
from .features.luxai_api import LuxaiApi
from .features.menu_service import MenuService
from .features.motivation import Motivation
from .features.motivation import load_config as load_motivation_config
from .features.clips import ClipLibrary
from .features.speech import OperatorVoiceIn, Speaker, default_audio_dir
from .features.status import StatusPublisher
from .media import MediaService
from .recording.recorder import Recorder
from .robot.gestures import GestureLibrary, default_user_gesture_dir, packaged_gesture_dir
from .robot.backends import BACKENDS
from .robot.interface import Robot
from .robot.world import SimulatedWorld
from .settings import ServerSettings

if TYPE_CHECKING:
    from .study.kind import ServerParts
    from .study.live import LiveStudy

log = logging.getLogger(__name__)


class TeleopServer:
    """`clock`: the server's one clock (simclock). A simulated clock needs the stand-in backend and must be the
    running loop's (simclock.run), which then also times every sleep and timeout of the server."""

    def __init__(self, settings: ServerSettings, clock: Clock = WALL) -> None:
        if clock.simulated and settings.backend != "sim":
            raise ValueError(f"a simulated clock needs the stand-in (backend 'sim'), not {settings.backend!r}: a real "
                             "robot moves in real time")
        self.settings = settings
        self.clock = clock
        self.registry = TypeRegistry(time_style=settings.time_style, clock=clock)
        self.bus = Bus(self.registry, reporter=self._report)
        self.model = load_qtrobot()
        self.sessions: dict[str, Session] = {}
        self.features: list[Feature] = []  # in the order started; stopped in reverse
        self.robot: Robot | None = None
        self.luxai: LuxaiApi | None = None  # the parts tests and tools reach into
        self.control: ExplicitControl | None = None
        self.recorder: Recorder | None = None
        self.rosapi: RosApi | None = None
        self.media: MediaService | None = None
        self.autonomy: Autonomy | None = None
        self.bystanders: Any = None  # the stand-in's simulated pupils (features/bystanders.py), backend sim only
        # Data files are checked before anything starts, so that a bad one stops `serve` with its name.
        tokens = tokens_from({"operator": settings.operator_token, "supervisor": settings.supervisor_token,
                              "spectator": settings.spectator_token})
        self.study_file = None
        if (settings.study is None) != (settings.study_dir is None):
            raise ValueError("--study FILE and --study-dir DIR go together: the study file says what to run, the "
                             "folder keeps its state")
        if settings.study is not None and BACKENDS[settings.backend].factory is None:
            raise ValueError(f"--study runs its trials on a robot: give --backend sim, ros or luxai, not "
                             f"{settings.backend!r}")
        if settings.study is not None:  # the study tools' libraries (scipy) only when a study is hosted
            from .study.kinds import load_study
            self.study_file = load_study(settings.study)
            if self.study_file.consent_form is None:
                raise ValueError(f"{settings.study}: the study file declares no consent_form (the version of the "
                                 "consent form participants sign); a study with people needs one")
        self.live_study: LiveStudy | None = None
        self.access = AccessPolicy(tokens, participants=self._participant_of,
                                   blurred_views={names.CAMERA_TOPIC: names.CAMERA_BLURRED_TOPIC}
                                   if settings.blur_faces else {})
        self.faces: FacePublisher | None = None  # /perception/faces, once the robot is open
        self.face_blur: FaceBlur | None = None  # serve --blur-faces, on a robot
        if self.access.open and not is_loopback(settings.host) and not settings.insecure:
            raise ValueError(f"refusing to serve {settings.host} without tokens: anyone on the network could drive "
                             "the robot. Give --operator-token/--supervisor-token (or --generate-tokens), or pass "
                             "--insecure")
        self.menus = load_menus(settings.menu_dir)
        self.motivation_config = load_motivation_config(settings.motivation_config)
        self.autonomy_rules = load_rules(settings.autonomy_rules)
        self.attention_config = load_attention_config(settings.autonomy_attention)
        # who moves each part (design.md, "Who moves the robot")
        self.owners = Ownership(self.model.parts, client_grace_s=self.attention_config.client_grace_s)
        self.learner = Learner(settings.autonomy_memory)
        self.transport = WebSocketTransport(settings, self._open_session, self._close_session, self.access)

    def _open_session(self, name: str, peer: str, ping: Ping) -> Session:
        recorder = self.recorder
        session = Session(name, self.bus, self.settings, peer, policy=self.access, ping=ping,
                          tap=recorder.on_frame if recorder is not None else None)
        self.sessions[name] = session
        if recorder is not None:
            recorder.on_connection(name, "connect", peer)
        return session

    def _close_session(self, session: Session) -> None:
        session.close()
        self.sessions.pop(session.name, None)
        if self.recorder is not None:
            self.recorder.on_connection(session.name, "disconnect", session.peer)

    def _participant_of(self, token: str) -> str | None:
        """A live study's participant page's token: whose it is."""
        return self.live_study.folder.participant_for_token(token) if self.live_study is not None else None

    def _who(self, owner: str) -> str:
        """Who called, for the study's event log: `supervisor:KEY`, or a participant's `participant:P03`."""
        session = self.sessions.get(owner)
        if session is None:
            return owner
        if session.role == "participant":
            return session.operator
        return f"{session.role or ('supervisor' if self.access.open else 'anonymous')}:{session.operator}"

    def _role(self, owner: str) -> Role | None:
        session = self.sessions.get(owner)
        return session.role if session is not None else None

    def _operator(self, owner: str) -> str:
        session = self.sessions.get(owner)
        return session.operator if session is not None else owner

    def _identity(self, owner: str) -> dict[str, Any]:
        session = self.sessions.get(owner)
        role = (session.role if session is not None else None) or ("supervisor" if self.access.open else "")
        operator = self._operator(owner) if role in ("operator", "supervisor") else ""
        holder = self.control.holder if self.control is not None else None
        return {"connection": owner, "role": role, "operator": operator,
                "holding": bool(operator) and holder == operator}

    def _holds_control(self, owner: str) -> bool:
        """Whether this connection's operator holds explicit control (the poses data channel's rule)."""
        return self.control is not None and self.control.holds(owner)

    def _audience(self) -> bool:
        """Whether someone who may decide a proposal (an operator or a supervisor) is watching the proposals: a
        client subscribed to them or to the autonomy state (the operator page's HUD, the dashboard). A client that
        only uses LuxAI's API is no audience, however open the access."""
        for topic_name in (names.AUTONOMY_PROPOSALS_TOPIC, names.AUTONOMY_STATE_TOPIC):
            topic = self.bus.topics.get(topic_name)
            for owner, _callback in topic.subscribers.values() if topic is not None else ():
                session = self.sessions.get(owner)
                if session is not None and not session.closed and (
                        session.role in ("operator", "supervisor") or (session.role is None and self.access.open)):
                    return True
        return False

    def _operator_online(self, operator: str, gone: str) -> bool:
        return any(name != gone and not session.closed and session.operator == operator
                   for name, session in self.sessions.items())

    def _publish_description(self) -> None:
        """The robot's joints and limits, latched, so that clients (the dashboard's gauges) hard-code none."""
        self.bus.declare_topic(names.DESCRIPTION_TOPIC, "std_msgs/String", state=True, persistent=True)
        joints = [{"name": n, "part": part, "lower": self.model.joint(n).lower, "upper": self.model.joint(n).upper,
                   "home": self.model.joint(n).home, "max_velocity": self.model.joint(n).max_velocity}
                  for part, joint_names in self.model.parts.items() for n in joint_names]
        description: dict[str, Any] = {"robot": "QTrobot", "joints": joints}
        info = self.robot.info if self.robot is not None else {}  # what a real robot's backend knows of it
        if info:
            description["backend"] = info
        self.bus.publish(names.DESCRIPTION_TOPIC, {"data": json.dumps(description)}, latch=True)

    def _report(self, owner: str, level: str, text: str) -> None:
        session = self.sessions.get(owner)
        if session is not None:
            session.status(level, text)
        else:
            log.log(logging.ERROR if level == "error" else logging.WARNING, "%s: %s", owner, text)

    def _start(self, feature: Feature) -> None:
        feature.start()
        self.features.append(feature)

    async def _start_robot(self) -> None:
        """The robot and the features on it."""
        s = self.settings
        backend = BACKENDS[s.backend]
        if backend.factory is None:
            return
        # Built off the loop (the stand-in starts MuJoCo; a real robot's backend does no I/O until open()), wired,
        # then opened, so that what opening finds (camera_unavailable) reaches the event topic.
        robot = await asyncio.to_thread(backend.load().from_settings, s, self.model, self.clock)
        self.robot = robot
        declare_event_topic(self.bus)
        robot.on_event(functools.partial(publish_event, self.bus, "backend"))
        await robot.open()
        self.model = robot.model  # a robot's own limits may narrow the model's: everything uses those in force
        gestures = GestureLibrary([packaged_gesture_dir()], self.model,
                                  user_dir=s.gesture_dir or default_user_gesture_dir())
        audio_dir = s.audio_dir or default_audio_dir()
        speaker = Speaker(self.bus, robot, audio_dir)
        self._start(speaker)
        self.luxai = LuxaiApi(self.bus, robot, gestures, speaker, clock=self.clock, owners=self.owners)
        self._start(self.luxai)
        self.control = ExplicitControl(
            self.bus, robot, s.teleop, may_override=lambda caller: self.access.may_override_control(self._role(caller)),
            operator_of=self._operator, operator_online=self._operator_online, clock=self.clock,
            owners=self.owners)
        self._start(self.control)
        voice = OperatorVoiceIn(self.bus, robot, audio_dir, owners=self.owners)
        self._start(voice)
        clips = ClipLibrary(self.bus, speaker, s.clips, voice, owners=self.owners)
        self._start(clips)
        status = StatusPublisher(self.bus, robot)
        self._start(status)
        motivation = Motivation(self.bus, self.motivation_config)
        self._start(motivation)
        perception: Perception
        if s.perception == "modelled":  # the stand-in's faces from its scene (the settings allow it on sim only)
            from .features.modelled_faces import ModelledFaces

            perception = ModelledFaces(robot.standin, self.clock, rate_hz=min(s.camera_fps, 5.0),
                                       seed=s.perception_seed)
        else:
            perception = RenderedFaces(robot)
        self.faces = FacePublisher(self.bus, perception)
        self._start(self.faces)
        if s.blur_faces:
            self.face_blur = FaceBlur(self.bus, robot, clock=self.clock)
            self._start(self.face_blur)
            if self.recorder is not None:
                self.recorder.blur = self.face_blur
        panels = {"hardware": status.hardware, "motors": status.motors, "dialog": status.dialog,
                  "motivation": motivation.message}
        menu = MenuService(self.bus, self.menus, gestures=self.luxai.gesture_names, emotions=self.model.emotions,
                           status=lambda which: panels[which](), luxai=self.luxai, language=lambda: speaker.language,
                           clips=clips.names,
                           unavailable=lambda: set() if clips.directory is not None else {"record_clip"},
                           variables=lambda: {"pupil": self.autonomy.attended_pupil() if self.autonomy else "",
                                              "teacher": s.teacher_name})
        speaker.language_checks.append(menu.check_language)  # a missing sentence list refuses the switch
        speaker.language_changed.append(menu.publish)
        clips.changed.append(menu.publish)
        self._start(menu)
        check_actions(self.autonomy_rules, menu.ids(), s.autonomy_rules)
        if isinstance(robot, SimulatedWorld):  # the stand-in's simulated pupils (simulation only)
            from .features.bystanders import Bystanders

            async def render(text: str) -> tuple[bytes, int, int]:
                wav = await speaker.tts.render(text)
                return wav.pcm, wav.sample_rate, wav.channels

            self.bystanders = Bystanders(self.bus, robot, render, clock=self.clock, interval=s.bystander_interval)
            self._start(self.bystanders)
        self.autonomy = Autonomy(self.bus, robot, self.owners, level=s.autonomy, attention=self.attention_config,
                                 rules=self.autonomy_rules, learner=self.learner, menu_entry=menu.entry,
                                 may_decide=self._audience, operator_of=self._operator, clock=self.clock)
        self.autonomy.pupil_changed.append(menu.publish)  # the sentences' labels name the pupil attended to
        self._start(self.autonomy)

    async def start(self) -> None:
        await self.transport.bind()  # a busy port fails here, before the robot and the features start
        try:
            if self.settings.record is not None:
                self.recorder = Recorder(self.settings.record, self.registry, self.settings.record_camera_fps,
                                         bus=self.bus, clock=self.clock)
                self._start(self.recorder)
                log.info("recording to %s", self.settings.record)
            self.rosapi = RosApi(self.bus)
            self._start(self.rosapi)
            self._start(WhoAmI(self.bus, self._identity))
            # the experimenter's labels
            self.bus.declare_topic(names.STUDY_LABELS_TOPIC, "vr_teleop_msgs/Event", persistent=True)
            await self._start_robot()
            self._start_media()
            if self.study_file is not None:
                self._start_study()
            self._publish_description()  # after the robot: its own limits may have narrowed the model's
            self._start(Avatar(self.bus, self.rosapi, self.robot))
            await self.transport.start()
        except BaseException:
            await self.transport.stop()
            await self._stop_parts()
            raise

    async def stop(self) -> None:
        await self.transport.stop()
        for session in list(self.sessions.values()):
            self._close_session(session)
        await self._stop_parts()

    async def _stop_parts(self) -> None:
        """Every started feature in reverse order (the recorder, started first, goes last), then the robot."""
        while self.features:
            await self.features.pop().stop()
        if self.robot is not None:
            await self.robot.aclose()
        self.recorder = None

    def study_parts(self) -> ServerParts:
        """What a trial of any kind needs of this server to run on it (study/kind.py)."""
        from .study.kind import ServerParts

        assert self.robot is not None
        autonomy = self.autonomy
        return ServerParts(self.bus, self.robot, self.registry, self.owners,
                           self.luxai.gestures if self.luxai is not None else None,
                           (lambda level: autonomy.set_level(level, "study")) if autonomy is not None else None,
                           autonomy_level=lambda: autonomy.level if autonomy is not None else None,
                           camera_fps=self.settings.record_camera_fps, clock=self.clock, blur=self.face_blur)

    def _start_study(self) -> None:
        """`serve --study FILE --study-dir DIR`: the folder opened (a trial a crash cut marked interrupted)."""
        from .study.folder import StudyFolder
        from .study.kinds import kind_of
        from .study.live import LiveStudy, TrialHost
        from .study.protocol import plan_of

        s, study = self.settings, self.study_file
        assert s.study_dir is not None and self.robot is not None
        clock = self.clock  # the log's times on the server's clock: a pilot at --speed max logs simulated times
        folder = StudyFolder.open(s.study_dir, plan_of(study), who="server",
                                  clock=lambda: datetime.fromtimestamp(clock.time(), UTC))
        self.live_study = LiveStudy(self.bus, folder, TrialHost(study, kind_of(study), self.study_parts()),
                                    self._who)
        self._start(self.live_study)
        log.info("hosting the live study %s in %s", folder.plan.study, s.study_dir)

    def _start_media(self) -> None:
        """WebRTC (media/): the camera as video, the robot's audio out, the operator's voice in, telemetry."""
        # (the stand-in's pupils speak into its microphone, which the media mixes as a real robot's: Bystanders)
        self.media = MediaService(self.bus, self.robot, self.access, lambda: self.sessions,
                                  camera_fps=self.settings.camera_fps,
                                  ice=self.settings.ice_config(), holds_control=self._holds_control,
                                  control=lambda connection: self.control.link_view(connection)
                                  if self.control is not None else None, clock=self.clock, blur=self.face_blur)
        self._start(self.media)

    @property
    def url(self) -> str:
        scheme = "wss" if self.settings.certfile else "ws"
        return f"{scheme}://{self.settings.host}:{self.transport.port}"

    async def __aenter__(self) -> "TeleopServer":
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()
