"""One shape for every kind of study (kinds.py holds the table of them: task, classroom).

A kind says how to load its file (its `model`), what its conditions are, how to run one trial on a server it is
given (`host`: the condition on the server, for `serve --study` and the pilot, whatever the backend; `run_on`: a
whole trial with its simulated people on `study run`'s own stand-in, in this process or a Dask worker), how to
measure a trial from its recording (`measures`; QAM's objective items: `qam_items`), and how to summarise trials
(`summary`, `table`, `stats_table`). Whatever differs between kinds lives in a kind's class; the command line, the
live study, the pilot, the runner and the report ask the kind and never test which kind it is. Every trial gives
one `TrialReport`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Protocol

from pydantic import BaseModel
from client_protocol.vocabulary import AutonomyLevel
from simclock import WALL, Clock

from ..core.bus import Bus
from ..core.ownership import Ownership
from ..questionnaires.stats import describe
from ..robot.gestures import GestureLibrary
from ..robot.interface import Robot

Progress = Callable[[float, int], None]  # (elapsed s, things done): how a running trial goes


class Overran(Exception):
    """A trial not over within its timeout (run_on); `study run` words it as a sentence (tools/timeout.py)."""


class Measures(Protocol):
    """A trial's measures, as any kind gives them."""

    @property
    def duration_s(self) -> float:
        """The trial's length in its own clock's seconds."""

    def to_json_dict(self) -> dict[str, Any]:
        """The `--json` document of the trial's measures."""


@dataclass(frozen=True)
class TrialReport:
    """One trial of any kind: its measures live (as the server computed them while it ran) and from its recording,
    and whether the two agree (None: no recording)."""

    trial: str  # the condition, with "@profile" under a network profile
    modules: tuple[str, ...]  # what ran it: a task's perception, decision, motion; a lesson's level and network
    outcome: str
    live: Any  # Measures
    recorded: Any | None
    recording: Path | None
    refusals: tuple[str, ...]
    seed: int = 0
    recording_matches: bool | None = None


@dataclass(frozen=True)
class Ran:
    """What running a trial's people on a server gives: the outcome, the live measures (None: the kind's measures
    are its recording's) and the operator's commands the server refused."""

    outcome: str
    live: Any | None
    refusals: tuple[str, ...]


@dataclass
class ServerParts:
    """What hosting a trial needs of the server it runs on (app.py gives them)."""

    bus: Bus
    robot: Robot
    registry: Any  # client_protocol.registry.TypeRegistry, for the recorder
    owners: Ownership
    gestures: GestureLibrary | None
    set_autonomy: Callable[[AutonomyLevel], None] | None  # None: the server has no autonomy feature
    autonomy_level: Callable[[], AutonomyLevel | None] = lambda: None
    camera_fps: float = 2.0
    clock: Clock = WALL
    blur: Any = None  # features/face_blur.FaceBlur under serve --blur-faces: trial recordings blur faces too
    # hears the /decision/* commands a trial took: (caller, service, request)
    observer: Callable[[str, str, dict[str, object]], None] | None = None


class HostedTrial(Protocol):
    """A condition running on a server: ended by the experimenter (or the pilot) with an outcome."""

    async def end(self, outcome: str) -> None: ...


