"""The fuzz campaign: over 10,000 hostile frames a run (a fixed seed, then a random one that is printed; FUZZ_SEED
fixes it, and every failure says the command that replays the same frames), against
a server with the MuJoCo stand-in, with the invariants checked after every frame:

- the server is alive, and the sender's connection still works: each frame is followed by a probe (a publish on
  the sender's own topic) that must come back, in order; a frame over the hard size limit must close the
  connection with 1009 instead (the client then reconnects);
- what the protocol demands of that frame came before the probe: a status error for a frame the op models or
  message types reject (tests/fuzz_frames.py's oracle), the reassembled message for a completed fragment set;
- a bystander client subscribed to the joint states never sees an error and keeps receiving them;
- no joint target outside robot_models' limits ever reached the simulation, no command the server published
  was outside them, and the joints stayed within them.

Two fuzzing clients share ids (fragment sets, calls, goals, subscriptions) so that ids collide across clients.
Frames are pipelined over few connections so that the campaign takes well under a minute of CPU.
"""

from __future__ import annotations

import asyncio
import json
import math
import os
import random
import threading
import time
from collections.abc import Callable
from typing import Any

import pytest
from fuzz_frames import (
    HARD_FACTOR,
    MAX_MESSAGE,
    PROBE_PREFIX,
    WRONG_MESSAGES,
    WRONG_OPS,
    Frame,
    _dumps,
    expected,
    fragment_sets,
    frame_payloads,
)
from hypothesis import HealthCheck, Phase, given, seed, settings
from hypothesis import strategies as st
from support import RunningServer
from testbed.server import until
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed

from robot_models import load_qtrobot
from vr_teleop_server.core.bus import SERVER_NODE

pytestmark = pytest.mark.slow  # campaigns of thousands of frames

FIXED_SEED = 20261123
FRAMES_PER_SEED = 5_000 if os.environ.get("FUZZ_FRAMES") is None else int(os.environ["FUZZ_FRAMES"])
RANDOM_SEED = None if os.environ.get("FUZZ_SEED") is None else int(os.environ["FUZZ_SEED"])  # fixes the "random" run
WINDOW = 48  # frames in flight per client before the probes are checked
MODEL = load_qtrobot()
JOINT_TOLERANCE_DEG = 3.0  # the simulated joints may overshoot a limit slightly under load and gravity


class Campaign(AssertionError):
    pass


