"""The server's one clock: the wall clock in real use, a simulated clock in replays and studies at `--speed max`.

A `Clock` answers two questions: `monotonic()` (seconds, for intervals and deadlines) and `time()` (seconds since
the epoch, for message headers and recordings). `WALL` is the machine's clocks; every parameter that takes a
clock defaults to it, so code that is given none keeps its real-time behaviour.

A `SimulatedClock` advances only when told to. `SimulatedEventLoop` is an asyncio loop whose `time()` is such a
clock and which, when nothing is ready (no callback queued, no socket readable, no thread working for it), jumps
the clock to the next timer instead of sleeping: asyncio code (sleeps, `wait_for`, timeouts, websockets) runs
unchanged and as fast as the work allows, timers firing in order. Work the loop cannot see counts itself in with
`hold()`/`release()` (the loop's executor does so for every `run_in_executor` and `asyncio.to_thread`), and so
holds the clock still until it is done. Parts that live in simulated time between the loop's turns (the
stand-in's physics and camera) `attach()` a participant: the clock asks it how far it may jump
(`next_due()`) and brings it along (`advance_to(t)`), in the loop's thread, so they move in lock-step with it.
Nothing here depends on the wall clock, so a simulated run is as deterministic as the work it runs.
"""

from __future__ import annotations

import asyncio
import math
import selectors
import threading
import time
from collections.abc import Awaitable, Callable
from typing import Any, Protocol, TypeVar

T = TypeVar("T")
EPOCH = 1_767_225_600.0  # 2026-01-01T00:00:00Z: where a simulated clock's time() starts, unless told otherwise


class Clock(Protocol):
    def monotonic(self) -> float: ...

    def time(self) -> float: ...

    @property
    def simulated(self) -> bool: ...


class WallClock:
    """The machine's clocks."""

    simulated = False

    @staticmethod
    def monotonic() -> float:
        return time.monotonic()

    @staticmethod
    def time() -> float:
        return time.time()

    def __repr__(self) -> str:
        return "WALL"


WALL = WallClock()


class Participant(Protocol):
    """Something that lives in simulated time between the loop's turns (a physics engine, a camera)."""

    def next_due(self) -> float:
        """The next simulated time it must act at (math.inf: none); the clock jumps no further than that."""

    def advance_to(self, t: float) -> None:
        """Bring it to simulated time t (called in the loop's thread, in time order, t never decreasing)."""


class SimulatedClock:
    """A clock that moves only when advanced; monotonic() starts at 0, time() at `epoch`."""

    simulated = True

    def __init__(self, epoch: float = EPOCH) -> None:
        self._now = 0.0
        self._epoch = float(epoch)
        self._holds = 0
        self._lock = threading.Lock()
        self._participants: list[Participant] = []
        self.jumps = 0  # how often the clock jumped (for tests and benches)
        self.real_waits = 0  # how often the loop had to wait for the machine (held work, sockets)

    def monotonic(self) -> float:
        return self._now

    def time(self) -> float:
        return self._epoch + self._now

    def attach(self, participant: Participant) -> None:
        self._participants = [*self._participants, participant]

    def detach(self, participant: Participant) -> None:
        self._participants = [p for p in self._participants if p is not participant]

    def hold(self) -> None:
        """Work the loop cannot see has started: the clock stays where it is until release()."""
        with self._lock:
            self._holds += 1

    def release(self) -> None:
        with self._lock:
            if self._holds <= 0:
                raise RuntimeError("SimulatedClock.release() without a hold")
            self._holds -= 1

    @property
    def held(self) -> bool:
        return self._holds > 0

    def next_due(self) -> float:
        return min((p.next_due() for p in self._participants), default=math.inf)

    def advance_to(self, t: float) -> None:
        """Move to t, stopping at every participant's due time on the way so each acts when it should."""
        if t < self._now:
            raise ValueError(f"a clock does not go back: {t!r} < {self._now!r}")
        while True:
            due = self.next_due()
            stop = min(t, max(due, self._now))
            self._now = stop
            for p in self._participants:
                p.advance_to(stop)
            if stop >= t:
                return

    def advance(self, seconds: float) -> None:
        self.advance_to(self._now + seconds)

    def __repr__(self) -> str:
        return f"SimulatedClock(t={self._now:.6f})"


class _JumpingSelector(selectors.DefaultSelector):  # type: ignore[misc,valid-type]
    """Polls without waiting; when nothing is ready and nobody holds the clock, jumps it to the loop's next timer
    (or a participant's due time) instead of sleeping."""

    REAL_WAIT_S = 0.05  # how long one wait for held work lasts before looking again
    BUSY_POLL_EVERY = 16  # while callbacks are ready, sockets are polled on one turn in this many

    def __init__(self, clock: SimulatedClock) -> None:
        super().__init__()
        self.clock = clock
        self._busy_turns = 0

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        if timeout == 0:
            # Callbacks are ready, so the clock stays where it is this turn whatever the poll finds: polling on
            # every turn of a busy loop (a system call each) only sees the outside world a few turns sooner in
            # the same simulated instant. Threads' results need no poll (call_soon_threadsafe queues them).
            self._busy_turns += 1
            if self._busy_turns % self.BUSY_POLL_EVERY:
                return []
        events = super().select(0)
        if events or timeout == 0:
            return events
        clock = self.clock
        if clock.held:
            clock.real_waits += 1
            return super().select(self.REAL_WAIT_S if timeout is None else min(timeout, self.REAL_WAIT_S))
        target = clock.next_due()
        if timeout is not None:
            target = min(target, clock.monotonic() + timeout)
        if math.isinf(target):  # no timer, nothing due: only the outside world can wake us
            clock.real_waits += 1
            return super().select(None)
        clock.jumps += 1
        clock.advance_to(max(target, clock.monotonic()))
        return []


class SimulatedEventLoop(asyncio.SelectorEventLoop):
    """An asyncio loop on a SimulatedClock (see the module's docstring)."""

    def __init__(self, clock: SimulatedClock | None = None) -> None:
        self.clock = clock if clock is not None else SimulatedClock()
        super().__init__(_JumpingSelector(self.clock))
        self._clock_resolution = 1e-9

    def time(self) -> float:
        return self.clock.monotonic()

    def run_in_executor(self, executor: Any, func: Callable[..., T], *args: Any) -> asyncio.Future[T]:
        """As asyncio's, with the clock held until the result is back on the loop."""
        self.clock.hold()
        try:
            future = super().run_in_executor(executor, func, *args)
        except BaseException:
            self.clock.release()
            raise
        future.add_done_callback(lambda _f: self.clock.release())
        return future


def run(main: Awaitable[T], clock: Clock = WALL) -> T:
    """asyncio.run on the given clock: a SimulatedEventLoop for a simulated clock, asyncio's own loop otherwise."""
    if not isinstance(clock, SimulatedClock):
        return asyncio.run(main)  # type: ignore[arg-type]
    with asyncio.Runner(loop_factory=lambda: SimulatedEventLoop(clock)) as runner:
        return runner.run(main)  # type: ignore[arg-type]


def loop_clock() -> Clock:
    """The clock the running loop keeps (its SimulatedClock, else the wall clock)."""
    loop = asyncio.get_running_loop()
    return loop.clock if isinstance(loop, SimulatedEventLoop) else WALL
