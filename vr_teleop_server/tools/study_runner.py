"""Run study trials of any kind (study/kind.py) on the stand-in: a server of our own (sim backend, session
recording, the kind's settings), the trial run on it by its kind with its simulated people as rosbridge clients,
and its measures read back from the recording (and, where the kind has live ones, compared with them).

On a simulated clock (`--speed max`, simclock) the trial runs as fast as the work allows: the people reach the
server through in-process connections to its transport, and the camera is rendered in simulated time. `seed` picks
the simulated people's draws (the study's seed by default); `--repeat N` runs a trial with seeds S..S+N-1 and the
kind summarises each measure (mean, SD, 95% confidence interval).

The unit of work for many trials (`--workers K`, `--scheduler`: tools/distributed.py) is a `TrialJob` -> its
`TrialDone` (`run_job`): one trial, one seed, on a simulated clock of its own in whichever process runs it, so the
measures are the same wherever it ran. Its recording is written where the job says (a directory every process
sees), or to a temporary directory of the worker's and sent back as bytes.
"""

from __future__ import annotations

import os
import resource
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from simclock import WALL, Clock, SimulatedClock
from simclock import run as run_on_clock

from ..app import TeleopServer
from ..settings import ServerSettings
from ..study.kind import Overran, Progress, TrialReport
from ..study.kinds import kind_of
from .timeout import TrialTimedOut


def dashboard_address(server: TeleopServer) -> str:
    """Where a person follows a trial server live: its dashboard's page (the Study panel)."""
    return server.url.replace("ws", "http", 1) + "/"


async def run_trial(study: Any, trial: str, *, record: Path | None = None, timeout: float = 900.0,
                    settings: ServerSettings | None = None, progress: Progress | None = None,
                    seed: int | None = None, clock: Clock = WALL, network: str | None = None,
                    on_server: Callable[[TeleopServer], None] | None = None, port: int = 0) -> TrialReport:
    """Runs one trial of any kind on a server of its own; `progress(elapsed_s, done)` hears how it goes while it
    runs; `on_server` hears of the server once it listens. `clock`: the running loop's (simclock.run) when
    simulated. `timeout` is on that clock: TrialTimedOut. `port`: the server's (0: any free one). `record`: where
    the recording goes (None: a temporary file, read and removed)."""
    kind = kind_of(study)
    seed = study.seed if seed is None else seed
    name = trial if network is None else f"{trial}@{network}"
    with tempfile.TemporaryDirectory(prefix="vr-teleop-trial-") as tmp:
        path = record or Path(tmp) / "trial.mcap"
        update = {"port": port, "backend": "sim", "record": path, "record_camera_fps": 0.0, "perception_seed": seed,
                  **kind.standin_settings(study, trial, clock, Path(tmp))}
        server = TeleopServer((settings or ServerSettings(port=0, backend="sim")).model_copy(update=update), clock)
        await server.start()
        if on_server is not None:
            on_server(server)
        try:
            ran = await kind.run_on(server, study, trial, seed=seed, clock=clock, timeout=timeout, network=network,
                                    progress=progress)
        except Overran:
            raise TrialTimedOut(name, timeout, clock.simulated, record) from None
        finally:
            await server.stop()
        recorded = kind.measures(study, trial, path)
    live = recorded if ran.live is None else ran.live
    return TrialReport(name, kind.modules(study, trial, network), ran.outcome, live, recorded, record, ran.refusals,
                       seed, kind.matches(live, recorded))


@dataclass(frozen=True)
class TrialJob:
    """One trial run: what `study run` asks of a worker. `record_dir`: where the recording goes, a directory the
    worker sees (this process's --record-dir, or a --shared-dir); None: a temporary one, the bytes sent back."""
    study: Any  # a loaded study file of any kind
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
    report: TrialReport
    recording: bytes | None
    wall_s: float
    cpu_s: float
    peak_rss_mb: float
    worker_pid: int


def run_job(job: TrialJob) -> TrialDone:
    one, many, done_word = kind_of(job.study).progress_words

    def progress(elapsed: float, done: int) -> None:
        print(f"  {job.name}: {elapsed:5.1f} s, {done} {one if done == 1 else many} {done_word}",
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
        trial = run_trial(job.study, job.trial, record=record, timeout=job.timeout, port=job.port,
                          progress=progress if job.progress else None, seed=job.seed, clock=clock,
                          network=job.network, on_server=on_server)
        report = run_on_clock(trial, clock)
        wall, cpu = time.perf_counter() - wall, _cpu_seconds() - cpu
        data = record.read_bytes() if job.record_dir is None else None
    peak_kb = sum(resource.getrusage(who).ru_maxrss for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))
    return TrialDone(report, data, wall, cpu, peak_kb / 1024.0, os.getpid())


def _cpu_seconds() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system
