"""A trial that ran past `study run --timeout`: an error the command line words as a sentence (exit code 2)."""

from __future__ import annotations

from pathlib import Path


class TrialTimedOut(Exception):
    """A trial that did not end within its `--timeout` (seconds on the trial's clock)."""

    def __init__(self, name: str, timeout: float, simulated: bool, recording: Path | None) -> None:
        self.name, self.timeout, self.simulated, self.recording = name, timeout, simulated, recording
        on = "simulated s" if simulated else "s"
        kept = f"; its recording {recording} holds what happened until then" if recording is not None else ""
        super().__init__(f"trial {name} stopped by --timeout: not finished after {timeout:g} {on}{kept}")

    def __reduce__(self):  # raised in a worker process, read in the client
        return (TrialTimedOut, (self.name, self.timeout, self.simulated, self.recording))
