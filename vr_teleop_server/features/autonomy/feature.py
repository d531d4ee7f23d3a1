"""Supervised autonomy on the bus: the level, attention, proposals and their outcomes (docs/guides/autonomy.md).

It acts as a client would: head commands on the head command topic (the Robot interface clamps them), actions as
menu items through the menu service. Before each head command it asks the ownership arbiter (core/ownership.py):
autonomy moves only a part nobody claims, and only once it has been free for the release grace. An action waits
until the part it uses is free: a sentence never starts over someone else's, an emotion never over theirs.
Proposals go only to an audience (`may_decide`: someone who may decide is watching them), one at a time, each
shown at least MIN_SHOWN_S before a newer one replaces it. Everything runs on the server's clock: attention at
its rate (the control tick), each proposal's time-out on a timer of its own.
"""

from __future__ import annotations

import asyncio
import itertools
import json
import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from client_protocol import names
from client_protocol.events import ActionFailed, AutonomyLevelChanged, EventKind, EventLevel
from client_protocol.vocabulary import AutonomyLevel, Decider, Decision, Initiator, Outcome, Owner, Part
from menus import Command, MenuEntry
from simclock import WALL, Clock

from ...core.bus import Bus, BusError, Published
from ...core.events import declare_event_topic, publish_event
from ...core.ownership import Ownership
from ...core.tasks import cancel_and_wait, every
from ...robot.interface import Robot, VoiceActivity
from .attention import Attention, AttentionConfig, Candidate, Target
from .learner import Learner, Situation
from .rules import Rules

log = logging.getLogger(__name__)

AUTONOMY_NODE = "/vr_teleop_server/autonomy"  # the caller and sender name of what autonomy does
ACTION_COMMANDS = (Command.SHOW_EMOTION, Command.SAY, Command.PLAY_GESTURE)  # menu commands that are actions the teacher takes
FACE_FRESH_S = 1.5  # a face track seen this recently is a candidate (detection: 5 Hz at best, 1 Hz on a busy machine)
HEAD_HISTORY_S = 3.0  # the head's recent directions, to place a face found in an older frame
FACE_FORGET_S = 30.0
NEW_FACE_CONFIRM_S = 1.0  # a face must stay this long before it is "new" (the detector flickers)
SITUATION_WINDOW_S = 10.0  # an event stays the situation this long (the teacher's own actions are learned in it)
ATTENTION_REPUBLISH_S = 1.0
EXECUTE_TIMEOUT_S = 60.0
MIN_SHOWN_S = 1.0  # a proposal is not replaced sooner: a teacher in a headset must be able to read it
NAME_MAX = 40  # characters of a person's name (the HUD's line has room for little more)
BUSY_WAIT_S = 30.0  # an accepted action waits this long at most for its part (someone else's speech) to be free
ACTION_PARTS = {Command.SAY: (Part.VOICE,), Command.SHOW_EMOTION: (Part.FACE,)}  # play_gesture: the robot's parts


@dataclass
class FaceTrack:
    key: str
    yaw: float
    pitch: float
    distance: float
    box: dict[str, Any]
    first_seen: float
    last_seen: float
    frame_seq: int = 0  # the camera frame (header.seq) the box was found in
    announced: bool = False  # new_face fired
    away_fired: bool = False


@dataclass
class Voice:
    who: str
    direction: float | None
    since: float


@dataclass
class Proposal:
    id: str
    action: str
    label: str
    reason: str
    confidence: float
    timeout: float
    on_timeout: str
    situation: Situation
    created: float
    stamp: Any = None
    timer: asyncio.TimerHandle | None = None
    waiting: bool = False  # its time-out came while its part was someone else's: done once the part is free

    def message(self, now: float) -> dict[str, Any]:
        left = 0.0 if self.waiting else max(0.0, self.timeout - (now - self.created))
        return {"header": {"stamp": self.stamp}, "id": self.id, "action": self.action, "label": self.label,
                "reason": self.reason, "confidence": self.confidence, "timeout": self.timeout,
                "on_timeout": self.on_timeout, "situation": self.situation.name, "left": round(left, 3)}


@dataclass
class _Published:
    summary: tuple = ()
    attention_key: tuple = ()
    attention_at: float = -math.inf


