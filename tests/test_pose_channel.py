"""The poses data channel's checks, sans I/O: messages in, the frames handed to the session out."""

from __future__ import annotations

import asyncio
import json

from vr_teleop_server.media.poses import PoseChannel

HEAD = "/vr/head/pose"
JOY = "/vr/right_controller/joy"


class FakeSession:
    """Records what the channel hands over; refuses (as the real session does, with a status error) a frame whose
    msg is not an object."""

    def __init__(self) -> None:
        self.name = "client-1"
        self.closed = False
        self.counters = {"errors": 0}
        self.last_error = ""
        self.frames: list[dict] = []
        self.statuses: list[str] = []

    async def handle_frame(self, frame: str) -> None:
        parsed = json.loads(frame)
        if not isinstance(parsed["msg"], dict):
            self.counters["errors"] += 1
            self.last_error = f"{parsed['topic']}: msg must be an object"
            return
        self.frames.append(parsed)

    def status(self, level: str, message: str) -> None:
        self.statuses.append(message)


def publish(topic: str, stamp: float, **extra) -> dict:
    secs = int(stamp)
    return {"op": "publish", "topic": topic,
            "msg": {"header": {"stamp": {"secs": secs, "nsecs": int(round((stamp - secs) * 1e9))}}, **extra}}


def deliver(channel: PoseChannel, *messages: str) -> None:
    async def run() -> None:
        for message in messages:
            await channel.on_message(message)
    asyncio.run(run())


class Ticking:
    """A clock two seconds later at each reading (simclock.Clock's shape)."""
    simulated = True

    def __init__(self, step: float) -> None:
        self.step, self.now = step, -step

    def monotonic(self) -> float:
        self.now += self.step
        return self.now

    def time(self) -> float:
        return self.monotonic()


def test_good_frames_are_handed_over_in_order_and_bad_ones_refused_and_counted() -> None:
    session = FakeSession()
    channel = PoseChannel(session, lambda name: name == "client-1", clock=Ticking(2.0))
    deliver(channel, json.dumps(publish(HEAD, 100.0)),
            json.dumps({"op": "publish", "topic": "/qt_robot/head_position/command", "msg": {}}),
            json.dumps(publish(JOY, 100.0)), json.dumps({"op": "subscribe", "topic": HEAD}),
            json.dumps({"op": "publish", "topic": HEAD, "msg": 3}), json.dumps([publish(HEAD, 101.0)]))
    assert [f["topic"] for f in session.frames] == [HEAD, JOY]
    assert channel.counts.received == 6 and channel.counts.refused == 4
    assert "is not 'publish'" in channel.counts.last_refusal  # the array: one frame a message
    assert "msg must be an object" in session.last_error
    told = [m.split(": refused: ")[1] for m in session.statuses]  # each refusal a clock second apart: all told
    assert len(told) == 3 and told[0].startswith("topic '/qt_robot/head_position/command' is not one")
    assert told[1].startswith("op 'subscribe'") and told[2].startswith("op 'None'")


def test_stale_frames_are_dropped_by_stamp() -> None:
    session = FakeSession()
    channel = PoseChannel(session, lambda name: True)
    deliver(channel, *(json.dumps(f) for f in [publish(HEAD, 100.2), publish(HEAD, 100.1), publish(JOY, 100.1),
                                               publish(HEAD, 100.15), publish(HEAD, 100.3), publish(HEAD, 90.0)]))
    heads = [f["msg"]["header"]["stamp"] for f in session.frames if f["topic"] == HEAD]
    # 90.0 is more than CLOCK_RESET_S behind: a headset clock that started over, taken
    assert heads == [{"secs": 100, "nsecs": 200_000_000}, {"secs": 100, "nsecs": 300_000_000},
                     {"secs": 90, "nsecs": 0}]
    assert channel.counts.stale_dropped == 2 and channel.counts.refused == 0


def test_not_holding_control_refuses_every_frame() -> None:
    session = FakeSession()
    channel = PoseChannel(session, lambda name: False)
    deliver(channel, json.dumps(publish(HEAD, 100.0)), json.dumps(publish(JOY, 100.0)))
    assert session.frames == [] and channel.counts.refused == 2
    assert "does not hold control" in channel.counts.last_refusal
