"""A network profile on an in-process connection (`study run --network lan,continent` at `--speed max`): every
frame the teacher sends and every frame she receives goes through the profile's impairment model (netem/model.py's
Direction, a pure seeded model: delay, jitter, bandwidth, loss), on the server's clock, simulated or not.

The connection is a WebSocket's (TCP): a frame the model loses is not lost but sent again one retransmission
time-out later (RTO_MIN_S plus the profile's round trip, as Linux does at its floor), and nothing overtakes a frame
ahead of it (head-of-line blocking). It wraps the transport's LocalConnection as it is (send, iterate, close):
the server's transport needs nothing of it.
"""

from __future__ import annotations

import asyncio
import heapq
import itertools
from collections.abc import AsyncIterator
from typing import Any

from netem.model import Direction, Profile, load_profiles

from simclock import Clock

RTO_MIN_S = 0.2


def profiles(names: list[str]) -> dict[str, Profile]:
    """The named profiles of netem/profiles.yaml; ValueError naming an unknown one and the known ones."""
    known = load_profiles()
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(f"--network: unknown profile {', '.join(unknown)}; the profiles are {', '.join(known)}")
    return {n: known[n] for n in names}


class _Link:
    """One direction: frames in, each delivered in order when the model says."""

    def __init__(self, direction: Direction, rtt_s: float, clock: Clock) -> None:
        self.model = direction
        self.rto = RTO_MIN_S + rtt_s
        self.clock = clock
        self.last = 0.0
        self.queue: list[tuple[float, int, Any]] = []
        self.order = itertools.count()
        self.ready = asyncio.Event()
        self.retransmitted = 0

    def put(self, frame: str | bytes) -> None:
        now = self.clock.monotonic()
        size = len(frame)
        at = self.model.admit(size, now)
        while at is None:  # lost: TCP sends it again after its time-out
            self.retransmitted += 1
            now += self.rto
            at = self.model.admit(size, now)
        self.last = max(self.last, at)
        heapq.heappush(self.queue, (self.last, next(self.order), frame))
        self.ready.set()

    async def get(self) -> Any:
        while True:
            if not self.queue:
                self.ready.clear()
                await self.ready.wait()
                continue
            at = self.queue[0][0]
            wait = at - self.clock.monotonic()
            if wait > 0:
                self.ready.clear()
                try:
                    await asyncio.wait_for(self.ready.wait(), wait)
                except TimeoutError:
                    pass
                continue
            return heapq.heappop(self.queue)[2]


class ImpairedConnection:
    """A LocalConnection through `profile`: up is client -> server, down is server -> client."""

    def __init__(self, inner: Any, profile: Profile, clock: Clock, seed: int) -> None:
        self.inner = inner
        self.profile = profile
        rtt = profile.rtt_ms / 1e3
        self.up = _Link(Direction(profile.up, seed * 2 + 1), rtt, clock)
        self.down = _Link(Direction(profile.down, seed * 2 + 2), rtt, clock)
        self._sender = asyncio.ensure_future(self._deliver_up())
        self._reader = asyncio.ensure_future(self._read_down())
        self.closed = False

    async def send(self, frame: str | bytes) -> None:
        if self.closed:
            raise ConnectionError("the connection is closed")
        self.up.put(frame)

    async def _deliver_up(self) -> None:
        while True:
            frame = await self.up.get()
            await self.inner.send(frame)

    async def _read_down(self) -> None:
        async for frame in self.inner:
            self.down.put(frame)

    async def __aiter__(self) -> AsyncIterator[str | bytes]:
        while not self.closed:
            yield await self.down.get()

    async def close(self) -> None:
        self.closed = True
        for task in (self._sender, self._reader):
            task.cancel()
        await asyncio.gather(self._sender, self._reader, return_exceptions=True)
        await self.inner.close()
