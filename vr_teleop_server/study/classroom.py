"""The people of a classroom lesson (classroom_file.py), each an ordinary client of the server:

- the pupils, one task each on the stand-in's /sim/bystanders/speak and /sim/bystanders/look: quiet for an
  exponential gap, then a sentence of a drawn length (as many words as espeak-ng says in that time), again and
  again; and now and then looking away for a while;
- the teacher in the operator's role, on a connection of her own (possibly through a network profile's
  impairment: study/network.py): she hears who speaks (/sim/bystanders), sees the proposals and the robot's head
  (/qt_robot/joints/state), streams head poses on /vr/head/pose at the headset's rate while she holds control
  (engaged through /vr_teleop/control/engage, as the operator page does), picks menu items through
  /vr_teleop/menu/select and decides proposals through /vr_teleop/autonomy/decide.

Every draw comes from generators seeded by the run's seed (one per pupil, one for the teacher), so a seed gives
the same lesson wherever it runs.
"""

from __future__ import annotations

import asyncio
import math
import random
from collections.abc import Callable
from typing import Any

from scipy.spatial.transform import Rotation

from client_protocol import names
from client_protocol.vocabulary import AutonomyLevel, Decision

from ..client import Client, Refused
from .classroom_file import ClassroomStudy

WORDS_PER_S = 2.9  # espeak-ng's default 175 words a minute
WORDS = ("the", "robot", "sun", "is", "a", "star", "and", "plants", "need", "water", "light", "to", "grow", "my",
         "cat", "likes", "fish", "we", "went", "park", "today", "why", "sky", "blue", "can", "you", "help", "me")
EYE_HEIGHT = 1.6
POINTING_DEG = 10.0


