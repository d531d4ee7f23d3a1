"""The live study on a running server (`serve --study FILE --study-dir DIR`): the experimenter's and the
participants' services over the study folder (folder.py), and its trials hosted on the server's robot, whatever
the backend.

Services (client_protocol/names.py): /study/participants/add, /study/trial/start, /study/trial/end, /study/note
(supervisor: core/access.py); /study/questionnaire/due and /study/questionnaire/submit (the participant role, for
themselves); the latched /study/session. A refused call answers success false with the reason and changes nothing
(the folder checks before it writes). Interventions and the experimenter's labels of a running trial go to the
folder's event log too.

A trial (TrialHost): its recording (DIR/P03/CONDITION.mcap, a Recorder on the bus) starts first, then its kind
hosts its condition on the server (kind.py: the classroom kind sets the autonomy level, the task kind runs the
condition's modules on the server's robot).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from client_protocol import names

from ..core.bus import SERVER_NODE, Bus, BusError, Published
from ..questionnaires.instrument import load_instrument
from ..recording.recorder import Recorder
from .folder import Refused, StudyFolder
from .kind import HostedTrial, ServerParts, StudyKind

log = logging.getLogger(__name__)

SERVICES = (names.STUDY_PARTICIPANT_ADD_SERVICE, names.STUDY_TRIAL_START_SERVICE, names.STUDY_TRIAL_END_SERVICE,
            names.STUDY_NOTE_SERVICE, names.STUDY_QUESTIONNAIRE_DUE_SERVICE, names.STUDY_QUESTIONNAIRE_SUBMIT_SERVICE)
DEMOGRAPHICS = "demographics"  # the study file's demographic questions, on the page as a questionnaire
PARTICIPANT_PREFIX = "participant:"  # a participant's connections' operator key (core/access.py)


class TrialHost:
    """One trial at a time on the live server: begin(condition, recording) and end(outcome). Its recording starts
    first, then the kind hosts the condition on the server (kind.py)."""

    def __init__(self, study: Any, kind: StudyKind, parts: ServerParts) -> None:
        self.study = study
        self.kind = kind
        self.parts = parts
        self.recorder: Recorder | None = None
        self.trial: HostedTrial | None = None

    async def begin(self, condition: str, recording: Path) -> None:
        p = self.parts
        self.recorder = Recorder(recording, p.registry, p.camera_fps, bus=p.bus, clock=p.clock, blur=p.blur)
        self.recorder.start()
        try:
            self.trial = await self.kind.host(self.study, condition, p)
        except BaseException:
            await self.end("aborted")
            raise

    async def end(self, outcome: str) -> None:
        """Stops the condition (the robot's decision module, if it still runs) and closes the recording."""
        try:
            if self.trial is not None:
                trial, self.trial = self.trial, None
                await trial.end(outcome)
        finally:
            if self.recorder is not None:
                recorder, self.recorder = self.recorder, None
                await recorder.stop()


class LiveStudy:
    """The study folder's services on the bus. `identity(caller)` is the calling connection's operator key
    (`participant:P03` for a participant's page, see core/access.py) for the event log's `who`."""

    def __init__(self, bus: Bus, folder: StudyFolder, host: TrialHost, identity: Callable[[str], str]) -> None:
        self.bus = bus
        self.folder = folder
        self.host = host
        self.identity = identity
        self._subscriptions: list[tuple[str, int]] = []
        self._busy = asyncio.Lock()  # one experimenter action at a time: a start waits for an end's recorder
        host.parts.observer = self._on_command

    # ---- lifetime -----------------------------------------------------------------------------------------------
    def start(self) -> None:
        bus = self.bus
        bus.declare_topic(names.STUDY_SESSION_TOPIC, "vr_teleop_msgs/StudySession", latched=True, persistent=True)
        bus.declare_topic(names.STUDY_INTERVENTIONS_TOPIC, "vr_teleop_msgs/Intervention", persistent=True)
        bus.declare_topic(names.STUDY_STATE_UPDATES_TOPIC, "vr_teleop_msgs/StateUpdate", persistent=True)
        bus.provide(names.STUDY_PARTICIPANT_ADD_SERVICE, "vr_teleop_msgs/AddParticipant", self._add,
                    confidential=True)  # the response holds the participant's token
        bus.provide(names.STUDY_TRIAL_START_SERVICE, "vr_teleop_msgs/StartTrial", self._start_trial)
        bus.provide(names.STUDY_TRIAL_END_SERVICE, "vr_teleop_msgs/EndTrial", self._end_trial)
        bus.provide(names.STUDY_NOTE_SERVICE, "vr_teleop_msgs/StudyNote", self._note)
        bus.provide(names.STUDY_QUESTIONNAIRE_DUE_SERVICE, "vr_teleop_msgs/QuestionnairesDue", self._due)
        bus.provide(names.STUDY_QUESTIONNAIRE_SUBMIT_SERVICE, "vr_teleop_msgs/SubmitQuestionnaire", self._submit)
        for topic, callback in ((names.STUDY_INTERVENTIONS_TOPIC, self._on_intervention),
                                (names.STUDY_STATE_UPDATES_TOPIC, self._on_update)):
            self._subscriptions.append((topic, bus.subscribe(SERVER_NODE, topic, None, callback)))
        self.publish()

    async def stop(self) -> None:
        """A trial still running stays running in the folder: reopened, it is marked interrupted."""
        for topic, token in self._subscriptions:
            self.bus.unsubscribe(topic, token)
        self._subscriptions.clear()
        for name in SERVICES:
            with contextlib.suppress(BusError):
                self.bus.unadvertise_service(SERVER_NODE, name)
        await self.host.end("aborted")
        self.folder.close()

    # ---- the session --------------------------------------------------------------------------------------------
    def publish(self) -> None:
        s = self.folder.session()
        running = s["running"] or {}
        self.bus.publish(names.STUDY_SESSION_TOPIC, {
            "study": s["study"], "kind": self.host.kind.name, "design": s["design"], "order": s["order"],
            "conditions": s["conditions"], "withdrawn": s["withdrawn"], "balance": s["balance"] or "",
            "participants": [{**p, "next": p["next"] or ""} for p in s["participants"]],
            "running_participant": running.get("participant", ""), "running_trial": running.get("trial", 0),
            "running_condition": running.get("condition", ""), "running_recording": running.get("recording", ""),
            **self.host.kind.session_fields(self.host.study)}, latch=True)

    def _who(self) -> str:
        return self.identity(Bus.caller())

    # ---- the experimenter ---------------------------------------------------------------------------------------
    async def _add(self, request: Any) -> dict[str, Any]:
        try:
            participant = self.folder.enrol(self._who(), consent=request.consent, consent_form=request.consent_form,
                                            group=request.group)
        except Refused as exc:
            return {"success": False, "message": str(exc), "participant": "", "order": [], "token": ""}
        self.publish()
        consent = "consented" if participant.consent else "no consent yet: record it before a first trial"
        return {"success": True, "message": f"{participant.id} enrolled ({consent}); order "
                                            f"{', '.join(participant.order)}",
                "participant": participant.id, "order": participant.order,
                "token": self.folder.participant_token(participant.id)}

    async def _start_trial(self, request: Any) -> dict[str, Any]:
        async with self._busy:
            who = self._who()
            try:
                trial = self.folder.start_trial(who, request.participant, request.condition, request.reason)
            except Refused as exc:
                return {"success": False, "message": str(exc), "trial": 0}
            try:
                await self.host.begin(trial.condition, self.folder.path / trial.recording)
            except Exception as exc:  # the robot could not take the condition: the trial ends, logged
                log.exception("the live study's trial %s %s did not start", request.participant, trial.condition)
                self.folder.end_trial(who, "aborted", note=f"did not start: {exc}")
                self.publish()
                return {"success": False, "message": f"{trial.condition} did not start ({exc}); logged as aborted",
                        "trial": trial.number}
            self.publish()
            return {"success": True, "message": f"{request.participant or 'trial'}: {trial.condition} started "
                                                f"(trial {trial.number}), recording {trial.recording}",
                    "trial": trial.number}

    async def _end_trial(self, request: Any) -> dict[str, Any]:
        async with self._busy:
            try:
                trial = self.folder.end_trial(self._who(), request.outcome, request.note)
            except Refused as exc:
                return {"success": False, "message": str(exc)}
            await self.host.end(request.outcome)
            self.publish()
            return {"success": True, "message": f"{trial.condition} {request.outcome}; recording {trial.recording}"}

    async def _note(self, request: Any) -> dict[str, Any]:
        try:
            self.folder.note(self._who(), request.text)
        except Refused as exc:
            return {"success": False, "message": str(exc)}
        return {"success": True, "message": "noted"}

    def _on_command(self, caller: str, service: str, request: dict[str, object]) -> None:
        """A Wizard-of-Oz, override or preempt command the trial took, with who gave it."""
        what = {names.DECISION_TELEOP_SERVICE: "wizard", names.DECISION_OVERRIDE_SERVICE: "override_command",
                names.DECISION_PREEMPT_SERVICE: "preempt_command"}[service]
        if self.folder.running is not None:
            self.folder.record(self.identity(caller), what, **request)

    def _on_intervention(self, published: Published) -> None:
        if self.folder.running is None:
            return
        m = published.data
        self.folder.record(published.sender, m["kind"], subtask=m["subtask"], note=m["note"], at=m["start"])

    def _on_update(self, published: Published) -> None:
        m = published.data
        if self.folder.running is None or m["source"] != "label":
            return
        self.folder.record(published.sender, "label", agent=m["agent"], action=m["action"],
                           phase="stop" if m["finished"] else "start", at=m["stop"] if m["finished"] else m["start"])

    # ---- the participant ----------------------------------------------------------------------------------------
    def _participant(self) -> str:
        who = self._who()
        if not who.startswith(PARTICIPANT_PREFIX):
            raise Refused("only a participant's page answers questionnaires: open /participant with the token "
                          "/study/participants/add gave")
        return who[len(PARTICIPANT_PREFIX):]

    async def _due(self, request: Any) -> dict[str, Any]:
        try:
            pid = self._participant()
            due = self.folder.due(pid)
            answered = len(self.folder.participants[pid].answers)
        except Refused as exc:
            return {"success": False, "message": str(exc), "participant": "", "due_json": "[]", "answered": 0}
        listing = [{"questionnaire": d.questionnaire, "condition": d.condition or "", "phase": d.phase or "",
                    "who": d.who or "", **_sheet(d.questionnaire)} for d in due]
        questions = self.folder.plan.protocol.demographics
        if questions and not self.folder.participants[pid].demographics:  # asked first, once, in bands
            listing.insert(0, {"questionnaire": DEMOGRAPHICS, "condition": "", "phase": "", "who": "",
                               "title": "About you", "scale": None, "blocks": [{"title": "About you", "items": [
                                   {"id": q.id, "text": q.question, "choices": q.choices} for q in questions]}]})
        return {"success": True, "message": f"{len(due)} due", "participant": pid,
                "due_json": json.dumps(listing), "answered": answered}

    async def _submit(self, request: Any) -> dict[str, Any]:
        try:
            pid = self._participant()
            try:
                answers = json.loads(request.answers_json)
            except ValueError as exc:
                raise Refused(f"answers_json is not JSON ({exc})") from None
            if request.questionnaire == DEMOGRAPHICS:
                if not isinstance(answers, dict):
                    raise Refused("answers_json must be an object from question id to choice")
                if self.folder.participants[pid].demographics:
                    raise Refused(f"{pid} answered the demographic questions already")
                self.folder.set_demographics(self.identity(Bus.caller()), pid, answers)
            else:
                self.folder.submit(self.identity(Bus.caller()), pid, request.questionnaire, request.condition,
                                   answers)
        except Refused as exc:
            return {"success": False, "message": str(exc)}
        self.publish()
        return {"success": True, "message": f"{request.questionnaire} received, thank you"}


def _sheet(name: str) -> dict[str, Any]:
    """What the participant's page shows of a questionnaire: its title, scale and items, block by block."""
    instrument = load_instrument(name)

    def scale(s: Any) -> dict[str, Any]:
        return {"min": s.min, "max": s.max, "integer": s.integer, "anchors": {str(k): v for k, v in s.anchors.items()},
                "unit": s.unit}

    blocks = ([{"title": "", "items": instrument.items}] if instrument.items else []) + \
        [{"title": sub.long_name or sub.name, "items": sub.items} for sub in instrument.subscales if sub.items]
    return {"title": instrument.title, "scale": scale(instrument.scale),
            "blocks": [{"title": b["title"], "items": [
                {"id": i.id, "text": i.text or i.short or i.id, "left": i.left or "", "right": i.right or "",
                 **({"scale": scale(i.scale)} if i.scale is not None else {})} for i in b["items"]]}
                for b in blocks]}
