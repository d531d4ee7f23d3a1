"""The study folder: a live study's whole state, so that a crash loses nothing and a restart carries on.

    DIR/study.json     the plan it was opened with (name, conditions, design, order, consent form ...)
    DIR/.secret        the key participant tokens are made from (HMAC of the pseudonym), so that a restarted
                       server knows the same tokens and a withdrawn participant's stops working
    DIR/events.jsonl   the event log: one JSON object a line (seq, time, who, what, ...), appended and fsynced
                       before an action counts
    DIR/P03/           the participant's recordings (CONDITION.mcap), written by whoever runs the trial

The state (participants, consent, orders, trials, answers) is the log replayed: `StudyFolder.open` reads it back,
drops a line a crash cut in half, and marks a trial that was running `interrupted` (its recording is kept and
the condition can be run again). Every action is checked against the state first; a refused one raises `Refused`
saying why and changes nothing. Participants have generated pseudonyms (P01, P02 ...), never names.

Withdrawal is the one change that is not an append: it deletes the participant's folder and rewrites the log
without their events (atomically), then appends only the fact and time of the withdrawal.

The server's live study (services, the dashboard) and the CLI call this module; it knows nothing of either.
"""

from __future__ import annotations

import fcntl
import hashlib
import hmac
import json
import os
import secrets
import shutil
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

from ..questionnaires.instrument import PREFER_NOT, AnswerError, check_answers, load_instrument, score
from .design import balance_note, participant_order
from .protocol import QuestionnaireEntry, StudyPlan

PLAN_FILE = "study.json"
LOG_FILE = "events.jsonl"
SECRET_FILE = ".secret"
LOCK_FILE = ".lock"  # held (flock) while a process has the folder open
Outcome = Literal["completed", "aborted", "interrupted"]
ENDINGS = ("completed", "aborted")


class Refused(Exception):
    """An action the study's state does not allow; the message says why and what to do."""


class FolderError(ValueError):
    """A folder that cannot be used with this study file."""


@dataclass
class Trial:
    number: int  # the participant's n-th trial
    condition: str
    position: int  # the condition's place in the participant's order, 1-based
    started: str
    recording: str  # relative to the folder
    outcome: Outcome | None = None  # None while it runs
    ended: str | None = None
    note: str = ""
    deviation: str | None = None  # the reason given for running it out of order


@dataclass
class Answers:
    questionnaire: str
    condition: str | None
    phase: str | None
    time: str
    answers: dict[str, float | None]  # None: the participant preferred not to answer
    scores: dict[str, float | None]


@dataclass
class Due:
    """A questionnaire a participant should fill in now."""

    questionnaire: str
    condition: str | None
    phase: str | None
    who: str | None = None

    def text(self) -> str:
        where = f" ({self.phase})" if self.phase else f" after {self.condition}" if self.condition else ""
        return f"{self.questionnaire}{where}" + (f" [{self.who}]" if self.who else "")


@dataclass
class Participant:
    id: str
    index: int  # 0 for the first ever enrolled: their row of the design
    group: str
    order: list[str]
    enrolled: str
    consent: dict[str, str] | None = None  # time, form
    demographics: dict[str, str] = field(default_factory=dict)
    trials: list[Trial] = field(default_factory=list)
    answers: list[Answers] = field(default_factory=list)

    def done(self) -> list[str]:
        """Conditions with a trial that ended (completed or aborted), in the order run."""
        return [t.condition for t in self.trials if t.outcome in ENDINGS]

    def next_condition(self) -> str | None:
        done = set(self.done())
        return next((c for c in self.order if c not in done), None)


def _now() -> datetime:
    return datetime.now(UTC)


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w", encoding="utf-8") as handle:
        handle.write(text)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(tmp, path)
    _fsync_dir(path.parent)


def participant_id(number: int) -> str:
    return f"P{number:02d}"


