"""The README's research commands, run as written, one after another, in an empty folder: what a researcher new to
the project types first. Each must succeed, say what it does in sentences (not a page of JSON) and leave the files
it names."""

from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from websockets.sync.client import connect

from testbed.processes import free_port
from vr_teleop_server.recording.format import check_recording

pytestmark = pytest.mark.slow  # a replay, six study trials and a server: minutes on a loaded 2-core machine

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent  # where `vr-teleop` is installed beside this Python


def research_block() -> list[str]:
    """The command lines of the README's "A researcher." block, comments dropped."""
    text = (ROOT / "README.md").read_text()
    block = re.search(r"\*\*A researcher\.\*\*.*?```sh\n(.*?)```", text, re.S)
    assert block, "the README has no researcher's block"
    return [line.split("  #")[0].strip() for line in block.group(1).splitlines() if line.strip()]


def test_the_block_is_the_one_this_test_knows():
    """The checks below follow the block's commands: a new command there needs its check here."""
    assert [shlex.split(line)[:2] for line in research_block()] == [
        ["vr-teleop", "serve"], ["vr-teleop", "synth"], ["vr-teleop", "replay"], ["vr-teleop", "study"],
        ["vr-teleop", "study"], ["vr-teleop", "qam"], ["vr-teleop", "examples"]]


@pytest.mark.timeout(3600)  # minutes on a loaded machine: the timeout only catches a hang
def test_the_readme_research_commands_run_as_written_from_an_empty_folder(tmp_path):
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}", "PYTHONUNBUFFERED": "1",
           "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    outputs = {}
    for line in research_block():
        argv = shlex.split(line)
        if argv[1] == "serve":
            outputs[line] = serve_until_interrupted(argv, tmp_path, env)
            continue
        # The timeout only catches a hang: the classroom study's three lessons take minutes on a busy machine.
        done = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=1800)
        assert done.returncode == 0, f"{line}\n{done.stdout}\n{done.stderr}"
        assert not done.stdout.lstrip().startswith(("{", "[")), f"{line}: JSON on the terminal"
        outputs[line] = done.stdout + done.stderr
    serve, synth, replay, toolbox, classroom, qam, examples = outputs.values()
    assert check_recording(tmp_path / "session.mcap").closed  # Ctrl-C closed it
    assert "OpenGL_accelerate" not in serve  # third parties' start-up notices are not shown at the default level
    assert not any("EventKind." in out for out in outputs.values())  # things named as the documentation does
    assert "classroom: 27045 headset frames" in synth and (tmp_path / "classroom.mcap").is_file()
    # the replay says at once what it does and how long it takes, then sums up for a person
    assert re.search(r"replaying 300\.\d s of session .* on a simulated clock.*about \d+ s", replay)
    assert "pose to command" in replay and "tracking error" in replay and (tmp_path / "classroom.png").is_file()
    assert "0 ms over" in replay and "simulated clock, no network" in replay  # the zero explained
    assert "running 3 trials at --speed max" in toolbox and "nothing to follow live" in toolbox
    assert all((tmp_path / "study-recordings" / f"{t}.mcap").is_file()
               for t in ("autonomous", "teleoperated", "semi-autonomous", "supervised"))
    assert "H-IDLE" in toolbox and "look mean" in classroom
    assert "QAM scores" in qam and (tmp_path / "qam.png").is_file()
    copied = tmp_path / "my-study"
    assert (copied / "toolbox.yaml").is_file() and (copied / "classroom.yaml").is_file()
    assert (copied / "menus" / "emotion.yaml").is_file() and (copied / "qam_paper_table1.csv").is_file()
    assert "copied" in examples


def serve_until_interrupted(argv: list[str], cwd: Path, env: dict[str, str]) -> str:
    """`vr-teleop serve ...` until a client has been served, then Ctrl-C. On a port of its own: 9090, the
    README's, may be another server's on this machine; the port is the one thing added to the line."""
    port = free_port()
    proc = subprocess.Popen([*argv, "--port", str(port)], cwd=cwd, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == f"vr-teleop: listening on ws://127.0.0.1:{port}"
        with connect(f"ws://127.0.0.1:{port}") as ws:
            ws.send('{"op": "call_service", "id": 1, "service": "/rosapi/get_time"}')
            assert '"service_response"' in ws.recv(timeout=30)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=120) == 0  # the timeout only catches a hang
        return proc.stdout.read() + proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
