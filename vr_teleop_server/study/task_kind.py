"""The task study (studyfile.py, examples/toolbox.yaml): each condition runs its perception, decision and motion
modules (runtime.py) on the server's robot; the simulated participant, operator and experimenter (people.py) act on
it; its measures are the fluency metrics, live and again from the recording, which must agree."""

from __future__ import annotations

import asyncio
import logging
import math
import zlib
from pathlib import Path
from typing import Any

from client_protocol.vocabulary import AutonomyLevel
from simclock import Clock

from ..core.tasks import cancel_and_wait
from .kind import HostedTrial, Overran, Progress, Ran, ServerParts, StudyKind, TrialReport, fmt
from .metrics import FluencyResult, compute_metrics, read_trial
from .metrics.fluency import fluency_summary
from .qam_measured import Measured, task_items
from .people import SimulatedPeople
from .runtime import TrialRuntime
from .studyfile import Study

log = logging.getLogger(__name__)

ARUCO_RATE_HZ = 5.0  # the frames a second ArUco perception searches (ArucoTracker's rate)
S_PER_PART = 8.5  # a trial at real time, per part: the toolbox's six parts take 47 to 53 s
ENDED = ("completed", "preempted", "failed")
MATCHED = ("h_idle", "r_idle", "c_act", "f_del", "both_idle", "efficiency_s", "effectiveness")


def people_seed(seed: int, trial: str) -> int:
    """The simulated people's generator seed for a run seed (the study's seed gives what the study file says)."""
    return seed * 1_000_003 + zlib.crc32(trial.encode())


def recorded_metrics(path: Path, trial: str) -> FluencyResult:
    data = read_trial(path, trial)
    return compute_metrics(data.updates, t0=data.t0, t1=data.t1, interventions=data.interventions,
                           planned_subtasks=data.planned_subtasks)


class HostedTask:
    """A task trial on a server: its modules prepared and its decision module running until it ends the trial
    (completed, preempted, failed) or the experimenter does."""

    def __init__(self, runtime: TrialRuntime) -> None:
        self.runtime = runtime
        self.task: asyncio.Task[Any] | None = None

    async def start(self) -> None:
        await self.runtime.prepare()
        self.task = asyncio.ensure_future(self.runtime.run())

    async def end(self, outcome: str) -> None:
        runtime = self.runtime
        if self.task is not None and not self.task.done():
            await cancel_and_wait(self.task)
            if runtime.log.started and runtime.log.final is None:
                await runtime.log.finish("preempted" if outcome == "aborted" else "completed",
                                         message=f"ended by the experimenter: {outcome}")
        await runtime.close()


