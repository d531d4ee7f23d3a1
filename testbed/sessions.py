"""The synthesised classroom session (`vr-teleop synth classroom`, seed 0) as replay steps: the session the replay and
WAN benches drive a server with."""

from __future__ import annotations

import tempfile
from pathlib import Path

from vr_teleop_server.tools.replay import Step, load_steps
from vr_teleop_server.tools.synth import build, write


def classroom_steps(first_s: float | None = None) -> list[Step]:
    """The classroom session's steps in time order, with `first_s` only those of its first seconds."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "classroom.mcap"
        write(build("classroom", seed=0), path)
        steps, _ = load_steps(path)
    return steps if first_s is None else [s for s in steps if s.t < first_s]
