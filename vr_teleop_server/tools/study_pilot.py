"""`vr-teleop study pilot`: the whole protocol of a study with people, played by simulated people through the live
study's own road: a server hosting the study (`serve --study` on the stand-in), the experimenter's services to enrol
(with consent), start and end each trial in the participant's order, the simulated people of the trial's kind acting
on it, and each participant's page answering what is due with seeded simulated answers (a participant token, the
same services as the tablet). How a lab checks a protocol before the first participant comes.
"""

from __future__ import annotations

import json
import random
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from client_protocol import names
from client_protocol.vocabulary import AutonomyLevel
from simclock import WALL, Clock

from ..app import TeleopServer
from ..client import Client, connect
from ..questionnaires.instrument import PREFER_NOT
from ..settings import ServerSettings
from ..study.kinds import kind_of, load_study


@dataclass
class PilotResult:
    participants: list[str] = field(default_factory=list)
    trials: int = 0
    questionnaires: int = 0
    outcomes: dict[str, int] = field(default_factory=dict)


def answer(sheet: dict[str, Any], rng: random.Random) -> dict[str, Any]:
    """A simulated respondent's answers to one due sheet: each item in its scale (now and then declined)."""
    out: dict[str, Any] = {}
    for block in sheet["blocks"]:
        for item in block["items"]:
            if rng.random() < 0.03:
                out[item["id"]] = PREFER_NOT
            elif "choices" in item:
                out[item["id"]] = rng.choice(item["choices"])
            else:
                scale = item.get("scale") or sheet["scale"]
                top = scale["max"] if scale["max"] is not None else scale["min"] + 60.0
                value = rng.uniform(scale["min"], top)
                out[item["id"]] = round(value) if scale["integer"] else round(value, 1)
    return out


async def pilot(study_file: Path, folder: Path, participants: int, *, clock: Clock = WALL, seed: int = 1,
                timeout: float = 900.0, perception: str = "modelled") -> PilotResult:
    study = load_study(study_file)
    rng = random.Random(seed)
    result = PilotResult()
    with tempfile.TemporaryDirectory(prefix="vr-teleop-pilot-") as tmp:
        settings = ServerSettings(port=0, backend="sim", study=study_file, study_dir=folder, record_camera_fps=0.0,
                                  autonomy=AutonomyLevel.TELEOPERATED, bystander_interval=0,
                                  gesture_dir=Path(tmp) / "g", audio_dir=Path(tmp) / "a",
                                  camera_fps=getattr(study, "camera_fps", None) or 30.0,
                                  perception=perception, perception_seed=seed)
        server = TeleopServer(settings, clock)
        await server.start()

        async def client(prefix: str, token: str = "") -> Client:
            if clock.simulated:
                return Client(server.transport.connect_local(f"/?token={token}" if token else "/"), id_prefix=prefix)
            return await connect(f"{server.url}/?token={token}" if token else server.url, id_prefix=prefix)

        try:
            experimenter = await client("experimenter")
            trial_state = await experimenter.subscribe(names.STUDY_TRIAL_TOPIC, "vr_teleop_msgs/TrialState")
            for _ in range(participants):
                added = await experimenter.call(names.STUDY_PARTICIPANT_ADD_SERVICE, {
                    "consent": True, "consent_form": study.consent_form, "group": ""})
                pid = added["participant"]
                result.participants.append(pid)
                page = await client(f"page-{pid}", added["token"])
                try:
                    result.questionnaires += await _fill_in(page, rng)
                    for condition in added["order"]:
                        outcome = await _trial(server, experimenter, trial_state, study, pid, condition, clock,
                                               rng.randrange(1 << 30), timeout)
                        result.trials += 1
                        result.outcomes[outcome] = result.outcomes.get(outcome, 0) + 1
                        result.questionnaires += await _fill_in(page, rng)
                finally:
                    await page.close()
            await experimenter.close()
        finally:
            await server.stop()
    return result


async def _fill_in(page: Client, rng: random.Random) -> int:
    """Everything due for the page's participant, in order, as the tablet would send it."""
    given = 0
    while True:
        due = json.loads((await page.call(names.STUDY_QUESTIONNAIRE_DUE_SERVICE, {}))["due_json"])
        if not due:
            return given
        sheet = due[0]
        await page.call(names.STUDY_QUESTIONNAIRE_SUBMIT_SERVICE, {
            "questionnaire": sheet["questionnaire"], "condition": sheet["condition"],
            "answers_json": json.dumps(answer(sheet, rng))})
        given += 1


async def _trial(server: TeleopServer, experimenter: Client, trial_state: Any, study: Any, pid: str,
                 condition: str, clock: Clock, seed: int, timeout: float) -> str:
    """One trial through the experimenter's services, its kind's simulated people acting on it; its outcome."""
    await experimenter.call(names.STUDY_TRIAL_START_SERVICE, {"participant": pid, "condition": "", "reason": ""})
    outcome = await kind_of(study).act(server, study, condition, clock=clock, seed=seed, timeout=timeout,
                                       trial_state=trial_state)
    await experimenter.call(names.STUDY_TRIAL_END_SERVICE, {"outcome": outcome, "note": "pilot"})
    return outcome
