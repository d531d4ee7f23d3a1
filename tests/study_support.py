"""Study helpers shared by the study framework's tests and the dashboard's study tests."""

from __future__ import annotations

import asyncio
import copy
from pathlib import Path

import yaml
from support import RunningServer, wait_for

from vr_teleop_server.study.runtime import TrialRuntime
from vr_teleop_server.study.studyfile import Study

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "toolbox.yaml"


def small_study(**trial_changes: dict) -> Study:
    """The shipped study cut to two parts (one held), with quick people, so a trial lasts about ten seconds."""
    doc = yaml.safe_load(EXAMPLE.read_text())
    doc["parts"] = [{"name": "bottom", "bin": "red_bin", "hold": True}, {"name": "front", "bin": "blue_bin"}]
    doc["human"]["reaction_s"] = [0.05, 0.15]
    for step in doc["human"]["steps"]:
        step["duration_s"] = [0.3, 0.5]
    doc["operator"]["reaction_s"] = [0.1, 0.2]
    doc["trials"]["teleoperated"]["stalls"] = []
    doc["trials"]["teleoperated"]["overrides"] = []
    for name, change in trial_changes.items():
        doc["trials"][name] = {**doc["trials"].get(name, {}), **copy.deepcopy(change)}
    return Study.model_validate(doc)


def on_loop(server: RunningServer, coro, timeout: float = 60.0):
    return asyncio.run_coroutine_threadsafe(coro, server.loop).result(timeout)


def prepared(server: RunningServer, study: Study, trial: str) -> TrialRuntime:
    robot = server.server.robot
    server.call(lambda: robot.home())
    def home() -> bool:
        here = robot.joint_state().as_dict()
        return all(abs(here[n] - robot.model.joint(n).home) < 2 for n in robot.model.names)
    assert wait_for(home, 30)

    async def make() -> TrialRuntime:
        runtime = TrialRuntime(server.server.bus, robot, study, trial, server.server.luxai.gestures,
                               owners=server.server.owners)
        await runtime.prepare()
        return runtime
    return on_loop(server, make())


