"""Replays and studies at `--speed max`: a server of their own on the stand-in and a simulated clock, reached
through in-process connections to its transport. Simulated runs of a seed give identical reports; a simulated
replay agrees with a real-time one; `--repeat` summarises runs of different seeds."""

from __future__ import annotations

import asyncio
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from robot_models import load_qtrobot
from scipy import stats
from study_support import small_study
from support import patient_teleop

from vr_teleop_server.settings import ServerSettings
from vr_teleop_server.tools import synth
from vr_teleop_server.teleop.settings import OneEuroSettings, TeleopSettings
from vr_teleop_server.tools.replay import ENGAGE_LAGS, load_steps, report, run_replay, run_simulated

pytestmark = pytest.mark.slow  # replays and studies, real-time and simulated

ROOT = Path(__file__).resolve().parent.parent
WALL_FIELDS = ("replay_s", "speed_achieved", "served_s", "speed_served")  # how long it took: the machine's


@pytest.fixture(scope="module")
def nod(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("speed_max") / "nod.mcap"
    synth.write(synth.build("nod"), path)
    return path


def simulated_report(path: Path, settings: ServerSettings, camera: bool) -> dict:
    steps, _client = load_steps(path)
    got, elapsed = run_simulated(steps, camera=camera, progress=False, settings=settings)
    return report(steps, got, elapsed, math.inf, settings.teleop)


def test_two_simulated_replays_of_a_session_give_identical_reports(nod, tmp_path):
    settings = ServerSettings(port=0, backend="sim", gesture_dir=tmp_path / "g", audio_dir=tmp_path / "a")
    first = simulated_report(nod, settings, camera=True)
    second = simulated_report(nod, settings, camera=True)
    assert first["clock"] == "simulated" and first["speed_requested"] == "max"
    assert all(first[k] is not None and first[k] > 0 for k in WALL_FIELDS), first
    assert {k: v for k, v in first.items() if k not in WALL_FIELDS} == \
        {k: v for k, v in second.items() if k not in WALL_FIELDS}
    # Everything happens when it should in simulated time: each command answers its pose at once, the offline
    # mapping at the send times is exactly what the server commanded, frames come at the camera's 30 fps.
    assert first["latency_ms"]["pairing"] == "in_order" and first["latency_ms"]["max"] == 0.0
    assert first["commands_received"] == first["commands_expected"] and first["tracking_error_deg"]["max"] == 0.0
    camera = first["camera"]
    assert camera["fps"] == pytest.approx(30.0, abs=0.01) and camera["age_ms_p99"] == 0.0
    assert camera["frames"] >= int(first["session_s"] * 30) and first["errors"]["count"] == 0


def timing_free_teleop() -> TeleopSettings:
    """The mapping without its time-dependent parts (filters pass through, caps out of reach, no ramp): its
    commands follow from the poses alone, so a loaded machine's delays in a real-time replay cannot move them.
    (With them, the real-time server's step times show: bench/replay.py measures that against the same bound.)"""
    passthrough = {"min_cutoff_hz": 1e12, "beta": 0.0, "d_cutoff_hz": 1e12}  # even poses a microsecond apart
    return patient_teleop().model_copy(update={
        "head_filter": OneEuroSettings(**passthrough), "arm_filter": OneEuroSettings(**passthrough),
        "velocity_caps_deg_s": {name: 1e6 for name in load_qtrobot().names}, "ramp_duration_s": 0.0})


@pytest.fixture(scope="module")
def server(module_servers):
    return module_servers(backend="sim", teleop=timing_free_teleop())


def test_a_simulated_replay_agrees_with_a_real_time_replay(nod, server, tmp_path):
    steps, _client = load_steps(nod)
    got, elapsed = asyncio.run(run_replay(steps, server.url, 1.0, camera=False, progress=False))
    real = report(steps, got, elapsed, 1.0, timing_free_teleop())
    simulated = simulated_report(nod, ServerSettings(port=0, backend="sim", gesture_dir=tmp_path / "g",
                                                     audio_dir=tmp_path / "a", teleop=timing_free_teleop()),
                                 camera=False)
    assert real["clock"] == "wall" and simulated["clock"] == "simulated"
    # The same commands, but for where the engage took hold: at once in simulated time, a pose or two later in
    # real time (the server runs calls as tasks), which the report finds and the offline mapping follows.
    assert simulated["commands_received"] == simulated["commands_expected"]
    assert simulated["commands_expected"].keys() == real["commands_expected"].keys()
    assert all(abs(n - real["commands_expected"][part]) < ENGAGE_LAGS
               for part, n in simulated["commands_expected"].items()), (simulated, real)
    assert simulated["calls_answered"] == real["calls_answered"] == real["calls_sent"]
    assert simulated["tracking_error_deg"]["max"] == 0.0
    if real["latency_ms"]["pairing"] == "in_order":  # the bound: the same tracking, to 0.1 degree
        for part, errors in real["tracking_error_deg"]["by_part"].items():
            if errors["n"]:
                assert errors["mean"] <= 0.1, (part, real)
    else:  # a loaded machine dropped a slow reader's backlog: the counts tell
        assert real["commands_received"] != real["commands_expected"], real


def cli(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "vr_teleop_server.cli", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT, check=False)


def own_messages(path: Path) -> int:
    return sum(1 for step in load_steps(path)[0] if step.kind == "publish")


def test_replay_speed_max_with_a_server_sends_as_fast_as_it_takes_them_and_without_one_serves_its_own(
        nod, server):
    proc = cli("replay", str(nod), "--server", server.url, "--speed", "max", "--quiet", "--no-camera", "--json", "-")
    assert proc.returncode == 0, proc.stderr
    against = json.loads(proc.stdout)
    assert against["speed_requested"] == "max" and against["clock"] == "wall" and against["server"] == server.url
    # Sent in one burst, the server's steps see poses closer together than recorded (and the engage may take
    # hold late in a short session): that its tracking differs is expected, that it took everything is not.
    assert against["calls_answered"] == against["calls_sent"] and against["errors"]["count"] == 0
    assert against["messages_sent"] == own_messages(nod)
    proc = cli("replay", str(nod), "--speed", "max", "--quiet", "--no-camera", "--json", "-")
    assert proc.returncode == 0, proc.stderr
    own = json.loads(proc.stdout)
    assert own["server"].startswith("in-process") and own["clock"] == "simulated" and own["speed_served"] > 0
    assert own["camera"]["frames"] == 0 and own["commands_received"] == own["commands_expected"]
    for bad, why in (("0", "above 0"), ("fast", "not a number or 'max'")):
        proc = cli("replay", str(nod), "--speed", bad, timeout=60)
        assert proc.returncode == 2 and why in proc.stderr, proc.stderr


def test_study_repeat_runs_a_trial_with_successive_seeds_and_summarises_each_metric(tmp_path):
    doc = small_study().model_dump(mode="json")
    doc["parts"] = [{"name": "front", "bin": "blue_bin", "hold": False}, {"name": "bottom", "bin": "red_bin"}]
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    proc = cli("study", "run", str(path), "--trial", "teleoperated", "--speed", "max", "--repeat", "3", "--seed",
               "4", "--record-dir", str(tmp_path / "rec"), "--json", "-")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    result = json.loads(proc.stdout)["teleoperated"]
    assert result["seeds"] == [4, 5, 6] and [r["seed"] for r in result["runs"]] == [4, 5, 6]
    assert {r["outcome"] for r in result["runs"]} == {"completed"}
    assert sorted(p.name for p in (tmp_path / "rec").iterdir()) == [
        f"teleoperated-seed{s}.mcap" for s in (4, 5, 6)]
    efficiency = np.array([r["efficiency_s"] for r in result["runs"]])
    assert len(set(efficiency)) > 1  # the simulated people differ by seed
    for key, summary in result["stats"].items():
        values = np.array([r[key] for r in result["runs"]], dtype=float)
        sd = values.std(ddof=1)
        half = stats.t.ppf(0.975, 2) * sd / math.sqrt(3)
        assert summary["n"] == 3 and summary["mean"] == pytest.approx(values.mean())
        assert summary["sd"] == pytest.approx(sd)
        assert summary["ci95_low"] == pytest.approx(values.mean() - half)
        assert summary["ci95_high"] == pytest.approx(values.mean() + half)
    table = proc.stderr.split("95% CI")[1]
    assert "teleoperated" in table and "efficiency_s" in table and "h_idle" in table
    # A simulated run is its seed's: the second run again, alone, gives the same metrics.
    proc = cli("study", "run", str(path), "--trial", "teleoperated", "--speed", "max", "--seed", "5",
               "--record-dir", str(tmp_path / "again"), "--json", "-")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    again = json.loads(proc.stdout)["teleoperated"]
    assert {k: v for k, v in again.items() if k not in ("outcome", "modules")} == \
        {k: v for k, v in result["runs"][1].items() if k not in ("seed", "outcome")}


def _stamps(value, path: str = ""):
    """(path, seconds) of every header stamp in a message, however deep."""
    if isinstance(value, dict):
        stamp = value.get("stamp") if isinstance(value.get("stamp"), dict) else None
        if stamp is not None and path.endswith("header"):
            yield path, stamp.get("secs", stamp.get("sec", 0)) + stamp.get("nsecs", stamp.get("nanosec", 0)) / 1e9
        for key, item in value.items():
            yield from _stamps(item, f"{path}.{key}" if path else key)
    elif isinstance(value, list):
        for item in value:
            yield from _stamps(item, path)


def test_a_simulated_replay_stamps_every_header_on_the_simulated_clock(nod, tmp_path):
    """Every header the server writes, and every log time of its recording, is on the server's (simulated) clock,
    which starts at simclock.EPOCH: none is wall time."""
    import time

    from simclock import EPOCH
    from vr_teleop_server.core.bus import SERVER_NODE
    from vr_teleop_server.recording.format import read_recording

    wall = time.time()
    assert wall - EPOCH > 3600, "the machine's clock must be well past the simulated epoch for this test to tell"
    out = tmp_path / "replayed.mcap"
    settings = ServerSettings(port=0, backend="sim", record=out, record_camera_fps=5, gesture_dir=tmp_path / "g",
                              audio_dir=tmp_path / "a")
    steps, _client = load_steps(nod)
    run_simulated(steps, camera=True, progress=False, settings=settings)
    duration = (max(s.t for s in steps) + 120.0)  # the replay, its start and drain: well under an hour
    ours: dict[str, int] = {}
    for message in read_recording(out):
        assert EPOCH <= message.time_ns / 1e9 <= EPOCH + duration, (message.topic, message.time_ns)
        if message.sender != SERVER_NODE:
            continue  # a client's headers are its own
        for path, seconds in _stamps(message.data):
            assert EPOCH <= seconds <= EPOCH + duration, (message.topic, path, seconds)
            ours[message.topic] = ours.get(message.topic, 0) + 1
    # the server's own stamps were all looked at: events, teleop state, joint states, commands' sources...
    assert {"/vr_teleop/events", "/vr_teleop/teleop_state", "/qt_robot/joints/state",
            "/camera/color/image_raw/compressed"} <= set(ours), ours