class FuzzClient:
    """One fuzzing connection: sends frames each followed by a numbered probe, and checks what came back."""

    def __init__(self, url: str, index: int, label: str) -> None:
        self.url = url
        self.index = index
        self.label = label
        self.topic = f"{PROBE_PREFIX}/{index}"
        self.ws: ClientConnection | None = None
        self.seq = 0
        self.level = "error"
        # (probe number, frame, status errors due by then) not yet confirmed. Replies may overtake topic messages
        # (the server sends them first), so errors are counted: by probe k, at least as many as frames up to k
        # that had to get one.
        self.pending: list[tuple[int, Frame, int]] = []
        self.required = 0
        self.errors_seen = 0
        self.inbox: asyncio.Queue[str | bytes | None] = asyncio.Queue()
        self.reader: asyncio.Task[None] | None = None
        self.reconnects = 0

    async def open(self) -> None:
        self.ws = await connect(self.url, compression=None, max_size=None, open_timeout=20)
        self.inbox = asyncio.Queue()
        self.reader = asyncio.create_task(self._read(self.ws, self.inbox))
        self.level = "error"
        self.required = self.errors_seen = 0
        await self.ws.send(_dumps({"op": "subscribe", "topic": self.topic, "type": "std_msgs/String"}))
        await self.ws.send(_dumps({"op": "advertise", "topic": self.topic, "type": "std_msgs/String"}))

    @staticmethod
    async def _read(ws: ClientConnection, inbox: asyncio.Queue) -> None:
        try:
            async for frame in ws:
                inbox.put_nowait(frame)
        except ConnectionClosed:
            pass
        inbox.put_nowait(None)

    async def close(self) -> None:
        if self.ws is not None:
            await self.ws.close()
        if self.reader is not None:
            await self.reader

    async def send(self, frame: Frame) -> None:
        assert self.ws is not None
        if frame.expect == "close":
            await self.settle()
            await self.ws.send(frame.payload)
            await self._expect_close(frame)
            return
        await self.ws.send(frame.payload)
        self.seq += 1
        if frame.expect == "error" and self.level != "none":
            self.required += 1
        self.pending.append((self.seq, frame, self.required))
        await self.ws.send(_dumps({"op": "publish", "topic": self.topic, "msg": {"data": f"p:{self.seq}"}}))
        self._track_level(frame)
        if len(self.pending) >= WINDOW:
            await self.settle()

    def _track_level(self, frame: Frame) -> None:
        if isinstance(frame.payload, str) and '"set_level"' in frame.payload and expected(frame.payload) is None:
            try:
                value = json.loads(frame.payload)
            except ValueError:
                return
            if isinstance(value, dict) and value.get("op") == "set_level":
                self.level = value["level"]

    async def _expect_close(self, frame: Frame) -> None:
        assert self.ws is not None
        while await asyncio.wait_for(self.inbox.get(), 30) is not None:
            pass
        if self.ws.close_code != 1009:
            raise Campaign(f"{self.label}: a frame of {len(frame.payload)} bytes (over {MAX_MESSAGE * HARD_FACTOR}) "
                           f"should close the connection with 1009, got {self.ws.close_code}")
        self.reconnects += 1
        await self.open()

    async def settle(self) -> None:
        """Reads until every probe sent so far came back, checking each frame's slice of replies."""
        replies: list[Any] = []
        while self.pending:
            try:
                raw = await asyncio.wait_for(self.inbox.get(), 30)
            except TimeoutError:
                raise Campaign(self._fault("no probe came back within 30 s: the connection or the server hangs",
                                           replies)) from None
            if raw is None:
                raise Campaign(self._fault(f"the connection closed (code {self.ws.close_code})", replies))
            message = _parse(raw)
            if message is None:
                replies.append(raw)  # CBOR from a subscription the fuzzer made: a frame, well-formed
                continue
            if not isinstance(message.get("op"), str):
                raise Campaign(self._fault(f"a frame without op came back: {str(raw)[:200]}", replies))
            data = message.get("msg", {}).get("data") if isinstance(message.get("msg"), dict) else None
            if message["op"] == "publish" and message.get("topic") == self.topic and isinstance(data, str) \
                    and data.startswith("p:"):
                number, frame, required = self.pending.pop(0)
                if data != f"p:{number}":
                    raise Campaign(self._fault(f"probe {data} came back when p:{number} was due", replies, frame))
                if self.errors_seen < required:
                    raise Campaign(self._fault(f"{required - self.errors_seen} frame(s) the protocol rejects got no "
                                               f"status error (the last sent is shown)", replies, frame))
                self._check(frame, replies)
                replies = []
            else:
                if message["op"] == "status" and message.get("level") == "error":
                    self.errors_seen += 1
                replies.append(message)

    def _check(self, frame: Frame, replies: list[Any]) -> None:
        if frame.expect is not None and frame.expect.startswith("echo:"):
            marker = frame.expect[5:]
            if not any(isinstance(r, dict) and r.get("topic") == self.topic and r.get("msg", {}).get("data") == marker
                       for r in replies):
                raise Campaign(self._fault("a completed fragment set was not delivered", replies, frame))

    def _fault(self, what: str, replies: list[Any], frame: Frame | None = None) -> str:
        frame = frame or (self.pending[0][1] if self.pending else None)
        shown = "" if frame is None else f"; the frame ({frame.kind}): {str(frame.payload)[:300]!r}"
        return f"{self.label}: {what}{shown}; replies: {str(replies)[:600]}"


def _parse(raw: str | bytes) -> dict[str, Any] | None:
    if isinstance(raw, bytes):
        return None
    value = json.loads(raw)  # a server frame that is not JSON fails the campaign here
    if not isinstance(value, dict):
        raise Campaign(f"the server sent a JSON value that is not an object: {raw[:200]}")
    return value


