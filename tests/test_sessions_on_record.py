"""Sessions on record, beyond tests/test_recording_replay.py: synth's motion profile and seeding, what a
recording holds after a replay, menu acknowledgements and failures in the report, and replay's CLI errors."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from testbed.processes import free_port
from support import patient_teleop

from vr_teleop_server.recording.format import read_recording
from vr_teleop_server.tools.replay import load_steps, plot, report, run_replay
from vr_teleop_server.tools.synth import build, menu_tour, write

pytestmark = pytest.mark.slow  # sessions replayed in real time

EXE = str(Path(sys.executable).with_name("vr-teleop"))


# ---- synth ------------------------------------------------------------------------------------------------------
def test_synth_sessions_are_seeded_and_the_classroom_lasts_five_minutes(tmp_path):
    a, b = build("wave", seed=1), build("wave", seed=1)
    assert a.duration == b.duration
    assert np.allclose(a.hands["right"](2.0), b.hands["right"](2.0))
    classroom = build("classroom", seed=0)
    assert 299 <= classroom.duration <= 302
    assert sum(1 for c in classroom.calls if c[1] == "/vr_teleop/menu/select") >= 3
    # Minimum-jerk: a move starts and ends at rest and peaks mid-way.
    hand = build("both-arms").hands["left"]
    t0, t1, _a, _b = next(m for m in hand.moves if np.linalg.norm(m[3] - m[2]) > 0.1)
    ts = np.linspace(t0, t1, 101)
    v = np.linalg.norm(np.diff([hand(t) for t in ts], axis=0), axis=1)
    assert v[0] < 0.02 * v.max() and v[-1] < 0.02 * v.max() and 40 <= int(np.argmax(v)) <= 60
    with pytest.raises(ValueError, match="unknown session"):
        build("juggle")


# ---- replay against a recording stand-in ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def recording_server(module_servers, tmp_path_factory: pytest.TempPathFactory):
    tmp = tmp_path_factory.mktemp("recording_server")
    server = module_servers(backend="sim", record=tmp / "session.mcap", record_camera_fps=5, teleop=patient_teleop())
    return server, tmp / "session.mcap"


def test_replay_reports_latency_tracking_camera_and_the_recording_holds_it_all(recording_server, tmp_path):
    server, recorded = recording_server
    synth = tmp_path / "wave.mcap"
    write(build("wave", seed=2), synth, seed=2)
    steps, client = load_steps(synth)
    assert client == "synth" and steps[0].kind == "publish"
    got, elapsed = asyncio.run(run_replay(steps, server.url, speed=2.0, progress=False))
    result = report(steps, got, elapsed, 2.0)
    assert result["calls_answered"] == result["calls_sent"] == 1
    assert result["errors"]["count"] == 0, result["errors"]
    # Replay never runs ahead of the speed asked (the last command can come before the session's quiet end,
    # hence the tenth above it); how close to it a machine gets is a speed figure (bench/suite.py's replay row).
    assert 0 < result["speed_served"] <= 2.2
    assert result["camera"]["frames"] > 0 and result["camera"]["fps"] >= 0  # how many: bench/suite.py's camera rows
    assert result["camera"]["age_ms_p50"] is not None and result["camera"]["age_ms_p50"] > 0  # after its stamp
    png = tmp_path / "plot.png"
    plot(got, png)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    server.call(lambda: server.server.recorder.flush())
    msgs = list(read_recording(recorded))
    # The counts decide how commands pair with poses: when the client got as many commands as the offline mapping
    # predicts, every pose caused its commands in order and the tracking is judged. On a loaded machine the server
    # may drop a slow reader's backlog or hold a starved stream; the counts then differ, commands are paired by
    # arrival and the tracking figures say nothing.
    latency, by_part = result["latency_ms"], result["tracking_error_deg"]["by_part"]
    assert latency["n"] > 0 and 0 < latency["p50"] <= latency["max"], latency
    assert by_part["left_arm"]["n"] == 0  # the wave is one-armed
    if latency["pairing"] != "in_order":
        assert result["commands_received"] != result["commands_expected"], result
    else:
        assert latency["pairing"] == "in_order" and latency["n"] > 100, latency  # the server dropped nothing
        head, right = by_part["head"], by_part["right_arm"]
        assert head["n"] > 100 and head["mean"] < 0.5, head  # the server runs the mapping offline replay runs
        # Arms: the filter and velocity caps integrate the server's own step times, so a loaded machine drifts
        # them by degrees; a wrong mapping (a side, a sign, an axis) misses by a good part of the wave's range.
        wave = np.array([c[1] for c in got.commands["right_arm"]])
        assert right["n"] > 50 and right["mean"] < 0.25 * float(np.ptp(wave, axis=0).max()), right
    by_topic = Counter((m.topic, m.schema) for m in msgs)
    assert by_topic[("/vr/head/pose", "geometry_msgs/PoseStamped")] >= len(got.sent_head)
    assert by_topic[("/qt_robot/head_position/command", "std_msgs/Float64MultiArray")] > 100
    assert by_topic[("/vr_teleop/teleop_state", "vr_teleop_msgs/TeleopState")] > 0
    events = [m.data for m in msgs if m.topic == "/vr_teleop/events"]
    assert any(e["kind"] == "engage" for e in events)
    camera = [m for m in msgs if m.topic == "/camera/color/image_raw/compressed"]
    camera_span = (camera[-1].time_ns - camera[0].time_ns) / 1e9
    assert 0 < len(camera) <= 5 * camera_span + 2  # the reduced rate, not the camera's 30 fps
    commands = [m for m in msgs if m.topic == "/qt_robot/head_position/command"]
    assert {m.sender for m in commands} == {"/vr_teleop_server"}


def test_replay_counts_acknowledged_and_failed_menu_selections(recording_server, tmp_path):
    server, _ = recording_server
    s = build("nod", seed=4)
    menu_tour(s, np.random.default_rng(0), ids=["emotion.happy", "no.such.item"], spacing=0.5)
    path = tmp_path / "menu.mcap"
    write(s, path)
    steps, _ = load_steps(path)
    got, elapsed = asyncio.run(run_replay(steps, server.url, speed=3.0, camera=False, progress=False))
    result = report(steps, got, elapsed, 3.0)
    menu = result["menu"]
    assert menu["selected"] == 2 and menu["acknowledged"] == 1
    assert list(menu["failed"]) == ["no.such.item"] and "no.such.item" in menu["failed"]["no.such.item"]
    assert menu["items_on_server"] > 10 and "emotion.sad" in menu["not_selected"]
    assert result["errors"]["count"] >= 1
    assert result["camera"]["frames"] == 0


def test_replay_cli_writes_the_report_and_plot_and_rejects_bad_input(recording_server, tmp_path):
    server, _ = recording_server
    synth = tmp_path / "nod.mcap"
    assert subprocess.run([EXE, "synth", "nod", "--out", str(synth)], timeout=120, check=False).returncode == 0
    report_path, png = tmp_path / "r.json", tmp_path / "r.png"
    result = subprocess.run([EXE, "replay", str(synth), "--server", server.url, "--speed", "4", "--report",
                             str(report_path), "--plot", str(png)], capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 0, result.stderr
    assert "replay" in result.stderr  # the progress bar
    data = json.loads(report_path.read_text())
    assert data["client"] == "synth" and data["latency_ms"]["n"] > 0 and data["speed_requested"] == 4.0
    assert png.stat().st_size > 10_000

    bad = subprocess.run([EXE, "replay", str(tmp_path / "missing.mcap"), "--server", server.url],
                         capture_output=True, text=True, timeout=60, check=False)
    assert bad.returncode == 2 and "missing.mcap" in bad.stderr
    down = subprocess.run([EXE, "replay", str(synth), "--server", f"ws://127.0.0.1:{free_port()}", "--quiet"],
                          capture_output=True, text=True, timeout=60, check=False)
    assert down.returncode == 1 and "cannot reach" in down.stderr
