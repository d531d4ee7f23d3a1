"""The command line as a researcher meets it in the first hour: examples reachable by name from any folder, a
study's --timeout and a recording's faults answered with sentences and exit codes, mistyped options answered by
their subcommand, a study followed live on its dashboard, reports for people with JSON on request, quiet logs."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import time
import urllib.request
from pathlib import Path
from types import SimpleNamespace

import pytest

from client_protocol.events import EventKind, EventLevel
from sim.physics import WARN_EVERY_S, Physics
from testbed.processes import free_port
from vr_teleop_server.recording.format import NotARecording, check_recording, read_recording

# Commands run as processes: a few seconds each idle, trials and replays on the stand-in; minutes on a loaded machine,
# where the timeout only catches a hang.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]

ROOT = Path(__file__).resolve().parent.parent
EXE = str(Path(sys.executable).with_name("vr-teleop"))
ENV = {**os.environ, "PYTHONUNBUFFERED": "1", "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}


def vr_teleop(*args: str, cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    # the timeout only catches a hang
    return subprocess.run([EXE, *args], cwd=cwd, env=ENV, capture_output=True, text=True, timeout=timeout)


# ---- examples ---------------------------------------------------------------------------------------------------
def test_examples_are_listed_and_copied_from_the_installed_package(tmp_path):
    listed = vr_teleop("examples", "list", cwd=tmp_path)
    assert listed.returncode == 0
    for name in ("toolbox.yaml", "classroom.yaml", "menus", "qam_paper_table1.csv", "fluency_example.csv"):
        assert name in listed.stdout
    copied = vr_teleop("examples", "copy", "mine", cwd=tmp_path)
    packaged_menus = sorted(p.name for p in (ROOT / "menus" / "data").iterdir() if p.is_file())
    files = 5 + len(packaged_menus)  # the two studies, the three sheets and the menus
    assert copied.returncode == 0 and f"copied {files} files into mine" in copied.stdout
    assert (tmp_path / "mine" / "toolbox.yaml").read_text().startswith("# The HRI framework's example study")
    assert sorted(p.name for p in (tmp_path / "mine" / "menus").iterdir()) == packaged_menus
    assert {"emotion.yaml", "speech.yaml", "sentences.en.txt"} <= set(packaged_menus)
    (tmp_path / "mine" / "toolbox.yaml").write_text("# edited\n")
    again = vr_teleop("examples", "copy", "mine", cwd=tmp_path)  # an edited copy is kept, and said so
    assert again.returncode == 0 and f"kept {files} files already there (--force overwrites them)" in again.stderr
    assert (tmp_path / "mine" / "toolbox.yaml").read_text() == "# edited\n"


def test_a_study_needs_a_file_or_an_example_by_name(tmp_path):
    neither = vr_teleop("study", "run", "--all", cwd=tmp_path)
    assert neither.returncode == 2 and "give a study FILE or --example NAME" in neither.stderr
    unknown = vr_teleop("study", "run", "--example", "toolbx", "--all", cwd=tmp_path)
    assert unknown.returncode == 2 and "invalid choice: 'toolbx'" in unknown.stderr


def next_line(stream, prefix: str) -> str:
    """The next line that starts with `prefix` (stripped); other lines (a warning of a loaded machine) are passed."""
    for line in stream:
        if line.strip().startswith(prefix):
            return line.strip()
    return ""


# ---- --timeout ----------------------------------------------------------------------------------------------------
def test_timeout_at_max_speed_ends_the_trial_with_a_sentence_and_exit_code_2(tmp_path):
    done = vr_teleop("study", "run", "--example", "toolbox", "--trial", "teleoperated", "--timeout", "8", "--speed",
                     "max", cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert ("vr-teleop study: trial teleoperated stopped by --timeout: not finished after 8 simulated s; its "
            "recording study-recordings/teleoperated.mcap holds what happened until then") in done.stderr
    assert "nothing to follow live" in done.stdout  # at --speed max, and why
    recording = tmp_path / "study-recordings" / "teleoperated.mcap"
    assert any(m.topic == "/study/state_updates" for m in read_recording(recording))


def test_a_real_time_study_is_followed_on_its_dashboard_and_its_timeout_is_a_sentence(tmp_path):
    port = free_port()
    proc = subprocess.Popen([EXE, "study", "run", "--example", "toolbox", "--trial", "teleoperated", "--timeout", "4",
                             "--port", str(port)], cwd=tmp_path, env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().startswith("running 1 trial in real time: about 51 s")
        address = f"http://127.0.0.1:{port}/"
        assert next_line(proc.stderr, "teleoperated: follow") == \
            f"teleoperated: follow it live on the dashboard at {address} (Study panel)"
        with urllib.request.urlopen(address, timeout=30) as page:  # the trial's server serves its dashboard
            assert b"dashboard.js" in page.read()
        assert next_line(proc.stderr, "teleoperated: ") == "teleoperated:   1.0 s, 0 actions done"  # first second
        assert proc.wait(timeout=300) == 2  # the timeout only catches a hang
        rest = proc.stderr.read()
        assert "trial teleoperated stopped by --timeout: not finished after 4 s" in rest and "Traceback" not in rest
    finally:
        if proc.poll() is None:
            proc.kill()


# ---- recordings ---------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def nod(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("nod")
    assert vr_teleop("synth", "nod", "--out", "nod.mcap", cwd=folder).returncode == 0
    return folder / "nod.mcap"


def test_a_replay_prints_a_summary_and_writes_json_only_when_asked(nod, tmp_path):
    done = vr_teleop("replay", str(nod), "--speed", "max", "--quiet", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert out.startswith(f"reading {nod} (0.1 MB)\nreplaying 4.0 s of session (1321 messages) on a simulated clock")
    assert "{" not in out and len(out.splitlines()) < 25
    assert "pose to command   0 ms over" in out and "simulated clock, no network" in out
    assert "joint commands    head 314/314 (received/expected)" in out
    assert list(tmp_path.iterdir()) == []
    # the JSON's two ways without the camera (the default way, above, draws it): a third of a replay's time
    done = vr_teleop("replay", str(nod), "--speed", "max", "--quiet", "--no-camera", "--json", "r.json", cwd=tmp_path)
    assert done.returncode == 0 and "wrote r.json (the full report)" in done.stdout and "{" not in done.stdout
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["closed"] is True and report["commands_received"]["head"] == 314
    piped = vr_teleop("replay", str(nod), "--speed", "max", "--quiet", "--no-camera", "--json", "-", cwd=tmp_path)
    assert json.loads(piped.stdout)["session_s"] == report["session_s"]  # stdout holds the JSON alone


def test_a_cut_off_recording_is_named_and_ends_non_zero_unless_allowed(nod, tmp_path):
    cut = tmp_path / "cut.mcap"
    data = nod.read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.65)])
    assert check_recording(nod) == check_recording(nod).__class__(closed=True, planned_s=3.989)
    assert not check_recording(cut).closed
    # without the camera, as the batch below: what is said of a cut-off recording does not depend on it
    done = vr_teleop("replay", str(cut), "--speed", "max", "--quiet", "--no-camera", cwd=tmp_path)
    assert done.returncode == 3
    assert "cut.mcap: cut off after 2.37 s of 4 s: the recording was not closed" in done.stderr
    assert "replaying what is there" in done.stderr and "pose to command" in done.stdout  # and it was replayed
    assert "exit code 3 (--allow-truncated accepts it)" in done.stderr
    allowed = vr_teleop("replay", str(cut), "--speed", "max", "--quiet", "--no-camera", "--allow-truncated",
                        cwd=tmp_path)
    assert allowed.returncode == 0 and "cut off after 2.37 s" in allowed.stderr
    batch = vr_teleop("replay", str(nod), str(cut), "--speed", "max", "--quiet", "--no-camera", cwd=tmp_path)
    assert batch.returncode == 3, batch.stderr  # a batch names it too, and is replayed whole
    assert "cut.mcap: cut off: the recording was not closed" in batch.stderr
    assert "1 recording was cut off" in batch.stderr
    assert str(cut) in batch.stdout and str(nod) in batch.stdout
    stub = tmp_path / "stub.mcap"
    stub.write_bytes(data[:2000])  # not one whole block of messages
    done = vr_teleop("replay", str(stub), "--speed", "max", "--quiet", cwd=tmp_path)
    assert done.returncode == 2 and "cut off before its first whole block of messages" in done.stderr


def test_a_foreign_file_is_not_an_mcap_file(tmp_path):
    foreign = tmp_path / "notes.mcap"
    foreign.write_text("participant 3 said hello\n")
    done = vr_teleop("replay", str(foreign), "--speed", "max", cwd=tmp_path)
    assert done.returncode == 2
    assert "notes.mcap: not an MCAP file (it does not begin as MCAP files do)" in done.stderr
    with pytest.raises(NotARecording, match="not an MCAP file"):
        list(read_recording(foreign))  # every reader of recordings says so, not "no messages"
    (tmp_path / "empty.mcap").write_bytes(b"")
    with pytest.raises(NotARecording, match=r"not an MCAP file \(an empty file\)"):
        check_recording(tmp_path / "empty.mcap")


# ---- options --------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("args", "usage", "message"), [
    (["serve", "--prot", "9702"], "usage: vr-teleop serve", "vr-teleop serve: error: unrecognized option --prot; "
                                                            "did you mean --port?"),
    (["study", "run", "--exampel", "toolbox", "--all"], "usage: vr-teleop study run",
     "unrecognized option --exampel; did you mean --example?"),
    (["replay", "x.mcap", "--speeed=max"], "usage: vr-teleop replay", "did you mean --speed?"),
    (["examples", "copy", "d", "--forse"], "usage: vr-teleop examples copy", "did you mean --force?"),
])
def test_a_mistyped_option_gets_its_subcommands_usage_and_the_nearest_option(tmp_path, args, usage, message):
    done = vr_teleop(*args, cwd=tmp_path)
    assert done.returncode == 2 and done.stderr.startswith(usage) and message in done.stderr
    assert not done.stderr.startswith("usage: vr-teleop [-h]")


# ---- logs ---------------------------------------------------------------------------------------------------------
def test_log_lines_name_things_as_the_documentation_does():
    assert f"{EventKind.ENGAGE} {EventLevel.WARNING}" == "engage warning"
    assert "teleop %s" % EventKind.ESTOP == "teleop estop"


def test_physics_falling_behind_is_said_once_then_counted(caplog):
    """The warning's state as Physics keeps it (a whole stand-in is not needed to count lines)."""
    physics = SimpleNamespace(_last_warn=-float("inf"), _behind=0, _worst_lag=0.0)
    with caplog.at_level(logging.WARNING, logger="sim.physics"):
        for lag in (0.05, 0.08, 0.12, 0.06):
            Physics._warn_behind(physics, lag, resync=False)
        assert [r.getMessage() for r in caplog.records] == [
            "stand-in physics is 50 ms behind real time (the machine is overloaded)"]
        physics._last_warn = time.monotonic() - WARN_EVERY_S  # a minute on
        Physics._warn_behind(physics, 0.07, resync=False)
    assert caplog.records[-1].getMessage().startswith(
        "stand-in physics fell behind real time 4 times in the last 60 s, by up to 120 ms")