class Bystander:
    """A client that only watches the joint states. It must never see an error or a frame it did not ask for,
    its stream must go on (fresh joint states after the campaign, see keeps_receiving), and its joint positions
    must stay within the limits. The worst gap is only printed: on a loaded machine it says nothing."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.count = 0
        self.last = time.monotonic()
        self.worst_gap = 0.0
        self.problems: list[str] = []
        self.task: asyncio.Task[None] | None = None
        self.ready = asyncio.Event()

    async def run(self) -> None:
        async with connect(self.url, compression=None, max_size=None) as ws:
            await ws.send(_dumps({"op": "subscribe", "topic": "/qt_robot/joints/state",
                                  "type": "sensor_msgs/JointState"}))
            async for raw in ws:
                message = json.loads(raw)
                now = time.monotonic()
                if message.get("op") != "publish" or message.get("topic") != "/qt_robot/joints/state":
                    self.problems.append(str(raw)[:300])
                    continue
                if self.count:
                    self.worst_gap = max(self.worst_gap, now - self.last)
                self.count += 1
                self.last = now
                self.ready.set()
                for name, deg in zip(message["msg"]["name"], message["msg"]["position"]):
                    j = MODEL.joint(name)
                    if not (j.lower - JOINT_TOLERANCE_DEG <= deg <= j.upper + JOINT_TOLERANCE_DEG):
                        self.problems.append(f"joint {name} at {deg:.1f} deg, limits [{j.lower}, {j.upper}]")

    def check(self) -> None:
        if self.problems:
            raise Campaign(f"the bystander noticed: {self.problems[:5]}")
        if self.task is not None and self.task.done():
            raise Campaign(f"the bystander's connection ended: {self.task.exception()!r}")

    async def keeps_receiving(self, timeout: float = 30.0) -> None:
        """A few more joint states arrive (the timeout only catches a stream that stopped)."""
        start = self.count

        def more() -> bool:
            self.check()
            return self.count >= start + 3

        if not await until(more, timeout):
            raise Campaign(f"the bystander got {self.count - start} joint states in {timeout:g} s after the "
                           "campaign: its stream stopped")


class CommandLog:
    """Every joint target handed to the simulation, and every joint command the server published."""

    def __init__(self, server: RunningServer) -> None:
        self.lock = threading.Lock()
        self.targets: list[dict[str, float]] = []
        self.published: list[tuple[str, list[float]]] = []
        app = server.server
        standin = app.robot.standin
        original = standin.set_targets

        def recorded(targets):
            with self.lock:
                self.targets.append(dict(targets))
            return original(targets)

        standin.set_targets = recorded

        def tap(published) -> None:
            if published.sender == SERVER_NODE and published.topic.endswith("_position/command"):
                with self.lock:
                    self.published.append((published.topic, list(published.data["data"])))

        server.call(lambda: app.bus.taps.append(tap))

    def check(self) -> int:
        with self.lock:
            targets, published = list(self.targets), list(self.published)
        for t in targets:
            for name, deg in t.items():
                j = MODEL.joint(name)
                if not (math.isfinite(float(deg)) and j.lower <= float(deg) <= j.upper):
                    raise Campaign(f"the simulation was told {name} = {deg} (limits [{j.lower}, {j.upper}])")
        for topic, data in published:
            part = topic.split("/")[2].removesuffix("_position")
            for name, deg in zip(MODEL.part_joints(part), data):
                j = MODEL.joint(name)
                if not (math.isfinite(deg) and j.lower <= deg <= j.upper):
                    raise Campaign(f"the server published {topic} with {name} = {deg}")
        return len(targets)


@pytest.fixture(scope="module")
def fuzz_server(module_servers):
    server = module_servers(backend="sim", max_message_size=MAX_MESSAGE, hard_frame_factor=HARD_FACTOR,
                            fragment_timeout=2.0, camera_width=64, camera_height=48, camera_fps=5,
                            service_timeout=2.0)
    return server, CommandLog(server)


class Run:
    """The campaign's clients on one event loop, kept across hypothesis examples."""

    def __init__(self, url: str, label: str, commands: CommandLog) -> None:
        self.commands = commands
        self.loop = asyncio.new_event_loop()
        self.clients = [FuzzClient(url, i, f"{label} client {i}") for i in (0, 1)]
        self.bystander = Bystander(url)
        self.frames = 0
        self.counter = [0]
        self.loop.run_until_complete(self._open())

    async def _open(self) -> None:
        self.bystander.task = asyncio.create_task(self.bystander.run())
        await asyncio.wait_for(self.bystander.ready.wait(), 20)
        for c in self.clients:
            await c.open()

    def send(self, frames: list[Frame]) -> None:
        async def go() -> None:
            for frame in frames:
                await self.clients[frame.conn].send(frame)
                self.frames += 1
            for c in self.clients:
                await c.settle()
        self.loop.run_until_complete(go())
        self.bystander.check()
        self.commands.check()

    def close(self) -> None:
        async def shut() -> None:
            for c in self.clients:
                await c.close()
            if self.bystander.task is not None:
                self.bystander.task.cancel()
                await asyncio.gather(self.bystander.task, return_exceptions=True)
        self.loop.run_until_complete(shut())
        self.loop.close()


