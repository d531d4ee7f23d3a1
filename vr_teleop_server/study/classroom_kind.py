"""The classroom study (classroom_file.py, examples/classroom.yaml): each condition is an autonomy level; the
simulated pupils and teacher (classroom.py) act for `lesson_s` on the server's clock; the measures
(metrics/classroom.py) are read from the recording, which is the lesson's record: there is no live copy to compare
them with. `network`: a profile of netem/profiles.yaml on the teacher's connection (network.py), simulated clock
only."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from client_protocol.vocabulary import AutonomyLevel
from simclock import Clock

from ..client import Client, connect
from .classroom import Pupils, Teacher
from .classroom_file import ClassroomStudy
from .kind import HostedTrial, Overran, Progress, Ran, ServerParts, StudyKind, TrialReport, fmt
from .metrics.classroom import ClassroomResult, classroom_metrics, classroom_summary, read_classroom
from .network import ImpairedConnection, profiles
from .qam_measured import Measured, lesson_items
from .trial import TrialLog


def menu_check(server: Any, study: ClassroomStudy) -> None:
    unknown = [a for a in study.teacher.actions if server.autonomy.menu_entry(a) is None]
    if unknown:
        raise ValueError(f"teacher.actions: {', '.join(unknown)} is not a menu item id (the ids on /vr_teleop/menus, "
                         "e.g. emotion.happy, speech.sentences.well_done)")


class HostedLesson:
    """A lesson on a server: its autonomy level set (the level before comes back at its end) and a trial log (the
    label services, state updates, metrics) running until the experimenter ends it."""

    def __init__(self, study: ClassroomStudy, condition: str, parts: ServerParts) -> None:
        self.parts = parts
        self.level = study.conditions[condition].autonomy
        self.level_before: AutonomyLevel | None = None
        self.log = TrialLog(parts.bus, study.study, condition, (self.level, "live", "live"), 0, clock=parts.clock)

    def start(self) -> None:
        if self.parts.set_autonomy is not None:
            self.level_before = self.parts.autonomy_level()
            self.parts.set_autonomy(self.level)
        self.log.attach()
        self.log.begin()

    async def end(self, outcome: str) -> None:
        if self.log.started and self.log.final is None:
            await self.log.finish("completed" if outcome == "completed" else "preempted",
                                  message=f"ended by the experimenter: {outcome}")
        self.log.detach()
        if self.level_before is not None and self.parts.set_autonomy is not None:
            self.parts.set_autonomy(self.level_before)


class ClassroomKind(StudyKind):
    name = "classroom"
    model = ClassroomStudy
    column, column_width, metric_width = "condition", 26, 24
    metrics = ("onset_to_look_mean_s", "onset_to_look_p95_s", "share_attended", "teacher_actions_per_min",
               "accepted", "rejected", "timed_out", "interventions", "effectiveness")
    progress_words = ("speech", "speeches", "heard")
    networks = True

    def trial_s(self, study: ClassroomStudy) -> float:
        return study.lesson_s

    def standin_settings(self, study: ClassroomStudy, condition: str, clock: Clock, scratch: Path) -> dict[str, Any]:
        return {"autonomy": study.conditions[condition].autonomy, "bystander_interval": 0,
                "camera_fps": study.camera_fps, "perception": study.perception, "gesture_dir": scratch / "g",
                "audio_dir": scratch / "a"}

    async def host(self, study: ClassroomStudy, condition: str, parts: ServerParts) -> HostedTrial:
        hosted = HostedLesson(study, condition, parts)
        try:
            hosted.start()
        except BaseException:
            await hosted.end("aborted")
            raise
        return hosted

    async def run_on(self, server: Any, study: ClassroomStudy, condition: str, *, seed: int, clock: Clock,
                     timeout: float, network: str | None, progress: Progress | None) -> Ran:
        """`timeout` (on `clock`) shorter than the lesson stops it there: Overran."""
        if network is not None and not clock.simulated:
            raise ValueError("--network runs on the simulated clock only (--speed max): at real time, run the server "
                             "behind the WAN emulator (docs/guides/deployment.md)")
        if server.autonomy is not None:
            server.autonomy.attention.reseed(seed)
        menu_check(server, study)

        def opener(prefix: str, impaired: bool) -> Client | None:
            if not clock.simulated:
                return None
            conn = server.transport.connect_local()
            if impaired and network is not None:
                conn = ImpairedConnection(conn, profiles([network])[network], clock, seed)
            return Client(conn, id_prefix=prefix)

        pupils_client = opener("pupils", False) or await connect(server.url, id_prefix="pupils")
        teacher_client = opener("teacher", True) or await connect(server.url, id_prefix="teacher")
        pupils = Pupils(pupils_client, study, seed)
        teacher = Teacher(teacher_client, study, study.conditions[condition].autonomy, seed, clock.monotonic)
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
            if timeout < study.lesson_s:
                raise Overran(condition)
        finally:
            await teacher_client.close()
            await pupils_client.close()
        return Ran("completed", None, tuple(teacher.refusals))

    async def act(self, server: Any, study: ClassroomStudy, condition: str, *, clock: Clock, seed: int,
                  timeout: float, trial_state: Any) -> str:
        opener = server.transport.connect_local if clock.simulated else None
        pupils_client = Client(opener()) if opener else await connect(server.url, id_prefix="pupils")
        teacher_client = Client(opener()) if opener else await connect(server.url, id_prefix="teacher")
        pupils = Pupils(pupils_client, study, seed)
        teacher = Teacher(teacher_client, study, study.conditions[condition].autonomy, seed, clock.monotonic)
        try:
            await teacher.connect()
            await teacher.begin()
            acting = asyncio.ensure_future(pupils.run())
            try:
                await asyncio.sleep(study.lesson_s)  # the lesson's length, on the server's clock
                if acting.done():
                    acting.result()
            finally:
                acting.cancel()
                await asyncio.gather(acting, return_exceptions=True)
                await teacher.close()
        finally:
            await teacher_client.close()
            await pupils_client.close()
        return "completed"

    def modules(self, study: ClassroomStudy, condition: str, network: str | None) -> tuple[str, ...]:
        return study.conditions[condition].autonomy, network or "direct"

    def measures(self, study: ClassroomStudy, condition: str, recording: Path) -> ClassroomResult:
        return classroom_metrics(read_classroom(recording, study.lesson_s))

    def qam_items(self, recording: Path) -> list[Measured]:
        return lesson_items(recording)

    def matches(self, live: ClassroomResult, recorded: ClassroomResult) -> bool:
        return live == recorded

    def summary(self, title: str, measures: ClassroomResult) -> str:
        return classroom_summary(title, measures)

    def recording_line(self, report: TrialReport) -> str:
        return f"  recording {report.recording}: the measures are read from it"

    def table(self, reports: list[TrialReport]) -> str:
        head = (f"{'condition':<26} {'seed':>4} {'speeches':>8} {'look mean':>9} {'look p95':>8} {'attended':>8} "
                f"{'teacher/min':>11} {'acc':>4} {'rej':>4} {'t/o':>4} {'interv':>6} {'effect.':>7}")
        lines = [head, "-" * len(head)]
        for i, r in enumerate(reports, 1):
            m = r.live
            lines.append(f"{f'{i} {r.trial}':<26} {r.seed:>4} {m.speeches:>8} {fmt(m.onset_to_look_mean_s):>9} "
                         f"{fmt(m.onset_to_look_p95_s):>8} {fmt(m.share_attended):>8} "
                         f"{m.teacher_actions_per_min:>11.2f} {m.accepted:>4} {m.rejected:>4} {m.timed_out:>4} "
                         f"{m.interventions:>6} {fmt(m.effectiveness):>7}")
        return "\n".join(lines)
