"""Run study trials on the stand-in: a server of our own (sim backend, session recording), the trial's modules
on it, and the simulated participant, operator and experimenter as rosbridge clients. After each trial the
metrics are recomputed from the recording and compared with the live ones.

On a simulated clock (`--speed max`, simclock) the trial runs as fast as the work allows: the people reach the
server through in-process connections to its transport, and the camera is rendered in simulated time at the
rate ArUco perception searches frames. `seed` picks the simulated people's draws (the study's seed by default);
`--repeat N` runs a trial with seeds S..S+N-1 and summarises each metric (mean, SD, 95% confidence interval).

The unit of work for many trials (`--workers K`, `--scheduler`: tools/distributed.py) is a `TrialJob` -> its
`TrialDone` (`run_job`): one trial, one seed, on a simulated clock of its own in whichever process runs it, so the
metrics are the same wherever it ran. Its recording is written where the job says (a directory every process
sees), or to a temporary directory of the worker's and sent back as bytes.
"""

from __future__ import annotations

import asyncio
import logging
import math
import os
import resource
import sys
import tempfile
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from client_protocol.vocabulary import AutonomyLevel
from simclock import WALL, Clock, SimulatedClock
from simclock import run as run_on_clock

from ..app import TeleopServer
from ..core.tasks import cancel_and_wait
from ..questionnaires.stats import describe
from ..settings import ServerSettings
from ..study.metrics import FluencyResult, compute_metrics, read_trial
from ..study.people import SimulatedPeople
from ..study.runtime import TrialRuntime
from ..study.classroom_file import ClassroomStudy
from ..study.studyfile import Study
from .classroom_runner import ClassroomReport, run_lesson
from .timeout import TrialTimedOut

log = logging.getLogger(__name__)


def dashboard_address(server: TeleopServer) -> str:
    """Where a person follows a trial server live: its dashboard's page (the Study panel)."""
    return server.url.replace("ws", "http", 1) + "/"


@dataclass(frozen=True)
class TrialReport:
    trial: str
    modules: tuple[str, str, str]
    outcome: str
    live: FluencyResult
    recorded: FluencyResult | None
    recording: Path | None
    refusals: tuple[str, ...]
    seed: int = 0

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


ARUCO_RATE_HZ = 5.0  # the frames a second ArUco perception searches (ArucoTracker's rate)


def people_seed(seed: int, trial: str) -> int:
    """The simulated people's generator seed for a run seed (the study's seed gives what the study file says)."""
    return seed * 1_000_003 + zlib.crc32(trial.encode())


async def run_trial(study: Study, trial: str, *, record: Path | None = None, timeout: float = 900.0,
                    settings: ServerSettings | None = None, progress: Callable[[float, int], None] | None = None,
                    progress_every_s: float = 5.0, seed: int | None = None, clock: Clock = WALL,
                    on_server: Callable[[TeleopServer], None] | None = None, port: int = 0) -> TrialReport:
    """Runs one trial on a server of its own; `progress(elapsed_s, actions_done)` hears how it goes, every
    `progress_every_s` while it runs and once at its end; `on_server` hears of the server once it listens.
    `clock`: the running loop's (simclock.run) when simulated. `timeout` is on that clock: TrialTimedOut. `port`:
    the server's (0: any free one)."""
    spec = study.trials[trial]
    seed = study.seed if seed is None else seed
    base = settings or ServerSettings(port=0, backend="sim")
    # the trial's decision module is the robot's autonomy here: the server's own stays off
    update = {"port": port, "backend": "sim", "record": record, "record_camera_fps": 0.0,
              "autonomy": AutonomyLevel.TELEOPERATED}
    if clock.simulated and spec.perception == "aruco":  # every frame drawn is searched: none drawn in vain
        update["camera_fps"] = ARUCO_RATE_HZ
    server = TeleopServer(base.model_copy(update=update), clock)
    await server.start()
    if on_server is not None:
        on_server(server)
    try:
        assert server.robot is not None and server.luxai is not None
        runtime = TrialRuntime(server.bus, server.robot, study, trial, server.luxai.gestures, clock=clock,
                               owners=server.owners)
        people = SimulatedPeople(server.url, study, trial, operator=spec.decision != "scripted",
                                 seed=people_seed(seed, trial),
                                 opener=server.transport.connect_local if clock.simulated else None)
        try:
            await runtime.prepare()
            await people.connect()
            acting = asyncio.ensure_future(people.run())
            reporting = asyncio.ensure_future(_report_progress(runtime, progress, progress_every_s)) \
                if progress is not None else None
            try:
                result = await asyncio.wait_for(runtime.run(), timeout)
            except TimeoutError:
                raise TrialTimedOut(trial, timeout, clock.simulated, record) from None
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
                       recorded, record, tuple(people.refusals), seed)