class StudyKind(ABC):
    name: ClassVar[str]
    model: ClassVar[type[BaseModel]]  # the study file's model, with `kind: Literal[name]`
    column: ClassVar[str]  # the tables' first column: trial or condition
    column_width: ClassVar[int]
    metric_width: ClassVar[int]
    metrics: ClassVar[tuple[str, ...]]  # what `--repeat` summarises (mean, SD, 95% CI), in table order
    progress_words: ClassVar[tuple[str, str, str]]  # one, many, done: "2 speeches heard"
    networks: ClassVar[bool] = False  # runs under `--network` profiles (the operator's connection impaired)

    def conditions(self, study: Any) -> list[str]:
        return list(study.trials)

    @abstractmethod
    def trial_s(self, study: Any) -> float:
        """About how long one trial lasts at real time (the plan `study run` prints)."""

    @abstractmethod
    def standin_settings(self, study: Any, condition: str, clock: Clock, scratch: Path) -> dict[str, Any]:
        """The ServerSettings fields `study run`'s own stand-in server takes for a trial (`scratch`: a directory
        of its own for the run's files)."""

    @abstractmethod
    async def run_on(self, server: Any, study: Any, condition: str, *, seed: int, clock: Clock, timeout: float,
                     network: str | None, progress: Progress | None) -> Ran:
        """One whole trial on `server` (a started app.TeleopServer) with the kind's simulated people; Overran when
        it has not ended within `timeout` on `clock`."""

    @abstractmethod
    async def host(self, study: Any, condition: str, parts: ServerParts) -> HostedTrial:
        """The condition set on a live server and running, until its end(outcome)."""

    @abstractmethod
    async def act(self, server: Any, study: Any, condition: str, *, clock: Clock, seed: int, timeout: float,
                  trial_state: Any) -> str:
        """The kind's simulated people acting on a hosted trial (the pilot) until it is over: its outcome
        (completed or aborted). `trial_state`: a client's subscription to /study/trial."""

    @abstractmethod
    def modules(self, study: Any, condition: str, network: str | None) -> tuple[str, ...]:
        """What a trial of the condition runs with, for the tables."""

    @abstractmethod
    def measures(self, study: Any, condition: str, recording: Path) -> Any:
        """A trial's measures from its recording."""

    @abstractmethod
    def qam_items(self, recording: Path) -> list[Any]:
        """QAM's items P1-P6 a trial's recording gives (qam_measured.Measured; each missing one with its reason)."""

    @abstractmethod
    def matches(self, live: Any, recorded: Any) -> bool:
        """Whether the recording gives the live measures."""

    @abstractmethod
    def summary(self, title: str, measures: Any) -> str:
        """A trial's measures in a few lines."""

    @abstractmethod
    def recording_line(self, report: TrialReport) -> str:
        """What `study run` says of a trial's recording."""

    @abstractmethod
    def table(self, reports: list[TrialReport]) -> str:
        """One row per trial."""

    def session_fields(self, study: Any) -> dict[str, list[str]]:
        """What /study/session carries of the study for the dashboard: its actions (the Wizard-of-Oz buttons) and
        objects."""
        return {"actions": [], "objects": []}

    def summarise(self, runs: list[TrialReport]) -> dict[str, dict[str, float | int | None]]:
        """Per measure over the runs of one condition: n, mean, SD and the 95% confidence interval of the mean."""
        out = {}
        for key in self.metrics:
            d = describe([r.live.to_json_dict().get(key) for r in runs])
            out[key] = {"n": d.n, "mean": d.mean, "sd": d.sd, "ci95_low": d.ci95_low, "ci95_high": d.ci95_high}
        return out

    def stats_table(self, runs_by_condition: dict[str, list[TrialReport]]) -> str:
        """Mean, SD and 95% CI per measure and condition, beside the table."""
        w, m = self.column_width, self.metric_width
        head = f"{self.column:<{w}} {'metric':<{m}} {'n':>3} {'mean':>8} {'SD':>8} {'95% CI':>20}"
        lines = [head, "-" * len(head)]
        for i, (name, runs) in enumerate(runs_by_condition.items(), 1):
            for key, s in self.summarise(runs).items():
                ci = f"[{fmt(s['ci95_low'])}, {fmt(s['ci95_high'])}]" if s["ci95_low"] is not None else "n/a"
                lines.append(f"{f'{i} {name}':<{w}} {key:<{m}} {s['n']:>3} {fmt(s['mean']):>8} {fmt(s['sd']):>8} "
                             f"{ci:>20}")
        return "\n".join(lines)


def fmt(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.2f}"