def _single(conn: int, payload: str | bytes) -> Frame:
    return Frame(conn, payload, expected(payload), "single")


@st.composite
def batches(draw: st.DrawFn, counter: list[int]) -> list[Frame]:
    frames: list[Frame] = []
    for _ in range(draw(st.integers(20, 40))):
        conn = draw(st.sampled_from([0, 1]))
        what = draw(st.sampled_from(["frame"] * 8 + ["fragments", "collide"]))
        if what == "frame":
            frames.append(_single(conn, draw(frame_payloads())))
        elif what == "fragments":
            frames += draw(fragment_sets(conn, f"{PROBE_PREFIX}/{conn}", counter))
        else:  # both clients send a set under the same id, piece by piece interleaved
            a = draw(fragment_sets(0, f"{PROBE_PREFIX}/0", counter))
            b = draw(fragment_sets(1, f"{PROBE_PREFIX}/1", counter))
            frames += [f for pair in zip(a, b) for f in pair] + a[len(b):] + b[len(a):]
    return frames


def play_round(campaign_seed: int, round_no: int, counter: list[int], sink: Callable[[list[Frame]], None]) -> None:
    """One round of examples, seeded from the campaign's seed and the round's number: the same seed draws the
    same frames in the same order (test_a_seed_draws_the_same_frames_again), which is what FUZZ_SEED relies on."""
    @settings(max_examples=40, database=None, deadline=None, phases=[Phase.generate],
              suppress_health_check=list(HealthCheck))
    @seed(campaign_seed + round_no)
    @given(data=st.data())
    def campaign(data) -> None:
        sink(data.draw(batches(counter)))

    campaign()


def rerun_hint(campaign_seed: int) -> str:
    """Both runs share one server, in order: the whole module again replays the same frames into the same state."""
    return (f"rerun with FUZZ_SEED={campaign_seed} FUZZ_FRAMES={FRAMES_PER_SEED} "
            f"pytest tests/test_fuzz_campaign.py")


@pytest.mark.timeout(900)  # three rounds of drawing: under a minute idle, minutes on a loaded machine
def test_a_seed_draws_the_same_frames_again():
    def draw(campaign_seed: int) -> list[tuple[int, str | bytes, str | None]]:
        frames: list[Frame] = []
        counter = [0]
        play_round(campaign_seed, 1, counter, frames.extend)
        return [(f.conn, f.payload, f.expect) for f in frames]

    first = draw(12345)
    assert len(first) > 500
    assert draw(12345) == first
    assert draw(12346) != first


@pytest.mark.timeout(1800)  # a minute idle, several on a loaded machine: the timeout only catches a hang
@pytest.mark.parametrize("which", ["fixed", "random"])
def test_fuzz_campaign(fuzz_server, which):
    server, commands = fuzz_server
    if which == "fixed":
        campaign_seed = FIXED_SEED
    else:
        campaign_seed = RANDOM_SEED if RANDOM_SEED is not None else random.SystemRandom().randrange(2**32)
    hint = rerun_hint(campaign_seed)
    print(f"fuzz campaign seed: {campaign_seed} ({which}); {hint}", flush=True)
    label = f"seed {campaign_seed}"
    run = Run(server.url, label, commands)
    try:
        if which == "fixed":  # every wrong-typed field of every op and of every message a client publishes
            table = WRONG_OPS + WRONG_MESSAGES
            for start in range(0, len(table), 200):
                run.send([_single(i % 2, _dumps(f)) for i, f in enumerate(table[start:start + 200])])

        rounds = 0
        while run.frames < FRAMES_PER_SEED:  # rounds of examples, each seeded from the campaign's seed
            play_round(campaign_seed, rounds, run.counter, run.send)
            rounds += 1
        assert run.frames >= FRAMES_PER_SEED, f"{label}: only {run.frames} frames were generated"
        issued = commands.check()
        run.loop.run_until_complete(run.bystander.keeps_receiving())
        assert server.thread.is_alive()
        print(f"{label}: {run.frames} frames, {sum(c.reconnects for c in run.clients)} closed with 1009, "
              f"{issued} joint commands reached the simulation, bystander got {run.bystander.count} joint states "
              f"(worst gap {run.bystander.worst_gap:.2f} s)")
    except Exception as exc:  # noqa: BLE001 (whatever failed, say how to replay it)
        raise AssertionError(f"{label}: {exc}\n{hint}") from (None if isinstance(exc, Campaign) else exc)
    finally:
        run.close()
