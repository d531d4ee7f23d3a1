"""Stopping background tasks: the one way the server's parts cancel what they started and wait for it to end."""

from __future__ import annotations

import asyncio
import contextlib


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