class StudyFolder:
    """One study's folder, opened for one process at a time."""

    def __init__(self, path: Path, plan: StudyPlan, clock: Callable[[], datetime]):
        self.path = path
        self.plan = plan
        self._clock = clock
        self.participants: dict[str, Participant] = {}
        self.withdrawn: dict[str, str] = {}  # id -> time
        self.running: tuple[str, Trial] | None = None
        self._seq = 0
        self._enrolled = 0  # participants ever enrolled, withdrawn ones too: the next one's design row
        self._lock: int | None = None
        self._secret = b""  # set by open(): read() makes no tokens

    def close(self) -> None:
        if self._lock is not None:
            os.close(self._lock)  # releases the flock
            self._lock = None

    def __enter__(self) -> StudyFolder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- opening -------------------------------------------------------------------------------------------

    @classmethod
    def open(cls, path: str | Path, plan: StudyPlan, *, clock: Callable[[], datetime] = _now,
             who: str = "server") -> StudyFolder:
        """Create the folder, or reopen it and carry on; a trial left running is marked interrupted."""
        path = Path(path)
        if plan.protocol.consent_form is None:
            raise FolderError(f"{plan.study}: the study file declares no consent_form (the version of the consent "
                              "form participants sign); a study with people needs one")
        path.mkdir(parents=True, exist_ok=True)
        lock = os.open(path / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(lock)
            raise FolderError(f"{path}: the study folder is open in another process (a running server?); "
                              "stop it first, or act through it") from None
        try:
            return cls._open_locked(path, plan, clock, who, lock)
        except BaseException:
            os.close(lock)
            raise

    @classmethod
    def _open_locked(cls, path: Path, plan: StudyPlan, clock: Callable[[], datetime], who: str,
                     lock: int) -> StudyFolder:
        plan_path = path / PLAN_FILE
        if plan_path.exists():
            stored = StudyPlan.from_json(json.loads(plan_path.read_text(encoding="utf-8")))
            differences = _differences(stored, plan)
            if differences:
                raise FolderError(f"{path}: this folder holds a study opened with another plan "
                                  f"({'; '.join(differences)}); its orders and answers would not fit. Use a new "
                                  "folder, or the study file the folder was made with")
        else:
            _write_atomic(plan_path, json.dumps(plan.to_json(), indent=2) + "\n")
        folder = cls(path, plan, clock)
        folder._lock = lock
        folder._secret = _secret(path / SECRET_FILE)
        folder._replay()
        if folder.running is not None:
            pid, trial = folder.running
            folder._append(who, "interrupted", participant=pid, trial=trial.number, condition=trial.condition,
                           reason="the server stopped while the trial ran; its recording is kept")
        return folder

    @classmethod
    def read(cls, path: str | Path) -> StudyFolder:
        """The folder's state for reading (the report), without the lock: a server may be writing it. A trial
        still running shows as running; nothing is written."""
        path = Path(path)
        if not (path / PLAN_FILE).exists():
            raise FolderError(f"{path}: not a study folder (no {PLAN_FILE})")
        plan = StudyPlan.from_json(json.loads((path / PLAN_FILE).read_text(encoding="utf-8")))
        folder = cls(path, plan, _now)
        folder._replay(repair=False)
        return folder

    def _replay(self, repair: bool = True) -> None:
        log = self.path / LOG_FILE
        if not log.exists():
            return
        data = log.read_bytes()
        good = data.rfind(b"\n") + 1
        if good < len(data) and repair:  # a line the crash cut: it never counted (its action was not acknowledged)
            with log.open("r+b") as handle:
                handle.truncate(good)
                os.fsync(handle.fileno())
        for number, line in enumerate(data[:good].decode("utf-8").splitlines(), start=1):
            if not line.strip():
                continue
            try:
                event = json.loads(line)
                self._apply(event)
                self._seq = event["seq"]
            except (ValueError, KeyError, IndexError, TypeError) as exc:
                raise FolderError(f"{log}, line {number}: not an event this tool wrote ({exc!r}); was the log "
                                  "edited by hand? Restore it from a backup") from None

    @staticmethod
    def _log_lines(path: Path) -> list[dict[str, Any]]:
        return [json.loads(line) for line in (path / LOG_FILE).read_text(encoding="utf-8").splitlines()
                if line.strip()] if (path / LOG_FILE).exists() else []

    def events(self) -> list[dict[str, Any]]:
        return self._log_lines(self.path)

    # ---- the log ------------------------------------------------------------------------------------------

    def _append(self, who: str, what: str, **fields: Any) -> dict[str, Any]:
        self._seq += 1
        event = {"seq": self._seq, "time": self._clock().isoformat(timespec="milliseconds"), "who": who,
                 "what": what, **fields}
        with (self.path / LOG_FILE).open("a", encoding="utf-8") as handle:
            handle.write(json.dumps(event, ensure_ascii=False) + "\n")
            handle.flush()
            os.fsync(handle.fileno())
        self._apply(event)
        return event

    def _apply(self, event: dict[str, Any]) -> None:
        what, pid = event["what"], event.get("participant")
        if what == "enrol":
            self._enrolled = max(self._enrolled, event["index"] + 1)
            self.participants[pid] = Participant(pid, event["index"], event["group"], list(event["order"]),
                                                 event["time"])
        elif what == "consent":
            self.participants[pid].consent = {"time": event["time"], "form": event["form"]}
        elif what == "demographics":
            self.participants[pid].demographics.update(event["values"])
        elif what == "trial_start":
            trial = Trial(event["trial"], event["condition"], event["position"], event["time"],
                          event["recording"], deviation=event.get("reason"))
            self.participants[pid].trials.append(trial)
            self.running = (pid, trial)
        elif what in ("trial_end", "interrupted"):
            trial = self.participants[pid].trials[event["trial"] - 1]
            trial.outcome = event.get("outcome", "interrupted")
            trial.ended = event["time"]
            trial.note = event.get("note", "")
            self.running = None
        elif what == "questionnaire":
            self.participants[pid].answers.append(Answers(
                event["questionnaire"], event.get("condition"), event.get("phase"), event["time"],
                event["answers"], event["scores"]))
        elif what == "withdraw":
            self.participants.pop(pid, None)
            self.withdrawn[pid] = event["time"]
            self._enrolled = max(self._enrolled, event["index"] + 1)
            if self.running is not None and self.running[0] == pid:
                self.running = None
        # note, label, override, preempt, wizard, ...: recorded facts with no state of their own

    # ---- actions ------------------------------------------------------------------------------------------

    def _participant(self, pid: str) -> Participant:
        if pid in self.participants:
            return self.participants[pid]
        if pid in self.withdrawn:
            raise Refused(f"{pid} withdrew at {self.withdrawn[pid]}; their data is deleted")
        known = ", ".join(self.participants) or "none yet"
        raise Refused(f"unknown participant {pid!r} (enrolled: {known})")

    def enrol(self, who: str, *, consent: bool, consent_form: str = "", group: str = "") -> Participant:
        """A new participant with the next pseudonym and design row; consent may be given now or later."""
        if consent:
            self._check_form(consent_form)
        index = self._enrolled
        pid = participant_id(index + 1)
        order = participant_order(self.plan.conditions, self.plan.protocol.design, self.plan.protocol.order,
                                  index, self.plan.seed)
        self._append(who, "enrol", participant=pid, index=index, group=group, order=order)
        if consent:
            self._append(who, "consent", participant=pid, form=consent_form)
        return self.participants[pid]

    def _check_form(self, form: str) -> None:
        expected = self.plan.protocol.consent_form
        if form != expected:
            raise Refused(f"consent form {form!r} is not the study's ({expected!r}): consent must be given on the "
                          "form the study file names")

    def give_consent(self, who: str, pid: str, consent_form: str) -> None:
        participant = self._participant(pid)
        if participant.consent is not None:
            raise Refused(f"{pid} consented already, at {participant.consent['time']}")
        self._check_form(consent_form)
        self._append(who, "consent", participant=pid, form=consent_form)

    def set_demographics(self, who: str, pid: str, values: Mapping[str, str]) -> None:
        self._participant(pid)
        questions = {d.id: d for d in self.plan.protocol.demographics}
        problems = []
        for key, value in values.items():
            if key in questions and value == PREFER_NOT:
                continue
            if key not in questions:
                problems.append(f"{key}: not a question of this study "
                                f"({', '.join(questions) or 'it asks none'})")
            elif value not in questions[key].choices:
                problems.append(f"{key}: {value!r} is not one of its choices ({', '.join(questions[key].choices)})")
        problems += [f"{key}: no answer (choose one, or \"{PREFER_NOT}\")" for key in questions if key not in values]
        if problems:
            raise Refused("; ".join(problems))
        self._append(who, "demographics", participant=pid, values=dict(values))

    def start_trial(self, who: str, pid: str, condition: str = "", reason: str = "") -> Trial:
        """Start the participant's next condition (or `condition`, which out of order needs a `reason`)."""
        participant = self._participant(pid)
        if participant.consent is None:
            raise Refused(f"{pid} has not consented: record their consent (form {self.plan.protocol.consent_form})"
                          " before a first trial")
        if self.running is not None:
            running_pid, trial = self.running
            raise Refused(f"a trial is already running ({running_pid}, {trial.condition}): end it first")
        following = participant.next_condition()
        if not condition:
            if following is None:
                raise Refused(f"{pid} has done every condition of their order ({', '.join(participant.order)})")
            condition = following
        if condition not in participant.order:
            where = "their group's" if self.plan.protocol.design == "between" else "the study's"
            raise Refused(f"{condition!r} is not one of {where} conditions for {pid} ({', '.join(participant.order)})")
        deviation = condition != following
        if deviation and not reason.strip():
            outcomes = [t.outcome or "" for t in participant.trials
                        if t.condition == condition and t.outcome in ENDINGS]
            why = f"already done ({', '.join(outcomes)})" if outcomes else f"the next in {pid}'s order is {following}"
            raise Refused(f"running {condition} now is a deviation ({why}): give a reason, which is logged")
        number = len(participant.trials) + 1
        runs = sum(t.condition == condition for t in participant.trials)
        recording = f"{pid}/{condition}{'' if runs == 0 else f'-{runs + 1}'}.mcap"
        (self.path / pid).mkdir(exist_ok=True)
        fields: dict[str, Any] = dict(participant=pid, trial=number, condition=condition,
                                      position=participant.order.index(condition) + 1, recording=recording)
        if deviation:
            fields["reason"] = reason.strip()
            fields["expected"] = following
        self._append(who, "trial_start", **fields)
        return participant.trials[-1]

    def end_trial(self, who: str, outcome: str, note: str = "") -> Trial:
        if self.running is None:
            raise Refused("no trial is running")
        if outcome not in ENDINGS:
            raise Refused(f"outcome {outcome!r} is not one of {', '.join(ENDINGS)}")
        pid, trial = self.running
        self._append(who, "trial_end", participant=pid, trial=trial.number, condition=trial.condition,
                     outcome=outcome, note=note)
        return trial

    def record(self, who: str, what: str, **fields: Any) -> dict[str, Any]:
        """A fact for the log (a note, a label, an override, a preempt, a Wizard-of-Oz action), tied to the
        running trial if there is one."""
        if what in {"enrol", "consent", "demographics", "trial_start", "trial_end", "interrupted",
                    "questionnaire", "withdraw"}:
            raise Refused(f"{what!r} is recorded by its own action")
        if self.running is not None:
            pid, trial = self.running
            fields = {"participant": pid, "trial": trial.number, **fields}
        return self._append(who, what, **fields)

    def note(self, who: str, text: str) -> dict[str, Any]:
        if not text.strip():
            raise Refused("an empty note")
        return self.record(who, "note", text=text)

    # ---- participant tokens -------------------------------------------------------------------------------

    def participant_token(self, pid: str) -> str:
        """The token of the participant's page: admits only their own questionnaires (role participant)."""
        self._participant(pid)
        if not self._secret:
            raise FolderError("participant tokens need the folder opened for writing (StudyFolder.open)")
        return hmac.new(self._secret, b"participant\0" + pid.encode(), hashlib.sha256).hexdigest()[:32]

    def participant_for_token(self, token: str) -> str | None:
        """Whose page presents `token`: an enrolled participant's id, or None (a withdrawn one's is refused)."""
        if not self._secret or not token:
            return None
        for pid in self.participants:
            if hmac.compare_digest(self.participant_token(pid), token):
                return pid
        return None

    # ---- questionnaires -----------------------------------------------------------------------------------

    def due(self, pid: str) -> list[Due]:
        """What the participant should fill in now, in the study file's order."""
        participant = self._participant(pid)
        given = {(a.questionnaire, a.condition, a.phase) for a in participant.answers}
        plan = self.plan.protocol.questionnaires
        due: list[Due] = []

        def add(entry: QuestionnaireEntry, condition: str | None) -> None:
            key = (entry.name, condition, entry.phase)
            if key not in given:
                due.append(Due(entry.name, condition, entry.phase, entry.who))

        for entry in plan.before_first:
            add(entry, None)
        for condition in dict.fromkeys(t.condition for t in participant.trials if t.outcome == "completed"):
            for entry in plan.after_each:
                add(entry, condition)
        if participant.done() and participant.next_condition() is None:
            for entry in plan.after_last:
                add(entry, None)
        return due

    def submit(self, who: str, pid: str, questionnaire: str, condition: str, answers: Mapping[str, object]) \
            -> dict[str, float | None]:
        """Take a due questionnaire's answers (item id -> answer, or "prefer_not_to_answer"); its scores."""
        due = self.due(pid)
        match = next((d for d in due if d.questionnaire == questionnaire and (d.condition or "") == condition),
                     None)
        if match is None:
            shown = ", ".join(d.text() for d in due) or "nothing"
            what = f"{questionnaire}" + (f" after {condition}" if condition else "")
            raise Refused(f"{what} is not due for {pid} (due now: {shown})")
        instrument = load_instrument(questionnaire)
        try:
            checked = check_answers(instrument, answers)
        except AnswerError as exc:
            raise Refused(f"{questionnaire}: {exc}") from None
        scores = score(instrument, checked)
        self._append(who, "questionnaire", participant=pid, questionnaire=questionnaire,
                     condition=match.condition, phase=match.phase, answers=checked, scores=scores)
        return scores

    # ---- withdrawal ---------------------------------------------------------------------------------------

    def withdraw(self, who: str, pid: str) -> None:
        """Delete the participant's data: their folder, and their events from the log, keeping the fact."""
        participant = self._participant(pid)
        shutil.rmtree(self.path / pid, ignore_errors=True)
        kept = [e for e in self.events() if e.get("participant") != pid]
        _write_atomic(self.path / LOG_FILE, "".join(json.dumps(e, ensure_ascii=False) + "\n" for e in kept))
        self._append(who, "withdraw", participant=pid, index=participant.index)

    # ---- reading ------------------------------------------------------------------------------------------

    def balance(self) -> str | None:
        p = self.plan.protocol
        return balance_note(p.design, p.order, len(self.plan.conditions), len(self.participants))

    def session(self) -> dict[str, Any]:
        """Everything the dashboard shows: each participant's order, trials done and questionnaires due."""
        running = None
        if self.running is not None:
            pid, trial = self.running
            running = {"participant": pid, "trial": trial.number, "condition": trial.condition,
                       "started": trial.started, "recording": trial.recording}
        return {
            "study": self.plan.study, "design": self.plan.protocol.design, "order": self.plan.protocol.order,
            "conditions": list(self.plan.conditions), "running": running, "balance": self.balance(),
            "participants": [{"id": p.id, "group": p.group, "order": p.order, "consented": p.consent is not None,
                              "done": p.done(), "next": p.next_condition(),
                              "due": [d.text() for d in self.due(p.id)]}
                             for p in self.participants.values()],
            "withdrawn": sorted(self.withdrawn),
        }


def _secret(path: Path) -> bytes:
    """The folder's token key, made once (readable by its owner only)."""
    if not path.exists():
        fd = os.open(path.with_name(path.name + ".tmp"), os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as handle:
            handle.write(secrets.token_hex(32))
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(path.with_name(path.name + ".tmp"), path)
        _fsync_dir(path.parent)
    return bytes.fromhex(path.read_text().strip())


def _differences(stored: StudyPlan, plan: StudyPlan) -> list[str]:
    out = []
    if stored.study != plan.study:
        out.append(f"study {stored.study!r}, not {plan.study!r}")
    if stored.conditions != plan.conditions:
        out.append(f"conditions {', '.join(stored.conditions)}, not {', '.join(plan.conditions)}")
    if stored.seed != plan.seed:
        out.append(f"seed {stored.seed}, not {plan.seed}")
    for key in ("design", "order", "consent_form"):
        a, b = getattr(stored.protocol, key), getattr(plan.protocol, key)
        if a != b:
            out.append(f"{key} {a}, not {b}")
    if stored.protocol.questionnaires != plan.protocol.questionnaires:
        out.append("other questionnaires")
    return out


def withdraw(path: str | Path, pid: str, who: str = "cli") -> StudyFolder:
    """`vr-teleop study withdraw DIR P07`: the folder opened with the plan it was made with."""
    plan = StudyFolder.read(path).plan
    with StudyFolder.open(path, plan, who=who) as folder:
        folder.withdraw(who, pid)
    return folder