def head_pose(yaw_left_deg: float) -> dict[str, Any]:
    """A headset's head pose (Unity frame: y up, left-handed) turned `yaw_left_deg` to the left."""
    q = Rotation.from_euler("Y", -yaw_left_deg, degrees=True).as_quat()
    return {"header": {"frame_id": "unity_left_handed"},
            "pose": {"position": {"x": 0.0, "y": EYE_HEIGHT, "z": 0.0},
                     "orientation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]}}}


class Pupils:
    def __init__(self, client: Client, study: ClassroomStudy, seed: int) -> None:
        self.client = client
        self.spec = study.pupils
        self.rngs = {who: random.Random(seed * 7919 + i) for i, who in enumerate(self.spec.who)}
        self.refusals: list[str] = []

    async def run(self) -> None:
        tasks = [self._speak(who) for who in self.spec.who]
        if self.spec.look_away_per_min > 0:
            tasks += [self._look(who) for who in self.spec.who]
        await asyncio.gather(*tasks)

    async def _speak(self, who: str) -> None:
        rng = self.rngs[who]
        while True:
            await asyncio.sleep(rng.expovariate(self.spec.speak_per_min / 60.0))
            seconds = rng.uniform(*self.spec.speech_s)
            text = " ".join(rng.choice(WORDS) for _ in range(max(1, round(seconds * WORDS_PER_S))))
            try:
                await self.client.call(names.SIM_BYSTANDERS_SPEAK_SERVICE, {"who": who, "text": text})
            except Refused as exc:
                self.refusals.append(exc.message)
                continue
            await asyncio.sleep(seconds)  # about its length: the next gap starts when it has (nearly) ended

    async def _look(self, who: str) -> None:
        rng = random.Random(self.rngs[who].random())
        while True:
            await asyncio.sleep(rng.expovariate(self.spec.look_away_per_min / 60.0))
            await self.client.call(names.SIM_BYSTANDERS_LOOK_SERVICE, {"who": who, "at": "away"})
            await asyncio.sleep(rng.uniform(*self.spec.look_away_s))
            await self.client.call(names.SIM_BYSTANDERS_LOOK_SERVICE, {"who": who, "at": "robot"})


class Teacher:
    def __init__(self, client: Client, study: ClassroomStudy, level: AutonomyLevel, seed: int,
                 monotonic: Callable[[], float]) -> None:
        self.client = client
        self.spec = study.teacher
        self.level = AutonomyLevel(level)
        self.rng = random.Random(seed * 104729 + 1)
        self.now = monotonic
        self.yaw = 0.0  # her head, relative to where it was when she engaged (the robot's straight ahead)
        self.target = 0.0
        self.engaged = False
        self.robot_yaw = 0.0
        self.speaking: dict[str, float] = {}  # who -> onset (her clock)
        self.heard = 0  # speeches begun so far (the progress lines)
        self.last_proposal_at = -math.inf
        self.refusals: list[str] = []
        self._tasks: set[asyncio.Task[Any]] = set()
        self._streaming: asyncio.Task[None] | None = None
        self._intervening = False
        self.started = False

    # ---- what she sees and hears ------------------------------------------------------------------------------
    async def connect(self) -> None:
        c = self.client
        await c.advertise(names.HEAD_POSE_TOPIC, "geometry_msgs/PoseStamped")
        await c.subscribe(names.SIM_BYSTANDERS_TOPIC, "vr_teleop_msgs/Bystanders", self._on_bystanders)
        await c.subscribe(names.JOINT_STATE_TOPIC, "sensor_msgs/JointState", self._on_joints)
        if self.level != AutonomyLevel.TELEOPERATED:
            await c.subscribe(names.AUTONOMY_PROPOSALS_TOPIC, "vr_teleop_msgs/Proposal", self._on_proposal)
        await c.sync()

    async def begin(self) -> None:
        """Before the lesson: in teleoperated she takes control (head poses first, as a headset's page does). The
        lesson starts when she sets the level (the recorded start)."""
        if self.level == AutonomyLevel.TELEOPERATED:
            await self._engage()
        await self._call(names.AUTONOMY_LEVEL_SERVICE, {"level": self.level})
        self.started = True

    async def close(self) -> None:
        for task in [*self._tasks, self._streaming]:
            if task is not None:
                task.cancel()
        await asyncio.gather(*[t for t in [*self._tasks, self._streaming] if t is not None], return_exceptions=True)

    def _spawn(self, coro: Any) -> None:
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _on_joints(self, msg: dict[str, Any]) -> None:
        joints = dict(zip(msg.get("name", []), msg.get("position", [])))
        if "HeadYaw" in joints:
            self.robot_yaw = float(joints["HeadYaw"])

    def _on_bystanders(self, msg: dict[str, Any]) -> None:
        if not self.started:
            return
        for b in msg.get("bystanders", []):
            who = b["name"]
            if b["speaking"] and who not in self.speaking:
                self.speaking[who] = self.now()
                self.heard += 1
                self._spawn(self._on_onset(who, float(b["yaw"])))
            elif not b["speaking"] and who in self.speaking:
                del self.speaking[who]
                self._spawn(self._on_stop(who))

    def _on_proposal(self, msg: dict[str, Any]) -> None:
        if not self.started:
            return
        self.last_proposal_at = self.now()
        if self.level == AutonomyLevel.SUPERVISED:
            self._spawn(self._decide(str(msg["id"])))

    # ---- what she does ----------------------------------------------------------------------------------------
    async def _on_onset(self, who: str, yaw: float) -> None:
        delay = self.rng.uniform(*self.spec.reaction_s)
        if self.level == AutonomyLevel.TELEOPERATED:
            await asyncio.sleep(delay)
            self.target = yaw
            return
        # supervised and autonomous: she waits to see whether the robot looks at them
        onset = self.speaking.get(who)
        await asyncio.sleep(self.spec.intervene_after_s)
        if self.speaking.get(who) != onset or abs(self.robot_yaw - yaw) <= POINTING_DEG or self._intervening:
            return
        self._intervening = True
        try:
            await self._engage()
            self.target = yaw
            while self.speaking.get(who) == onset:
                await asyncio.sleep(0.2)
            await asyncio.sleep(self.spec.intervene_hold_s)
            await self._release()
        finally:
            self._intervening = False

    async def _on_stop(self, who: str) -> None:
        draw = self.rng.random()
        action = self.rng.choice(self.spec.actions)
        wait = self.rng.uniform(*self.spec.answer_s)
        stopped = self.now()
        await asyncio.sleep(wait)
        if self.level == AutonomyLevel.AUTONOMOUS or draw >= self.spec.respond_probability:
            return
        if self.level == AutonomyLevel.SUPERVISED and self.last_proposal_at >= stopped:
            return  # the robot proposed something: she leaves the answer to it (and decides it)
        await self._call(names.MENU_SELECT_SERVICE, {"id": action, "args": ""})

    async def _decide(self, ident: str) -> None:
        accept = self.rng.random() < self.spec.accept_probability
        await asyncio.sleep(self.rng.uniform(*self.spec.decide_s))
        try:
            await self.client.call(names.AUTONOMY_DECIDE_SERVICE,
                                   {"id": ident, "decision": Decision.ACCEPT if accept else Decision.REJECT})
        except Refused as exc:
            if "no pending proposal" not in exc.message:  # too late (timed out or superseded) is no refusal
                self.refusals.append(exc.message)

    async def _engage(self) -> None:
        self.yaw = self.target = 0.0  # she faces the robot's straight ahead when she takes control
        if self._streaming is None or self._streaming.done():
            self._streaming = asyncio.ensure_future(self._stream())
        await self.client.publish(names.HEAD_POSE_TOPIC, head_pose(self.yaw))
        await self._call(names.ENGAGE_SERVICE, {"data": True})
        self.engaged = True

    async def _release(self) -> None:
        await self._call(names.ENGAGE_SERVICE, {"data": False})
        self.engaged = False
        if self._streaming is not None:
            self._streaming.cancel()
            await asyncio.gather(self._streaming, return_exceptions=True)
            self._streaming = None

    async def _stream(self) -> None:
        period = 1.0 / self.spec.headset_hz
        step = self.spec.turn_deg_s * period
        while True:
            await asyncio.sleep(period)
            error = self.target - self.yaw
            self.yaw += max(-step, min(step, error))
            await self.client.publish(names.HEAD_POSE_TOPIC, head_pose(self.yaw))

    async def _call(self, service: str, args: dict[str, Any]) -> None:
        try:
            await self.client.call(service, args)
        except Refused as exc:
            self.refusals.append(f"{service}: {exc.message}")
