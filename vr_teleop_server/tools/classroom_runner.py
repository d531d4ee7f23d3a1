"""Run one lesson of a classroom study (study/classroom_file.py) on the stand-in: a server of its own (sim backend,
session recording, the condition's autonomy level), the simulated pupils and teacher as its clients
(study/classroom.py), for `lesson_s` on the server's clock. The measures (study/metrics/classroom.py) are read from
the recording, which is the lesson's record: there is no live copy to compare them with.

`network`: a profile of netem/profiles.yaml on the teacher's connection (study/network.py); simulated clock only.
"""

from __future__ import annotations

import asyncio
import logging
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from simclock import WALL, Clock

from ..app import TeleopServer
from ..client import Client, connect
from ..questionnaires.stats import describe
from ..settings import ServerSettings
from ..study.classroom import Pupils, Teacher
from ..study.classroom_file import ClassroomStudy
from ..study.metrics.classroom import CLASSROOM_METRICS, ClassroomResult, classroom_metrics, read_classroom
from ..study.network import ImpairedConnection, profiles
from .timeout import TrialTimedOut

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ClassroomReport:
    trial: str  # the condition, with "@profile" under a network profile
    modules: tuple[str, ...]  # (autonomy level, network profile or "direct")
    outcome: str
    live: ClassroomResult
    recorded: ClassroomResult | None
    recording: Path | None
    refusals: tuple[str, ...]
    seed: int = 0

    @property
    def recording_matches(self) -> bool:
        return True  # the measures are the recording's own


def menu_check(server: TeleopServer, study: ClassroomStudy) -> None:
    unknown = [a for a in study.teacher.actions if server.autonomy.menu_entry(a) is None]
    if unknown:
        raise ValueError(f"teacher.actions: {', '.join(unknown)} is not a menu item id (the ids on /vr_teleop/menus, "
                         "e.g. emotion.happy, speech.sentences.well_done)")


async def run_lesson(study: ClassroomStudy, condition: str, *, record: Path | None = None, seed: int | None = None,
                     clock: Clock = WALL, network: str | None = None, timeout: float = 900.0,
                     progress: Callable[[float, int], None] | None = None, port: int = 0,
                     on_server: Callable[[TeleopServer], None] | None = None) -> ClassroomReport:
    """`timeout` (on `clock`) shorter than the lesson stops it there: TrialTimedOut. `on_server` hears of the
    lesson's server once it listens (on `port`, 0: any free one)."""
    level = study.conditions[condition].autonomy
    seed = study.seed if seed is None else seed
    if network is not None and not clock.simulated:
        raise ValueError("--network runs on the simulated clock only (--speed max): at real time, run the server "
                         "behind the WAN emulator (docs/guides/deployment.md)")
    with tempfile.TemporaryDirectory(prefix="vr-teleop-lesson-") as tmp:
        record = record or Path(tmp) / "lesson.mcap"
        settings = ServerSettings(port=port, backend="sim", record=record, record_camera_fps=0.0, autonomy=level,
                                  bystander_interval=0, camera_fps=study.camera_fps, perception=study.perception,
                                  perception_seed=seed, gesture_dir=Path(tmp) / "g", audio_dir=Path(tmp) / "a")
        server = TeleopServer(settings, clock)
        await server.start()
        if on_server is not None:
            on_server(server)
        refusals: list[str] = []
        try:
            if server.autonomy is not None:
                server.autonomy.attention.reseed(seed)
            menu_check(server, study)
            local = clock.simulated

            def opener(prefix: str, impaired: bool) -> Client | None:
                if not local:
                    return None
                conn = server.transport.connect_local()
                if impaired and network is not None:
                    conn = ImpairedConnection(conn, profiles([network])[network], clock, seed)
                return Client(conn, id_prefix=prefix)

            pupils_client = opener("pupils", False) or await connect(server.url, id_prefix="pupils")
            teacher_client = opener("teacher", True) or await connect(server.url, id_prefix="teacher")
            pupils = Pupils(pupils_client, study, seed)
            teacher = Teacher(teacher_client, study, level, seed, clock.monotonic)
            try:
                await teacher.connect()
                await teacher.begin()
                started = clock.monotonic()
                acting = asyncio.ensure_future(pupils.run())
                try:
                    end = started + min(study.lesson_s, timeout)
                    every = 1.0  # a first progress line within the first second, then every 5 s
                    while (left := end - clock.monotonic()) > 1e-6:
                        await asyncio.sleep(min(every, left))
                        every = 5.0
                        if progress is not None:
                            progress(clock.monotonic() - started, teacher.heard)
                        if acting.done():
                            acting.result()  # a pupil's failure ends the lesson with its error
                finally:
                    acting.cancel()
                    await asyncio.gather(acting, return_exceptions=True)
                    await teacher.close()
                refusals = teacher.refusals
                if timeout < study.lesson_s:
                    raise TrialTimedOut(condition if network is None else f"{condition}@{network}", timeout,
                                        clock.simulated, record if record.parent != Path(tmp) else None)
            finally:
                await teacher_client.close()
                await pupils_client.close()
        finally:
            await server.stop()
        result = classroom_metrics(read_classroom(record, study.lesson_s))
    trial = condition if network is None else f"{condition}@{network}"
    return ClassroomReport(trial, (level, network or "direct"), "completed", result, result,
                           None if record.parent == Path(tmp) else record, tuple(refusals), seed)


def summarise_classroom(runs: list[ClassroomReport]) -> dict[str, dict[str, float | int | None]]:
    out = {}
    for key in CLASSROOM_METRICS:
        d = describe([getattr(r.live, key) for r in runs])
        out[key] = {"n": d.n, "mean": d.mean, "sd": d.sd, "ci95_low": d.ci95_low, "ci95_high": d.ci95_high}
    return out


def _f(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.2f}"


def classroom_table(reports: list[ClassroomReport]) -> str:
    head = (f"{'condition':<26} {'seed':>4} {'speeches':>8} {'look mean':>9} {'look p95':>8} {'attended':>8} "
            f"{'teacher/min':>11} {'acc':>4} {'rej':>4} {'t/o':>4} {'interv':>6} {'effect.':>7}")
    lines = [head, "-" * len(head)]
    for i, r in enumerate(reports, 1):
        m = r.live
        lines.append(f"{f'{i} {r.trial}':<26} {r.seed:>4} {m.speeches:>8} {_f(m.onset_to_look_mean_s):>9} "
                     f"{_f(m.onset_to_look_p95_s):>8} {_f(m.share_attended):>8} {m.teacher_actions_per_min:>11.2f} "
                     f"{m.accepted:>4} {m.rejected:>4} {m.timed_out:>4} {m.interventions:>6} "
                     f"{_f(m.effectiveness):>7}")
    return "\n".join(lines)


def classroom_stats_table(runs_by_trial: dict[str, list[ClassroomReport]]) -> str:
    head = f"{'condition':<26} {'metric':<24} {'n':>3} {'mean':>8} {'SD':>8} {'95% CI':>20}"
    lines = [head, "-" * len(head)]
    for i, (trial, runs) in enumerate(runs_by_trial.items(), 1):
        for key, s in summarise_classroom(runs).items():
            ci = f"[{_f(s['ci95_low'])}, {_f(s['ci95_high'])}]" if s["ci95_low"] is not None else "n/a"
            lines.append(f"{f'{i} {trial}':<26} {key:<24} {s['n']:>3} {_f(s['mean']):>8} {_f(s['sd']):>8} {ci:>20}")
    return "\n".join(lines)
