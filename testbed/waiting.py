"""Waiting, for the tests and benches (testbed/server.py re-exports it): `wait_for` polls a condition with a
deadline from a thread, `until` the same from a coroutine, `Pace` paces a real-time source. Imports nothing of the
server's, so that a light helper (the WebRTC client, the WAN harness) can use it."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable
from typing import Any


def wait_for(predicate: Callable[[], Any], timeout: float = 5.0) -> bool:
    """Polls `predicate` until it is true or `timeout` seconds pass (the backstop: a condition the design
    guarantees comes well before it), then tries it a last time."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)  # polling: the harness's one blocking wait for a condition nothing signals
    return bool(predicate())


async def until(predicate: Callable[[], Any], timeout: float, interval: float = 0.02,
                blocking: bool = False) -> bool:
    """wait_for without blocking the running loop (a peer, a headset or a robot may live on it): polls `predicate`
    every `interval` seconds of the loop until it is true or `timeout` seconds pass, then tries it a last time.
    `blocking`: the predicate blocks (it asks a server in another thread), so it runs in a thread of its own."""
    async def check() -> bool:
        return bool(await asyncio.to_thread(predicate) if blocking else predicate())

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if await check():
            return True
        await asyncio.sleep(interval)  # polling: the harness's one wait in a loop for a condition nothing signals
    return await check()


class Pace:
    """Paces a real-time source (a headset at 90 Hz, a microphone's chunks, a link's packets): `wait()` (a thread)
    or `await tick()` (a loop) after each item. `catch_up`: a late item is followed at once by the next (a
    microphone's samples keep their rate on average); otherwise the next is a period after the late one (a headset
    drops frames). `tick(period)`: this item's own length instead (a packet takes its size's time on a link)."""

    def __init__(self, hz: float, catch_up: bool = True) -> None:
        self.period = 1.0 / hz
        self.catch_up = catch_up
        self.next = time.monotonic()

    def _left(self, period: float | None = None) -> float:
        now = time.monotonic()
        period = self.period if period is None else period
        self.next = self.next + period if self.catch_up else max(self.next + period, now)
        return max(0.0, self.next - now)

    def wait(self, stop: threading.Event | None = None) -> bool:
        """Until the next item is due, or `stop` is set (then True)."""
        if stop is not None:
            return stop.wait(self._left())
        time.sleep(self._left())  # the source's own pace: what it plays is real time
        return False

    async def tick(self, period: float | None = None) -> None:
        await asyncio.sleep(self._left(period))  # the source's own pace: what it plays is real time
