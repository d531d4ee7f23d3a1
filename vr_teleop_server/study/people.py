"""The simulated people of a trial, each an ordinary rosbridge client of the server:

- the human participant, who acts on the study file's human script, and whose actions the experimenter labels
  as they happen (/study/label/start and /study/label/stop);
- the operator of the Wizard-of-Oz trials, replaying the study file's operator script on /decision/teleop;
- the experimenter's scripted overrides (/decision/override).

Each step waits until every event it names ("agent:action:start|stop", seen on /study/state_updates) has
happened, then for a reaction time drawn from the script's range; human actions last a duration drawn from
theirs. Draws come from a generator seeded by the study's seed and the trial's name, so a trial replays alike.
"""

from __future__ import annotations

import asyncio
import random
import zlib
from collections.abc import Callable
from typing import Any

from client_protocol import names

from ..client import Client, Refused, connect
from .studyfile import Script, Study

BUSY_RETRY_S = 0.3


class SimulatedPeople:
    def __init__(self, url: str, study: Study, trial: str, *, operator: bool, seed: int | None = None,
                 opener: Callable[[], Any] | None = None) -> None:
        self.study = study
        self.trial = trial
        self.spec = study.trials[trial]
        self.operator = operator
        self.rng = random.Random(seed if seed is not None else study.seed * 1_000_003 + zlib.crc32(trial.encode()))
        self.url = url
        self.opener = opener  # the server's in-process connection (a simulated clock), else a WebSocket to url
        self._client: Client | None = None
        self.events: set[str] = set()
        self._changed = asyncio.Event()
        self.refusals: list[str] = []  # commands the server refused for a reason other than "busy"

    @property
    def client(self) -> Client:
        assert self._client is not None, "connect() first"
        return self._client

    async def connect(self) -> None:
        self._client = Client(self.opener(), id_prefix="people") if self.opener is not None \
            else await connect(self.url, id_prefix="people")
        await self.client.subscribe(names.STUDY_STATE_UPDATES_TOPIC, "vr_teleop_msgs/StateUpdate", self._on_update)
        await self.client.sync()  # the subscription is in place before the trial's first update

    async def close(self) -> None:
        if self._client is not None:
            await self._client.close()

    def _on_update(self, msg: dict[str, Any]) -> None:
        if msg.get("trial") != self.trial:
            return
        self.events.add(f"{msg['agent']}:{msg['action']}:{'stop' if msg['finished'] else 'start'}")
        self._changed.set()
        self._changed = asyncio.Event()

    async def _until(self, events: list[str]) -> None:
        while not all(e in self.events for e in events):
            await self._changed.wait()

    def _steps(self, script: Script) -> list[tuple[str, list[str], tuple[float, float], int]]:
        out = []
        for i, part in enumerate(self.study.parts):
            for step in script.steps:
                if not self.study.applies(step.when, part):
                    continue
                name = self.study.fill(step.action, i)
                if name is None:
                    continue
                after = [e for e in (self.study.fill(a, i) for a in step.after) if e is not None]
                out.append((name, after, step.duration_s, i))
        return out

    async def run(self) -> None:
        tasks = [self._human()]
        if self.operator:
            tasks.append(self._operate())
        tasks.extend(self._override(o.action, o.delay_s, o.succeeded, o.note) for o in self.spec.overrides)
        await asyncio.gather(*tasks)

    async def _human(self) -> None:
        script = self.study.human
        for name, after, (lo, hi), _ in self._steps(script):
            await self._until(after)
            await asyncio.sleep(self.rng.uniform(*script.reaction_s))
            await self.client.call(names.STUDY_LABEL_START_SERVICE, {"action": name})
            await asyncio.sleep(self.rng.uniform(lo, hi))
            await self.client.call(names.STUDY_LABEL_STOP_SERVICE, {"action": name})

    async def _operate(self) -> None:
        script = self.study.operator
        # Under the semi-autonomous module the operator commands only the plan's teleoperated steps.
        commanded = {s.robot for s in self.study.plan if s.teleop} if self.spec.decision == "semi" else None
        for action, after, _, i in self._steps(script):
            if commanded is not None and action not in commanded:
                continue
            part = self.study.parts[i].name
            await self._until(after)
            await asyncio.sleep(self.rng.uniform(*script.reaction_s))
            while True:
                try:
                    await self.client.call(names.DECISION_TELEOP_SERVICE, {"object": part, "action": action})
                    break
                except Refused as exc:
                    if "busy" not in exc.message and "not waiting" not in exc.message:
                        self.refusals.append(exc.message)
                        break
                    await asyncio.sleep(BUSY_RETRY_S)

    async def _override(self, subtask: str, delay_s: float, succeeded: bool, note: str) -> None:
        await self._until([f"robot:{subtask}:start"])
        await asyncio.sleep(delay_s)
        await self.client.call(names.DECISION_OVERRIDE_SERVICE,
                               {"succeeded": succeeded, "note": note or "scripted override"})