@dataclass(frozen=True)
class TrialJob:
    """One trial run: what `study run` asks of a worker. `record_dir`: where the recording goes, a directory the
    worker sees (this process's --record-dir, or a --shared-dir); None: a temporary one, the bytes sent back."""
    study: Study | ClassroomStudy
    trial: str
    seed: int
    record_name: str
    record_dir: Path | None = None
    timeout: float = 900.0
    simulated: bool = True
    progress: bool = False  # progress lines on stderr while it runs (in this process only)
    network: str | None = None  # a classroom lesson's network profile (netem/profiles.yaml), simulated clock only
    port: int = 0  # the trial server's port at real time (0: any free one)

    @property
    def name(self) -> str:
        """The condition (trial), with its network profile when it has one: supervised@continent."""
        return self.trial if self.network is None else f"{self.trial}@{self.network}"

    @property
    def key(self) -> str:
        return f"{self.name}-seed{self.seed}"


@dataclass(frozen=True)
class TrialDone:
    """A job's report, its recording's bytes when they were not written where the client reads them, and what it
    cost the process that ran it: wall and CPU seconds (with its children: the stand-in's render process) and its
    peak resident memory so far with its largest child's (MB: what a worker process needs)."""
    report: TrialReport | ClassroomReport
    recording: bytes | None
    wall_s: float
    cpu_s: float
    peak_rss_mb: float
    worker_pid: int


def run_job(job: TrialJob) -> TrialDone:
    what = ("speech", "speeches", "heard") if isinstance(job.study, ClassroomStudy) else ("action", "actions", "done")

    def progress(elapsed: float, done: int) -> None:
        print(f"  {job.name}: {elapsed:5.1f} s, {done} {what[0] if done == 1 else what[1]} {what[2]}",
              file=sys.stderr, flush=True)

    def listening(server: TeleopServer) -> None:
        print(f"  {job.name}: follow it live on the dashboard at {dashboard_address(server)} (Study panel)",
              file=sys.stderr, flush=True)

    on_server = listening if job.progress and not job.simulated else None
    with tempfile.TemporaryDirectory(prefix="vr-teleop-trial-") as tmp:
        directory = job.record_dir or Path(tmp)
        record = directory / job.record_name
        clock = SimulatedClock() if job.simulated else WALL
        wall, cpu = time.perf_counter(), _cpu_seconds()
        if isinstance(job.study, ClassroomStudy):
            lesson = run_lesson(job.study, job.trial, record=record, seed=job.seed, clock=clock, network=job.network,
                                timeout=job.timeout, progress=progress if job.progress else None,
                                port=job.port, on_server=on_server)
        else:
            lesson = run_trial(job.study, job.trial, record=record, timeout=job.timeout, port=job.port,
                               progress=progress if job.progress else None, seed=job.seed, clock=clock,
                               on_server=on_server)
        report = run_on_clock(lesson, clock)
        wall, cpu = time.perf_counter() - wall, _cpu_seconds() - cpu
        data = record.read_bytes() if job.record_dir is None else None
    peak_kb = sum(resource.getrusage(who).ru_maxrss for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))
    return TrialDone(report, data, wall, cpu, peak_kb / 1024.0, os.getpid())


def _cpu_seconds() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


async def _report_progress(runtime: TrialRuntime, progress: Callable[[float, int], None], every_s: float) -> None:
    first = True
    while True:
        await asyncio.sleep(min(1.0, every_s) if first else every_s)  # a first line within the first second
        first = False
        if runtime.log.started:
            counts = runtime.log.snapshot().counts
            progress(runtime.log.now(), counts.human_actions + counts.robot_actions - counts.unfinished)


METRICS = ("effectiveness", "efficiency_s", "h_idle", "r_idle", "c_act", "f_del")


def summarise(runs: list[TrialReport]) -> dict[str, dict[str, float | int | None]]:
    """Per metric over the runs of one trial: n, mean, SD and the 95% confidence interval of the mean (t)."""
    out = {}
    for key in METRICS:
        d = describe([r.live.to_json_dict().get(key) for r in runs])
        out[key] = {"n": d.n, "mean": d.mean, "sd": d.sd, "ci95_low": d.ci95_low, "ci95_high": d.ci95_high}
    return out


def stats_table(runs_by_trial: dict[str, list[TrialReport]]) -> str:
    """Mean, SD and 95% CI per metric and trial, beside the paper-shaped table."""
    def f(x: float | None) -> str:
        return "n/a" if x is None else f"{x:.2f}"

    head = f"{'trial':<20} {'metric':<14} {'n':>3} {'mean':>8} {'SD':>8} {'95% CI':>20}"
    lines = [head, "-" * len(head)]
    for i, (trial, runs) in enumerate(runs_by_trial.items(), 1):
        for key, s in summarise(runs).items():
            ci = f"[{f(s['ci95_low'])}, {f(s['ci95_high'])}]" if s["ci95_low"] is not None else "n/a"
            lines.append(f"{f'{i} {trial}':<20} {key:<14} {s['n']:>3} {f(s['mean']):>8} {f(s['sd']):>8} {ci:>20}")
    return "\n".join(lines)


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