class TaskKind(StudyKind):
    name = "task"
    model = Study
    column, column_width, metric_width = "trial", 20, 14
    metrics = ("effectiveness", "efficiency_s", "h_idle", "r_idle", "c_act", "f_del")
    progress_words = ("action", "actions", "done")

    def trial_s(self, study: Study) -> float:
        return len(study.parts) * S_PER_PART

    def standin_settings(self, study: Study, condition: str, clock: Clock, scratch: Path) -> dict[str, Any]:
        # the trial's decision module is the robot's autonomy here: the server's own stays off
        update: dict[str, Any] = {"autonomy": AutonomyLevel.TELEOPERATED}
        if clock.simulated and study.trials[condition].perception == "aruco":
            update["camera_fps"] = ARUCO_RATE_HZ  # every frame drawn is searched: none drawn in vain
        return update

    def _runtime(self, study: Study, condition: str, parts: ServerParts) -> TrialRuntime:
        return TrialRuntime(parts.bus, parts.robot, study, condition, parts.gestures, clock=parts.clock,
                            owners=parts.owners, observer=parts.observer)

    async def host(self, study: Study, condition: str, parts: ServerParts) -> HostedTrial:
        hosted = HostedTask(self._runtime(study, condition, parts))
        try:
            await hosted.start()
        except BaseException:
            await hosted.end("aborted")
            raise
        return hosted

    async def run_on(self, server: Any, study: Study, condition: str, *, seed: int, clock: Clock, timeout: float,
                     network: str | None, progress: Progress | None) -> Ran:
        spec = study.trials[condition]
        runtime = self._runtime(study, condition, server.study_parts())
        people = SimulatedPeople(server.url, study, condition, operator=spec.decision != "scripted",
                                 seed=people_seed(seed, condition),
                                 opener=server.transport.connect_local if clock.simulated else None)
        try:
            await runtime.prepare()
            await people.connect()
            acting = asyncio.ensure_future(people.run())
            reporting = asyncio.ensure_future(_report_progress(runtime, progress)) if progress is not None else None
            try:
                result = await asyncio.wait_for(runtime.run(), timeout)
            except TimeoutError:
                raise Overran(condition) from None
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
        return Ran(result.outcome, result.metrics, tuple(people.refusals))

    async def act(self, server: Any, study: Study, condition: str, *, clock: Clock, seed: int, timeout: float,
                  trial_state: Any) -> str:
        spec = study.trials[condition]
        people = SimulatedPeople(server.url, study, condition, operator=spec.decision != "scripted", seed=seed,
                                 opener=server.transport.connect_local if clock.simulated else None)
        await people.connect()
        acting = asyncio.ensure_future(people.run())
        try:
            state = await trial_state.next(lambda m: m["trial"] == condition and m["state"] in ENDED,
                                           timeout=timeout)
            return "completed" if state["state"] == "completed" else "aborted"
        finally:
            acting.cancel()
            await asyncio.gather(acting, return_exceptions=True)
            await people.close()

    def modules(self, study: Study, condition: str, network: str | None) -> tuple[str, ...]:
        spec = study.trials[condition]
        return spec.perception, spec.decision, spec.motion

    def measures(self, study: Study, condition: str, recording: Path) -> FluencyResult:
        return recorded_metrics(recording, condition)

    def qam_items(self, recording: Path) -> list[Measured]:
        return task_items(recording)

    def matches(self, live: FluencyResult, recorded: FluencyResult) -> bool:
        """To 1e-9: JSON keeps floats to the last bit anyway."""
        a, b = live.to_json_dict(), recorded.to_json_dict()
        for key in MATCHED:
            x, y = a.get(key), b.get(key)
            if (x is None) != (y is None) or (x is not None and not math.isclose(x, y, abs_tol=1e-9)):
                return False
        return a["counts"] == b["counts"]

    def summary(self, title: str, measures: FluencyResult) -> str:
        return fluency_summary(title, measures)

    def recording_line(self, report: TrialReport) -> str:
        return (f"  recording {report.recording}: metrics from it "
                f"{'equal' if report.recording_matches else 'DIFFER FROM'} the live ones")

    def table(self, reports: list[TrialReport]) -> str:
        """The results shaped like Table III of the framework's paper."""
        head = (f"{'trial':<20} {'modules (P/D/A)':<28} {'outcome':<10} {'effectiveness':>13} "
                f"{'efficiency (s)':>14} {'H-IDLE':>7} {'R-IDLE':>7} {'C-ACT':>6} {'F-DEL':>6}")
        lines = [head, "-" * len(head)]
        for i, r in enumerate(reports, 1):
            m = r.live
            lines.append(f"{f'{i} {r.trial}':<20} {'/'.join(r.modules):<28} {r.outcome:<10} "
                         f"{fmt(m.effectiveness):>13} {m.efficiency_s:>14.2f} {fmt(m.h_idle):>7} {fmt(m.r_idle):>7} "
                         f"{fmt(m.c_act):>6} {fmt(m.f_del):>6}")
        return "\n".join(lines)

    def session_fields(self, study: Study) -> dict[str, list[str]]:
        return {"actions": list(study.actions), "objects": [p.name for p in study.parts]}


async def _report_progress(runtime: TrialRuntime, progress: Progress, every_s: float = 5.0) -> None:
    first = True
    while True:
        await asyncio.sleep(min(1.0, every_s) if first else every_s)  # a first line within the first second
        first = False
        if runtime.log.started:
            counts = runtime.log.snapshot().counts
            progress(runtime.log.now(), counts.human_actions + counts.robot_actions - counts.unfinished)
