"""Run study trials on the stand-in: a server of our own (sim backend, session recording), the trial's modules
on it, and the simulated participant, operator and experimenter as rosbridge clients. After each trial the
metrics are recomputed from the recording and compared with the live ones.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ..app import TeleopServer
from ..core.tasks import cancel_and_wait
from ..settings import ServerSettings
from ..study.metrics import FluencyResult, compute_metrics, read_trial
from ..study.people import SimulatedPeople
from ..study.runtime import TrialRuntime
from ..study.studyfile import Study

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrialReport:
    trial: str
    modules: tuple[str, str, str]
    outcome: str
    live: FluencyResult
    recorded: FluencyResult | None
    recording: Path | None
    refusals: tuple[str, ...]

    @property
    def recording_matches(self) -> bool | None:
        """Whether the recording gives the live figures (to 1e-9: JSON keeps floats to the last bit anyway)."""
        if self.recorded is None:
            return None
        a, b = self.live.to_json_dict(), self.recorded.to_json_dict()
        for key in ("h_idle", "r_idle", "c_act", "f_del", "both_idle", "efficiency_s", "effectiveness"):
            x, y = a.get(key), b.get(key)
            if (x is None) != (y is None) or (x is not None and not math.isclose(x, y, abs_tol=1e-9)):
                return False
        return a["counts"] == b["counts"]


def recorded_metrics(path: Path, trial: str) -> FluencyResult:
    data = read_trial(path, trial)
    return compute_metrics(data.updates, t0=data.t0, t1=data.t1, interventions=data.interventions,
                           planned_subtasks=data.planned_subtasks)


async def run_trial(study: Study, trial: str, *, record: Path | None = None, timeout: float = 900.0,
                    settings: ServerSettings | None = None, progress: Callable[[float, int], None] | None = None,
                    progress_every_s: float = 5.0) -> TrialReport:
    """Runs one trial on a server of its own; `progress(elapsed_s, actions_done)` hears how it goes, every
    `progress_every_s` while it runs and once at its end."""
    spec = study.trials[trial]
    base = settings or ServerSettings(port=0, backend="sim")
    server = TeleopServer(base.model_copy(update={"port": 0, "backend": "sim", "record": record,
                                                  "record_camera_fps": 0.0}))
    await server.start()
    try:
        assert server.robot is not None and server.luxai is not None
        runtime = TrialRuntime(server.bus, server.robot, study, trial, server.luxai.gestures)
        people = SimulatedPeople(server.url, study, trial, operator=spec.decision != "scripted")
        try:
            await runtime.prepare()
            await people.connect()
            acting = asyncio.ensure_future(people.run())
            reporting = asyncio.ensure_future(_report_progress(runtime, progress, progress_every_s)) \
                if progress is not None else None
            try:
                result = await asyncio.wait_for(runtime.run(), timeout)
            finally:
                await cancel_and_wait(reporting)
                acting.cancel()
                await asyncio.gather(acting, return_exceptions=True)
            if progress is not None:
                counts = result.metrics.counts
                progress(result.metrics.t1, counts.human_actions + counts.robot_actions - counts.unfinished)
            if acting.done() and not acting.cancelled() and acting.exception() is not None:
                log.warning("a simulated person stopped early: %r", acting.exception())
        finally:
            await people.close()
            await runtime.close()
    finally:
        await server.stop()
    recorded = recorded_metrics(record, trial) if record is not None else None
    return TrialReport(trial, (spec.perception, spec.decision, spec.motion), result.outcome, result.metrics,
                       recorded, record, tuple(people.refusals))


async def _report_progress(runtime: TrialRuntime, progress: Callable[[float, int], None], every_s: float) -> None:
    while True:
        await asyncio.sleep(every_s)
        if runtime.log.started:
            counts = runtime.log.snapshot().counts
            progress(runtime.log.now(), counts.human_actions + counts.robot_actions - counts.unfinished)


def table(reports: list[TrialReport]) -> str:
    """The results shaped like Table III of the framework's paper."""
    def f(x: float | None) -> str:
        return "n/a" if x is None else f"{x:.2f}"

    head = (f"{'trial':<20} {'modules (P/D/A)':<28} {'outcome':<10} {'effectiveness':>13} {'efficiency (s)':>14} "
            f"{'H-IDLE':>7} {'R-IDLE':>7} {'C-ACT':>6} {'F-DEL':>6}")
    lines = [head, "-" * len(head)]
    for i, r in enumerate(reports, 1):
        m = r.live
        lines.append(f"{f'{i} {r.trial}':<20} {'/'.join(r.modules):<28} {r.outcome:<10} {f(m.effectiveness):>13} "
                     f"{m.efficiency_s:>14.2f} {f(m.h_idle):>7} {f(m.r_idle):>7} {f(m.c_act):>6} {f(m.f_del):>6}")
    return "\n".join(lines)