class Autonomy:
    def __init__(self, bus: Bus, robot: Robot, owners: Ownership, *, level: AutonomyLevel, attention: AttentionConfig,
                 rules: Rules, learner: Learner, menu_entry: Callable[[str], MenuEntry | None],
                 may_decide: Callable[[], bool], operator_of: Callable[[str], str], clock: Clock = WALL,
                 seed: int | None = None) -> None:
        self.bus = bus
        self.robot = robot
        self.owners = owners
        self.level = AutonomyLevel(level)
        self.cfg = attention
        self.rules = rules
        self.learner = learner
        self.menu_entry = menu_entry
        self.may_decide = may_decide
        self.operator_of = operator_of
        self.clock = clock
        model = robot.model
        yaw, pitch = model.joint("HeadYaw"), model.joint("HeadPitch")
        self.attention = Attention(attention, yaw_limits=(yaw.lower, yaw.upper),
                                   pitch_limits=(pitch.lower, pitch.upper), seed=seed)
        self.camera = model.camera
        self.target: Target | None = None
        self.pupil_changed: list[Callable[[], None]] = []  # called when attended_pupil() changes
        self._pupil = ""
        self.pending: dict[str, Proposal] = {}
        self.executing: dict[str, asyncio.Task[None]] = {}
        self.tracks: dict[str, FaceTrack] = {}
        # One name per person, the one every view shows: a track's id (the stand-in's pupils by their own names, a
        # real robot's faces face-1, face-2...) unless the teacher renamed it (/vr_teleop/people/rename).
        self.known = robot.known_people()
        self.renamed: dict[str, str] = {}
        self._head_history: deque[tuple[float, float, float]] = deque()  # (wall stamp, yaw, pitch)
        self.voice: Voice | None = None
        self._last_voice_end: float | None = None
        self._silence_fired = False
        self._situation: tuple[Situation, float] | None = None
        self._ids = itertools.count(1)
        self._track_ids = itertools.count(1)
        self._head_free_since: float | None = -math.inf  # None while claimed; free from the start
        self._driving = False  # attention moved the head since it got it
        self._sent: tuple[float, float] | None = None
        self._faces_token: int | None = None
        self._event_token: int | None = None
        self._unlisten: Callable[[], None] | None = None
        self._task: asyncio.Task[None] | None = None
        self._confirm: asyncio.TimerHandle | None = None  # a new speaker's confirmation time
        self._save: asyncio.Task[None] | None = None
        self._pub = _Published()
        self._started = 0.0
        self._queued: tuple[str, str, float, Situation] | None = None  # a newer proposal, until the shown one's 1 s
        self._queue_timer: asyncio.TimerHandle | None = None
        self._free: list[asyncio.Future[None]] = []  # actions waiting for their parts
        self.head_commands = 0  # head commands published (tests, the bench)

    # ---- lifetime -------------------------------------------------------------------------------------------
    def start(self) -> None:
        bus = self.bus
        declare_event_topic(bus)
        state = bus.declare_topic(names.AUTONOMY_STATE_TOPIC, "vr_teleop_msgs/AutonomyState", state=True,
                                  persistent=True)
        # a page that opens gets the time really left of a pending proposal, not the latched message's
        state.on_subscriber_count = lambda _count: self.pending and self._publish_state(force=True)
        bus.declare_topic(names.AUTONOMY_ATTENTION_TOPIC, "vr_teleop_msgs/AttentionTarget", state=True,
                          persistent=True)
        bus.declare_topic(names.AUTONOMY_PROPOSALS_TOPIC, "vr_teleop_msgs/Proposal", persistent=True)
        bus.declare_topic(names.AUTONOMY_OUTCOMES_TOPIC, "vr_teleop_msgs/ProposalOutcome", persistent=True)
        bus.provide(names.AUTONOMY_LEVEL_SERVICE, "vr_teleop_msgs/SetAutonomy", self._level_service)
        bus.provide(names.AUTONOMY_DECIDE_SERVICE, "vr_teleop_msgs/DecideProposal", self._decide_service)
        bus.provide(names.PEOPLE_RENAME_SERVICE, "vr_teleop_msgs/RenamePerson", self._rename_service)
        self._event_token = bus.subscribe(AUTONOMY_NODE, names.EVENT_TOPIC, None, self._on_event)
        self._unlisten = self.robot.on_voice_activity(self._on_voice)
        self.owners.changed.append(self._on_owners)
        self._started = self.clock.monotonic()
        self._watch_faces()
        self._publish_state(force=True)
        self._publish_attention(self.clock.monotonic(), force=True)
        self._task = asyncio.ensure_future(self._run())

    async def stop(self) -> None:
        for handle in [self._confirm, self._queue_timer] + [p.timer for p in self.pending.values()]:
            if handle is not None:
                handle.cancel()
        if self._on_owners in self.owners.changed:
            self.owners.changed.remove(self._on_owners)
        if self._unlisten is not None:
            self._unlisten()
        if self._event_token is not None:
            self.bus.unsubscribe(names.EVENT_TOPIC, self._event_token)
        self._watch_faces(False)
        await cancel_and_wait(self._task, *self.executing.values())
        if self._save is not None:
            await asyncio.gather(self._save, return_exceptions=True)

    def _watch_faces(self, on: bool | None = None) -> None:
        """Face detection runs (the camera renders) only while autonomy looks: not when teleoperated."""
        on = self.level != AutonomyLevel.TELEOPERATED if on is None else on
        if on and self._faces_token is None:
            self._faces_token = self.bus.subscribe(AUTONOMY_NODE, names.FACES_TOPIC, "vr_teleop_msgs/Faces",
                                                   self._on_faces)
        elif not on and self._faces_token is not None:
            self.bus.unsubscribe(names.FACES_TOPIC, self._faces_token)
            self._faces_token = None
            for key in list(self.tracks):
                self._forget(key)

    # ---- the tick -------------------------------------------------------------------------------------------
    async def _run(self) -> None:
        await every(1.0 / self.cfg.rate_hz, lambda: self.tick(self.clock.monotonic()), "autonomy tick")

    def tick(self, now: float) -> None:
        self._remember_head()
        self._expire_proposals(now)
        self._detect_events(now)
        self._attend(now)
        self._publish_state()

    # ---- perception -----------------------------------------------------------------------------------------
    def _head(self) -> tuple[float, float]:
        state = self.robot.joint_state().as_dict()
        return state["HeadYaw"], state["HeadPitch"]

    def _remember_head(self) -> None:
        state = self.robot.joint_state()
        positions = state.as_dict()
        history = self._head_history
        history.append((state.stamp_wall, positions["HeadYaw"], positions["HeadPitch"]))
        while history and history[-1][0] - history[0][0] > HEAD_HISTORY_S:
            history.popleft()

    def _head_at(self, stamp_wall: float) -> tuple[float, float]:
        """The head's direction when a camera frame was taken (the newest known, for a frame newer than that)."""
        if not self._head_history:
            return self._head()
        _, yaw, pitch = min(self._head_history, key=lambda h: abs(h[0] - stamp_wall))
        return yaw, pitch

    def _on_faces(self, published: Published) -> None:
        msg = published.data
        cam = self.camera
        if cam is None or not msg["image_width"]:
            return
        now = self.clock.monotonic()
        scale = msg["image_width"] / cam.width
        fx, fy, cx, cy = cam.fx * scale, cam.fy * scale, cam.cx * scale, cam.cy * scale
        stamp = msg["header"]["stamp"]
        head_yaw, head_pitch = self._head_at(stamp.get("secs", stamp.get("sec", 0))
                                             + stamp.get("nsecs", stamp.get("nanosec", 0)) * 1e-9)
        seen: set[str] = set()
        for face in msg["faces"]:
            u, v = face["x"] + face["width"] / 2, face["y"] + face["height"] / 2
            yaw = head_yaw + math.degrees(math.atan2(cx - u, fx))  # image right is the robot's right (yaw -)
            pitch = head_pitch + math.degrees(math.atan2(v - cy, fy))  # image down is pitch + (the head's down)
            distance = fy * self.cfg.face_height_m / max(face["height"], 1)
            box = {k: face[k] for k in ("x", "y", "width", "height", "confidence")}
            free = [t for t in self.tracks.values() if t.key not in seen]
            near = min(free, key=lambda t: abs(t.yaw - yaw), default=None)
            if near is not None and abs(near.yaw - yaw) <= self.cfg.match_deg:
                near.yaw, near.pitch, near.distance, near.box, near.last_seen = yaw, pitch, distance, box, now
                near.frame_seq = msg["frame_seq"]
                near.away_fired = False
                seen.add(near.key)
            else:
                key = self._track_id(yaw)
                self.tracks[key] = FaceTrack(key, yaw, pitch, distance, box, now, now, msg["frame_seq"])
                seen.add(key)
        for key in [k for k, t in self.tracks.items() if now - t.last_seen > FACE_FORGET_S]:
            self._forget(key)

    def _track_id(self, yaw: float) -> str:
        """A new face's id: the person the backend knows in that direction (the stand-in's pupils), so that the
        same pupil keeps their name whenever they are found again; else the next number."""
        free = [p for p in self.known if p.name not in self.tracks and abs(p.yaw_deg - yaw) <= self.cfg.match_deg]
        if free:
            return min(free, key=lambda p: abs(p.yaw_deg - yaw)).name
        return f"face-{next(self._track_ids)}"

    def _forget(self, key: str) -> None:
        """A track the robot no longer keeps, and the name it was given: a face found again is a new track (a known
        person keeps theirs: their id comes back with them)."""
        del self.tracks[key]
        if key not in {p.name for p in self.known}:
            self.renamed.pop(key, None)

    def name(self, ident: str) -> str:
        """The one name a person goes by: the teacher's, else their track id."""
        return self.renamed.get(ident, ident)

    async def _rename_service(self, request: Any) -> dict[str, Any]:
        return self.rename(request.id, request.name)

    def rename(self, ident: str, name: str) -> dict[str, Any]:
        """Names a tracked person (an empty name gives the id back); every view shows it from the next message."""
        ident, name = ident.strip(), " ".join(name.split())
        ids = set(self.tracks) | {p.name for p in self.known}
        if ident not in ids:
            tracked = ", ".join(sorted(ids)) or "nobody yet"
            return {"success": False, "message": f"no person {ident!r} is tracked; the ids are: {tracked} (the "
                                                 f"attention's id on {names.AUTONOMY_ATTENTION_TOPIC})"}
        if len(name) > NAME_MAX:
            return {"success": False, "message": f"a name is at most {NAME_MAX} characters, got {len(name)}"}
        taken = next((other for other in ids if other != ident and self.name(other) == name), None)
        if name and taken is not None:
            return {"success": False, "message": f"{name!r} is already the name of {taken}: give another"}
        if not name or name == ident:
            self.renamed.pop(ident, None)
        else:
            self.renamed[ident] = name
        now = self.clock.monotonic()
        self._publish_attention(now, force=True)
        self._publish_state(force=True)
        return {"success": True, "message": f"{ident} is {self.name(ident)}"}

    def _on_voice(self, activity: VoiceActivity) -> None:
        now = activity.stamp
        if activity.speaking:
            if self.voice is None or (activity.who and activity.who != self.voice.who):
                self.voice = Voice(activity.who, activity.direction_deg, now)
                # the speaker takes the attention when the confirmation time is up, not at the tick after it
                if self._confirm is not None:
                    self._confirm.cancel()
                delay = max(0.0, now + self.cfg.confirm_s - self.clock.monotonic()) + 1e-3
                self._confirm = asyncio.get_running_loop().call_later(
                    delay, lambda: self._attend(self.clock.monotonic()))
            else:
                self.voice.direction = activity.direction_deg
            self._silence_fired = False
            return
        voice, self.voice = self.voice, None
        self._last_voice_end = now
        if voice is not None:
            self._event(now, "speech_ended", speech_s=now - voice.since, who=self.name(voice.who))

    def _voice_track(self) -> FaceTrack | None:
        """The face the current voice comes from (nearest within match_deg), if any."""
        voice = self.voice
        if voice is None or voice.direction is None:
            return None
        now = self.clock.monotonic()
        fresh = [t for t in self.tracks.values() if now - t.last_seen <= FACE_FRESH_S]
        near = min(fresh, key=lambda t: abs(t.yaw - voice.direction), default=None)
        if near is not None and abs(near.yaw - voice.direction) <= self.cfg.match_deg:
            return near
        return None

    def candidates(self, now: float) -> list[Candidate]:
        speaker = self._voice_track()
        out = [Candidate(t.key, t.yaw, t.pitch, t.distance, 1.0,
                         self.voice.since if t is speaker and self.voice is not None else None)
               for t in self.tracks.values() if now - t.last_seen <= FACE_FRESH_S]
        voice = self.voice
        if voice is not None and voice.direction is not None and speaker is None:
            out.append(Candidate(f"voice:{voice.who}" if voice.who else "voice", voice.direction, 0.0, None, 1.0,
                                 voice.since, has_face=False))
        return out

    # ---- events and proposals -------------------------------------------------------------------------------
    def _detect_events(self, now: float) -> None:
        quiet_since = self._last_voice_end if self._last_voice_end is not None else self._started
        if self.voice is None and not self._silence_fired:
            silent = now - quiet_since
            if any(silent >= r.silence_s for r in self.rules.for_event("silence")):
                self._silence_fired = True
                self._event(now, "silence", silent_s=silent)
        head_yaw = None
        for track in self.tracks.values():
            if not track.announced and track.last_seen - track.first_seen >= NEW_FACE_CONFIRM_S:
                track.announced = True
                self._event(now, "new_face", who=self.name(track.key))
            gone = now - track.last_seen
            if track.announced and not track.away_fired and gone > FACE_FRESH_S and self.camera is not None:
                head_yaw = self._head()[0] if head_yaw is None else head_yaw
                half_fov = math.degrees(math.atan2(self.camera.width / 2, self.camera.fx))
                rules = [r for r in self.rules.for_event("looked_away") if gone >= r.away_s]
                if rules and abs(track.yaw - head_yaw) < half_fov * 0.8:
                    track.away_fired = True
                    self._event(now, "looked_away", away_s=gone, who=self.name(track.key))

    def _event(self, now: float, name: str, **detail: Any) -> None:
        situation = Situation(name)
        self._situation = (situation, now)
        if not self._proposing():
            return
        options: list[tuple[float, str, str]] = []
        for rule in self.rules.for_event(name):
            if name == "speech_ended" and detail.get("speech_s", 0.0) < rule.min_speech_s:
                continue
            if name == "silence" and detail.get("silent_s", 0.0) < rule.silence_s:
                continue
            if name == "looked_away" and detail.get("away_s", 0.0) < rule.away_s:
                continue
            if self.learner.forbidden(situation, rule.action) or self.menu_entry(rule.action) is None:
                continue
            options.append((self.learner.confidence(situation, rule.action, rule.confidence), rule.action,
                            rule.reason))
        for action, confidence in self.learner.learned(situation):
            if self.menu_entry(action) is not None:
                options.append((confidence, action, f"you did this yourself in this situation ({name})"))
        options = [o for o in options if o[0] >= 0.2]  # what the teacher keeps rejecting is no longer proposed
        if options:
            confidence, action, reason = max(options)
            self.propose(action, reason, confidence, situation, now)

    def _proposing(self) -> bool:
        if self.level == AutonomyLevel.TELEOPERATED or self.owners.stopped():
            return False
        return self.level == AutonomyLevel.AUTONOMOUS or self.may_decide()

    def propose(self, action: str, reason: str, confidence: float, situation: Situation,
                now: float) -> Proposal | None:
        """Proposes now, or, while the shown proposal is younger than MIN_SHOWN_S, once it has been shown that long
        (the newest situation waiting wins); None when it waits."""
        shown = [p for p in self.pending.values() if now - p.created < MIN_SHOWN_S]
        if shown:
            self._queued = (action, reason, confidence, situation)
            if self._queue_timer is None:
                delay = max(p.created for p in shown) + MIN_SHOWN_S - now
                self._queue_timer = asyncio.get_running_loop().call_later(delay + 1e-3, self._propose_queued)
            return None
        self._queued = None
        entry = self.menu_entry(action)
        label = entry.label if entry is not None else action
        for old in list(self.pending.values()):
            self._end(old, Outcome.SUPERSEDED, Decider.SERVER, now)
        proposal = Proposal(f"p-{next(self._ids)}", action, label, reason, round(confidence, 3),
                            self.rules.timeout_s, self.rules.on_timeout, situation, now,
                            self.bus.registry.now())
        self.bus.publish(names.AUTONOMY_PROPOSALS_TOPIC, proposal.message(now))
        if self.level == AutonomyLevel.AUTONOMOUS:
            self._end(proposal, Outcome.ACCEPTED, Decider.AUTONOMY, now, execute=True)
        else:
            self.pending[proposal.id] = proposal
            # its own timer on the server's clock (the loop's): the time-out is kept to the loop's latency
            proposal.timer = asyncio.get_running_loop().call_later(proposal.timeout, self._timed_out, proposal)
        self._publish_state()
        return proposal

    def _propose_queued(self) -> None:
        self._queue_timer = None
        queued, self._queued = self._queued, None
        if queued is not None and self._proposing():
            self.propose(*queued, self.clock.monotonic())

    def _expire_proposals(self, now: float) -> None:
        if self.level == AutonomyLevel.SUPERVISED and (self.pending or self._queued) and not self.may_decide():
            self._queued = None
            for p in list(self.pending.values()):
                self._end(p, Outcome.DROPPED, Decider.SERVER, now)

    def _timed_out(self, p: Proposal) -> None:
        if self.pending.get(p.id) is not p:
            return
        now = self.clock.monotonic()
        if p.on_timeout == "execute":
            if self._busy(p.action):  # someone else speaks (or shows, or moves): wait, never interrupt
                if not p.waiting:
                    p.waiting = True
                    self._publish_state(force=True)
                return
            self._end(p, Outcome.TIMED_OUT_EXECUTED, Decider.TIMEOUT, now, execute=True)
        else:
            self._end(p, Outcome.DROPPED, Decider.TIMEOUT, now)

    def _parts_of(self, action: str) -> tuple[Part, ...]:
        entry = self.menu_entry(action)
        if entry is None:
            return ()
        if entry.command == Command.SHOW_EMOTION and entry.args.get("say"):
            return (Part.FACE, Part.VOICE)  # an emotion that says its words never starts over someone else's sentence
        robot = tuple(map(Part, self.robot.model.parts))
        return ACTION_PARTS.get(entry.command, robot if entry.command == Command.PLAY_GESTURE else ())

    def _busy(self, action: str) -> bool:
        """Whether a part the action uses is someone else's now."""
        return not all(self.owners.free(part) for part in self._parts_of(action))

    def _end(self, p: Proposal, outcome: Outcome, by: str, now: float, *, execute: bool = False) -> None:
        self.pending.pop(p.id, None)
        if p.timer is not None:
            p.timer.cancel()
        if execute and not self._may_act(p.action):
            outcome, execute = Outcome.DROPPED, False
        self._outcome(p.id, p.action, outcome, Initiator.ROBOT, by, now - p.created, p.situation)
        if execute:
            self.executing[p.id] = asyncio.ensure_future(self._execute(p))
        self._publish_state()

    def _may_act(self, action: str) -> bool:
        """Not after an emergency stop, and a gesture not while an operator or a trial holds a part it moves (it
        would wait for them for long); whatever a gesture or a client holds is waited for (`_until_free`)."""
        entry = self.menu_entry(action)
        if entry is None or self.owners.stopped():
            return False
        return not any(self.owners.owner(part) in (Owner.OPERATOR, Owner.TRIAL) for part in self._parts_of(action))

    async def _until_free(self, action: str) -> None:
        """Returns once every part the action uses is nobody's (woken by the arbiter's changes)."""
        while self._busy(action):
            free: asyncio.Future[None] = asyncio.get_running_loop().create_future()
            self._free.append(free)
            await free

    async def _execute(self, p: Proposal) -> None:
        try:
            try:
                await asyncio.wait_for(self._until_free(p.action), BUSY_WAIT_S)
            except TimeoutError:
                raise BusError(f"{', '.join(self._parts_of(p.action))} stayed someone else's for "
                               f"{BUSY_WAIT_S:g} s") from None
            if not self._may_act(p.action):
                raise BusError("the emergency stop, an operator or a trial took the part meanwhile")
            await self.bus.call_service(names.MENU_SELECT_SERVICE, {"id": p.action, "args": ""}, EXECUTE_TIMEOUT_S,
                                        caller=AUTONOMY_NODE, refusal_response=False)
        except BusError as exc:
            publish_event(self.bus, "autonomy", EventKind.AUTONOMY_ACTION_FAILED, EventLevel.WARNING,
                          ActionFailed(id=p.id, action=p.action, reason=str(exc)))
        finally:
            self.executing.pop(p.id, None)
            self._publish_state()

    def _outcome(self, ident: str, action: str, outcome: Outcome, initiator: Initiator, by: str, seconds: float,
                 situation: Situation) -> None:
        self.bus.publish(names.AUTONOMY_OUTCOMES_TOPIC, {
            "header": {"stamp": self.bus.registry.now()}, "id": ident, "action": action, "outcome": outcome,
            "initiator": initiator, "decided_by": by, "seconds": round(max(0.0, seconds), 4),
            "situation": situation.name})
        if self.learner.record(situation, action, outcome):
            self._save_memory()

    def _save_memory(self) -> None:
        if self.learner.path is None:
            return
        previous = self._save

        async def save() -> None:
            if previous is not None:
                await asyncio.gather(previous, return_exceptions=True)
            try:
                await asyncio.to_thread(self.learner.save)
            except OSError:
                log.exception("the autonomy memory could not be written to %s", self.learner.path)

        self._save = asyncio.ensure_future(save())

    async def flushed(self) -> None:
        """Wait until the memory file holds every point stored so far (tests)."""
        if self._save is not None:
            await asyncio.gather(self._save, return_exceptions=True)

    def _on_event(self, published: Published) -> None:
        """The teacher's own actions from the menus: recorded as teacher-initiated, and learned."""
        msg = published.data
        if msg["source"] != "menu" or msg["kind"] != "select":
            return
        try:
            detail = json.loads(msg["detail"])
        except ValueError:
            return
        by = str(detail.get("by", ""))
        if by == AUTONOMY_NODE or detail.get("command") not in ACTION_COMMANDS:
            return
        now = self.clock.monotonic()
        situation = Situation("idle")
        if self._situation is not None and now - self._situation[1] <= SITUATION_WINDOW_S:
            situation = self._situation[0]
        self._outcome(f"t-{next(self._ids)}", str(detail.get("id", "")), Outcome.TEACHER_INITIATED, Initiator.TEACHER,
                      self.operator_of(by), 0.0, situation)

    # ---- services -------------------------------------------------------------------------------------------
    async def _level_service(self, request: Any) -> dict[str, Any]:
        return self.set_level(request.level, Bus.caller())

    def set_level(self, name: str, by: str) -> dict[str, Any]:
        try:
            level = AutonomyLevel(name)
        except ValueError:
            return {"success": False, "message": f"unknown autonomy level {name!r}: give one of "
                                                 f"{', '.join(AutonomyLevel)}"}
        cleared = self.owners.stopped()
        if cleared:
            self.owners.release(Owner.ESTOP)  # choosing a level again is the teacher's word that the robot may move
        before, self.level = self.level, level
        now = self.clock.monotonic()
        if level == AutonomyLevel.TELEOPERATED:
            for p in list(self.pending.values()):
                self._end(p, Outcome.DROPPED, Decider.SERVER, now)
            self._stop_attention(now)
        self._watch_faces()
        publish_event(self.bus, "autonomy", EventKind.AUTONOMY_LEVEL, EventLevel.INFO,
                      AutonomyLevelChanged(level=level, was=before, by=self.operator_of(by)))
        self._publish_state(force=True)
        note = " (the emergency stop's hold on autonomy is lifted)" if cleared else ""
        return {"success": True, "message": f"autonomy level {level}{note}"}

    async def _decide_service(self, request: Any) -> dict[str, Any]:
        return self.decide(request.id, request.decision, Bus.caller())

    def decide(self, ident: str, decision: str, caller: str) -> dict[str, Any]:
        try:
            outcome = Decision(decision).outcome
        except ValueError:
            return {"success": False, "message": f"unknown decision {decision!r}: give accept, reject or forbid"}
        p = self.pending.get(ident)
        if p is None:
            return {"success": False, "message": f"no pending proposal {ident!r}: it has ended (see "
                                                 f"{names.AUTONOMY_OUTCOMES_TOPIC}) or never was"}
        self._end(p, outcome, self.operator_of(caller), self.clock.monotonic(), execute=outcome == Outcome.ACCEPTED)
        return {"success": True, "message": f"{p.id} ({p.label}) {outcome}"}

    # ---- attention ------------------------------------------------------------------------------------------
    def _on_owners(self) -> None:
        now = self.clock.monotonic()
        free, self._free = self._free, []
        for waiter in free:
            if not waiter.done():
                waiter.set_result(None)
        for p in [p for p in self.pending.values() if p.waiting and not self._busy(p.action)]:
            self._timed_out(p)
        if not self.owners.free(Part.HEAD):
            self._head_free_since = None
            self._driving = False
        elif self._head_free_since is None:
            self._head_free_since = now
        if self.owners.stopped():
            for p in list(self.pending.values()):
                self._end(p, Outcome.DROPPED, Decider.SERVER, now)
        self._publish_state()

    def head_free(self, now: float) -> bool:
        """Whether autonomy may move the head now: nobody claims it, and it has been free for the grace."""
        if not self.owners.free(Part.HEAD):
            self._head_free_since = None
            return False
        if self._head_free_since is None:
            self._head_free_since = now
        return now - self._head_free_since >= self.cfg.release_grace_s

    def _stop_attention(self, now: float) -> None:
        self._driving = False
        self.target = None
        self._publish_attention(now, force=True)

    def _attend(self, now: float) -> None:
        if self.level == AutonomyLevel.TELEOPERATED:
            return
        if not self.head_free(now):
            if self.target is not None:
                self._stop_attention(now)
            return
        if not self._driving:
            self.attention.reset(self._head())  # from where the head is: the speed limit holds from there
            self._driving = True
        target = self.attention.update(now, self.candidates(now))
        self.target = target
        if target is not None:
            command = (round(target.yaw, 2), round(target.pitch, 2))
            if command != self._sent:
                self._sent = command
                self.head_commands += 1
                self.bus.publish(names.PART_COMMAND_TOPICS[Part.HEAD], {"data": list(command)}, sender=AUTONOMY_NODE)
        self._publish_attention(now)

    def running(self) -> list[str]:
        out = []
        if self.target is not None:
            out.append("glance" if self.target.source == "glance" else "attention")
        out += [f"proposal:{i}" for i in self.executing]
        return out

    def _target_id(self) -> str:
        """The attention target's person: a face's track id, a voice's speaker when the robot knows them, or ""."""
        t = self.target
        if t is None or t.key in self.tracks:
            return t.key if t is not None else ""
        return t.key.removeprefix("voice:") if t.key.startswith("voice:") else ""

    def _attention_message(self) -> dict[str, Any]:
        t = self.target
        face = self.tracks.get(t.key) if t is not None else None
        ident = self._target_id()
        return {"header": {"stamp": self.bus.registry.now()}, "source": t.source if t else "", "id": ident,
                "who": self.name(ident) if ident else "",
                "yaw": round(t.yaw, 3) if t else 0.0, "pitch": round(t.pitch, 3) if t else 0.0,
                "has_face": face is not None, "face": face.box if face is not None else {},
                "frame_seq": face.frame_seq if face is not None else 0, "score": round(t.score, 4) if t else 0.0}

    def attended_pupil(self) -> str:
        """The name of the person the robot attends to (the one every view shows), or ""."""
        ident = self._target_id()
        return self.name(ident) if ident else ""

    def _publish_attention(self, now: float, force: bool = False) -> None:
        pupil = self.attended_pupil()
        if pupil != self._pupil:
            self._pupil = pupil
            for changed in self.pupil_changed:
                changed()
        t = self.target
        face = self.tracks.get(t.key) if t else None  # each new box of the attended face: the pages draw it
        key = (t.source, t.key, self.name(self._target_id()), round(t.yaw / 2), round(t.pitch / 2),
               face.frame_seq if face else 0) if t else ()
        if force or key != self._pub.attention_key or now - self._pub.attention_at >= ATTENTION_REPUBLISH_S:
            self._pub.attention_key, self._pub.attention_at = key, now
            self.bus.publish(names.AUTONOMY_ATTENTION_TOPIC, self._attention_message(), latch=True)

    def _publish_state(self, force: bool = False) -> None:
        t = self.target
        summary = (self.level, tuple((p.id, p.waiting) for p in self.pending.values()), tuple(self.running()),
                   tuple(self.owners.owners().items()), (t.source, t.key, self.name(self._target_id())) if t else ())
        if not force and summary == self._pub.summary:
            return
        self._pub.summary = summary
        owners = self.owners.owners()
        if t is not None:
            owners = {part: (Owner.AUTONOMY if part == Part.HEAD and owner == Owner.NONE else owner)
                      for part, owner in owners.items()}
        self.bus.publish(names.AUTONOMY_STATE_TOPIC, {
            "header": {"stamp": self.bus.registry.now()}, "level": self.level,
            "attention": self._attention_message(),
            "pending": [p.message(self.clock.monotonic()) for p in self.pending.values()],
            "running": self.running(), "owners": [{"part": k, "owner": v} for k, v in owners.items()]}, latch=True)
