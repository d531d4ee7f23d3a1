"""The simulated clock and its event loop (simclock): timers fire in order at their simulated times without the
loop ever sleeping for one, work in threads holds the clock, participants are brought along in time order, and a
run is the same every time."""

from __future__ import annotations

import asyncio
import math
import random
import threading

import pytest

import simclock
from simclock import WALL, SimulatedClock


def test_timers_fire_in_order_at_their_simulated_times_without_waiting_for_the_wall_clock():
    clock = SimulatedClock()
    fired: list[tuple[str, float]] = []

    async def after(delay: float, tag: str) -> None:
        await asyncio.sleep(delay)  # simulated time: the clock jumps to it
        fired.append((tag, asyncio.get_running_loop().time()))

    async def main() -> None:
        await asyncio.gather(after(3600.0, "hour"), after(1.0, "second"), after(0.5, "half"), after(60.0, "minute"))
        with pytest.raises(TimeoutError):  # timeouts are timers too
            await asyncio.wait_for(asyncio.sleep(1e6), 2.0)  # simulated time: the clock jumps to it
        fired.append(("timeout", asyncio.get_running_loop().time()))

    simclock.run(main(), clock)
    assert fired == [("half", 0.5), ("second", 1.0), ("minute", 60.0), ("hour", 3600.0), ("timeout", 3602.0)]
    assert clock.monotonic() == 3602.0 and clock.time() == simclock.EPOCH + 3602.0
    assert clock.real_waits == 0  # no wall-clock wait on the way: the loop jumped to each timer
    assert clock.jumps >= 5


def test_work_in_a_thread_holds_the_clock_until_its_result_is_back():
    clock = SimulatedClock()

    async def main() -> tuple[float, float, float]:
        loop = asyncio.get_running_loop()
        ticker = asyncio.ensure_future(asyncio.sleep(1.0))  # in simulated time: a timer the loop would jump to
        started = threading.Event()

        def work() -> float:
            started.set()
            threading.Event().wait(0.05)  # wall time the simulated clock must not skip over
            return clock.monotonic()

        before = loop.time()
        during = await asyncio.to_thread(work)
        after = loop.time()
        await ticker
        assert started.is_set()
        return before, during, after

    before, during, after = simclock.run(main(), clock)
    assert before == during == after == 0.0
    assert clock.monotonic() == 1.0 and clock.real_waits > 0  # the loop waited for the thread, not for a timer


class Metronome:
    """A participant due every `period` simulated seconds."""

    def __init__(self, clock: SimulatedClock, period: float) -> None:
        self.clock, self.period, self.next = clock, period, period
        self.calls: list[float] = []

    def next_due(self) -> float:
        return self.next

    def advance_to(self, t: float) -> None:
        self.calls.append(t)
        if t >= self.next:
            self.next += self.period


def test_participants_are_brought_along_in_time_order_and_stopped_at_when_due():
    clock = SimulatedClock()
    metronome = Metronome(clock, 0.25)
    clock.attach(metronome)
    seen: list[tuple[float, float]] = []

    async def main() -> None:
        await asyncio.sleep(0.6)  # simulated time: the clock jumps to it
        seen.append((asyncio.get_running_loop().time(), metronome.calls[-1]))
        await asyncio.sleep(0.4)  # simulated time: the clock jumps to it

    simclock.run(main(), clock)
    assert metronome.calls == sorted(metronome.calls)
    assert [0.25, 0.5, 0.75, 1.0] == [t for t in metronome.calls if t in (0.25, 0.5, 0.75, 1.0)]
    assert seen == [(0.6, 0.6)]  # brought to the loop's time before the loop's callbacks run
    clock.detach(metronome)
    clock.advance(5.0)
    assert metronome.calls[-1] == 1.0


def test_a_simulated_run_is_the_same_every_time():
    def trace() -> list[tuple[str, float]]:
        clock = SimulatedClock()
        out: list[tuple[str, float]] = []

        async def worker(name: str, rng: random.Random) -> None:
            for _ in range(50):
                await asyncio.sleep(rng.uniform(0.0, 0.1))  # simulated time: the clock jumps to it
                out.append((name, asyncio.get_running_loop().time()))
                if rng.random() < 0.1:
                    await asyncio.to_thread(sum, range(1000))

        async def main() -> None:
            await asyncio.gather(*(worker(f"w{i}", random.Random(i)) for i in range(5)))

        simclock.run(main(), clock)
        return out

    first = trace()
    assert len(first) == 250 and first == trace()


def test_the_clock_refuses_to_go_back_and_unbalanced_releases():
    clock = SimulatedClock()
    clock.advance(2.0)
    with pytest.raises(ValueError, match="does not go back"):
        clock.advance_to(1.0)
    with pytest.raises(RuntimeError, match="without a hold"):
        clock.release()


def test_the_wall_clock_is_the_default_and_runs_on_asyncios_own_loop():
    async def main() -> bool:
        return isinstance(asyncio.get_running_loop(), simclock.SimulatedEventLoop) or simclock.loop_clock() is not WALL

    assert simclock.run(main()) is False
    assert not WALL.simulated and math.isfinite(WALL.monotonic()) and WALL.time() > simclock.EPOCH - 1e9
