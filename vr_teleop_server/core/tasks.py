"""Background tasks: the one way the server's parts run a periodic job, and cancel what they started and wait for
it to end."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable

log = logging.getLogger(__name__)


async def cancel_and_wait(*tasks: asyncio.Future | None) -> None:
    """Cancels each task (None and finished ones are skipped) and waits until all have ended.

    The tasks' own CancelledError is the expected outcome, not an error of the caller's; any other exception a
    task ended with is raised, as awaiting it would.
    """
    live = [t for t in tasks if t is not None]
    for task in live:
        task.cancel()
    for task in live:
        with contextlib.suppress(asyncio.CancelledError):
            await task


async def every(period: float, step: Callable[[], None], what: str) -> None:
    """Calls `step` every `period` seconds on the running loop's clock (the server's, simulated or not) until
    cancelled. After a stall it goes on from now rather than catching up in a burst; a step that fails is logged
    (as `what`) and the next one runs."""
    loop = asyncio.get_running_loop()
    next_at = loop.time()
    while True:
        try:
            step()
        except Exception:  # a periodic job must survive anything one step does
            log.exception("%s failed", what)
        next_at += period
        delay = next_at - loop.time()
        if delay < -period:
            next_at = loop.time()
        await asyncio.sleep(max(0.0, delay))
