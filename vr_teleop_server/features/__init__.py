"""What runs on the bus: each feature takes its collaborators in its constructor and has `start()` / `async stop()`.

app.py builds them, starts them in order and stops them in reverse; nothing is injected after construction.
"""

from __future__ import annotations

from typing import Protocol


class Feature(Protocol):
    def start(self) -> None:
        """Declares its topics and services on the bus and starts its background tasks."""

    async def stop(self) -> None:
        """Cancels its tasks and lets go of what it holds; called once, in the reverse order of start."""
