"""The stand-in's simulated pupils on the bus (simulation only): a test or a study makes a pupil speak or look away.

`/sim/bystanders/speak` renders the sentence with the server's TTS (espeak-ng) into the robot's microphone (the
stand-in's `hear`, which the WebRTC audio mixes as a real robot's microphone: the operator hears the pupil), and
reports voice activity with the pupil's direction as a microphone array would (`SimulatedWorld.report_voice`). With
`interval` > 0 the pupils also take turns saying a line every `interval` seconds (the classroom's background).
`/sim/bystanders/look` turns a pupil's head to the robot or away (the scene's figure turns: the head camera, the face
detector and attention see it); the pupils' list, places and states are
latched on `/sim/bystanders`.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable
from typing import Any

import numpy as np
from client_protocol import names
from sim.pupils import Pupil
from simclock import WALL, Clock

from ..core.bus import Bus
from ..core.tasks import cancel_and_wait
from ..robot.interface import VoiceActivity
from ..robot.world import SimulatedWorld

log = logging.getLogger(__name__)

GAIN = 0.35  # a pupil a few metres from the robot's microphone
CHUNK_S = 0.1  # the voice reaches the microphone in pieces of this length, in real time
LINES = ("Can I ask the robot a question?", "Look, it is waving at us.", "What is your name, robot?",
         "I think it can see us.")
MAX_TEXT = 500
Render = Callable[[str], Awaitable[tuple[bytes, int, int]]]  # text -> (PCM S16LE, sample rate, channels)


class Bystanders:
    def __init__(self, bus: Bus, world: SimulatedWorld, render: Render, *, clock: Clock = WALL,
                 interval: float = 0.0, lines: tuple[str, ...] = LINES) -> None:
        self.bus = bus
        self.world = world  # the stand-in's robot
        self.render = render
        self.clock = clock
        self.interval = interval
        self.lines = lines
        self.looking = {p.name: "robot" for p in world.pupils}
        self.speaking: dict[str, asyncio.Task[None]] = {}
        self._turns: asyncio.Task[None] | None = None

    def start(self) -> None:
        self.bus.declare_topic(names.SIM_BYSTANDERS_TOPIC, "vr_teleop_msgs/Bystanders", state=True,
                               persistent=True)
        self.bus.provide(names.SIM_BYSTANDERS_SPEAK_SERVICE, "vr_teleop_msgs/BystanderSpeak", self._speak_service)
        self.bus.provide(names.SIM_BYSTANDERS_LOOK_SERVICE, "vr_teleop_msgs/BystanderLook", self._look_service)
        self._publish()
        if self.interval > 0:
            self._turns = asyncio.ensure_future(self._take_turns())

    async def stop(self) -> None:
        await cancel_and_wait(self._turns, *self.speaking.values())

    def _pupil(self, who: str) -> Pupil | None:
        return next((p for p in self.world.pupils if p.name == who), None)

    def _known(self) -> str:
        return ", ".join(p.name for p in self.world.pupils)

    async def _speak_service(self, request: Any) -> dict[str, Any]:
        return await self.speak(request.who, request.text)

    async def speak(self, who: str, text: str) -> dict[str, Any]:
        """Starts `who` saying `text`; answers once the voice is rendered and the pupil has begun."""
        pupil = self._pupil(who)
        if pupil is None:
            return {"success": False, "message": f"no pupil {who!r}; the pupils are {self._known()}"}
        text = text.strip()
        if not text or len(text) > MAX_TEXT:
            return {"success": False, "message": f"text must be 1..{MAX_TEXT} characters, got {len(text)}"}
        if who in self.speaking:
            return {"success": False, "message": f"{who} is already speaking; wait until they finish"}
        try:
            pcm, rate, channels = await self.render(text)
        except Exception as exc:  # espeak-ng missing or failing: say so, the pupils stay silent
            return {"success": False, "message": f"the voice could not be rendered: {exc}"}
        pcm = (np.frombuffer(pcm[:len(pcm) - len(pcm) % 2], "<i2") * GAIN).astype("<i2").tobytes()
        if who in self.speaking:
            return {"success": False, "message": f"{who} is already speaking; wait until they finish"}
        begun = asyncio.get_running_loop().create_future()
        self.speaking[who] = asyncio.ensure_future(self._say(pupil, pcm, rate, channels, begun))
        seconds = await begun
        return {"success": True, "message": f"{who} speaks for {seconds:.1f} s from {pupil.yaw_deg:.1f} deg"}

    async def _say(self, pupil: Pupil, pcm: bytes, rate: int, channels: int, begun: asyncio.Future) -> None:
        frame = 2 * channels
        chunk = max(frame, int(rate * CHUNK_S) * frame)
        loop = asyncio.get_running_loop()
        try:
            self.world.report_voice(VoiceActivity(True, pupil.yaw_deg, self.clock.monotonic(), pupil.name))
            self._publish()
            begun.set_result(len(pcm) / frame / rate)
            next_at = loop.time()
            for start in range(0, len(pcm), chunk):
                self.world.hear(pcm[start:start + chunk], rate, channels)
                next_at += min(chunk, len(pcm) - start) / frame / rate
                await asyncio.sleep(max(0.0, next_at - loop.time()))
        finally:
            self.speaking.pop(pupil.name, None)
            self.world.report_voice(VoiceActivity(False, pupil.yaw_deg, self.clock.monotonic(), pupil.name))
            self._publish()

    async def _look_service(self, request: Any) -> dict[str, Any]:
        return self.look(request.who, request.at)

    def look(self, who: str, at: str) -> dict[str, Any]:
        if self._pupil(who) is None:
            return {"success": False, "message": f"no pupil {who!r}; the pupils are {self._known()}"}
        if at not in ("robot", "away"):
            return {"success": False, "message": f"at must be robot or away, not {at!r}"}
        self.world.pupil_looks(who, at == "robot")  # the head camera sees the face, or the back of the head
        self.looking[who] = at
        self._publish()
        return {"success": True, "message": f"{who} looks {'at the robot' if at == 'robot' else 'away'}"}

    async def _take_turns(self) -> None:
        """The classroom's background: a pupil says a line every `interval` seconds, in turn."""
        turn = 0
        while True:
            await asyncio.sleep(self.interval)
            pupil = self.world.pupils[turn % len(self.world.pupils)]
            reply = await self.speak(pupil.name, self.lines[turn % len(self.lines)])
            if not reply["success"]:
                log.info("a pupil's line was not spoken: %s", reply["message"])
            turn += 1

    def _publish(self) -> None:
        self.bus.publish(names.SIM_BYSTANDERS_TOPIC, {
            "header": {"stamp": self.bus.registry.now()},
            "bystanders": [{"name": p.name, "position": {"x": p.x, "y": p.y, "z": p.z}, "yaw": round(p.yaw_deg, 3),
                            "looking": self.looking[p.name], "speaking": p.name in self.speaking}
                           for p in self.world.pupils]}, latch=True)
