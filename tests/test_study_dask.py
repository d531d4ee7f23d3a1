"""Many trials and replays on Dask (tools/distributed.py): the same tables from 1 and 2 local workers as from this
process, a trial lost with its killed worker redone once and counted once, clear errors for a scheduler that is
not there and a worker without the package, and a batch replay's summary table."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import sysconfig
import threading
from pathlib import Path

import pytest
import yaml
from testbed.processes import free_port
from study_support import small_study

from vr_teleop_server.tools.distributed import Workers, run_all
from vr_teleop_server.tools.replay import load_steps
from vr_teleop_server.tools.study_runner import TrialJob, run_job

pytestmark = pytest.mark.slow

VR_TELEOP = Path(sys.executable).parent / "vr-teleop"


def one_part_study(tmp_path: Path) -> Path:
    """The shortest trials: the small study cut to one part (a few seconds of trial each)."""
    doc = small_study().model_dump(mode="json")
    doc["parts"] = [{"name": "front", "bin": "blue_bin", "hold": False}]
    path = tmp_path / "one_part.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def vr_teleop(*args: str, timeout: float = 600, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(VR_TELEOP), *args], capture_output=True, text=True, timeout=timeout, check=False,
                          env=None if env is None else {**os.environ, **env})


def tables(stdout: str) -> str:
    """The paper-shaped table and the statistics beside it: everything from the table's head on."""
    return stdout[stdout.index("trial                modules"):stdout.index("wrote ")]


@pytest.mark.timeout(900)
def test_one_and_two_local_workers_give_the_tables_of_a_run_in_this_process(tmp_path):
    study = one_part_study(tmp_path)
    out = {}
    for workers in ("1", "2"):
        proc = vr_teleop("study", "run", str(study), "--all", "--speed", "max", "--repeat", "2", "--seed", "3",
                         "--workers", workers, "--record-dir", str(tmp_path / f"rec{workers}"),
                         "--json", str(tmp_path / f"w{workers}.json"))
        assert proc.returncode == 0, proc.stdout + proc.stderr
        out[workers] = proc.stdout
        assert proc.stdout.count("metrics from it equal the live ones") == 6
        assert sorted(p.name for p in (tmp_path / f"rec{workers}").iterdir()) == sorted(
            f"{trial}-seed{seed}.mcap" for trial in ("autonomous", "teleoperated", "semi-autonomous")
            for seed in (3, 4))
    assert "local Dask cluster of 2 worker processes" in out["2"]
    assert tables(out["1"]) == tables(out["2"])
    one, two = (json.loads((tmp_path / f"w{w}.json").read_text()) for w in ("1", "2"))
    assert one == two and [r["seed"] for r in one["teleoperated"]["runs"]] == [3, 4]
    # The recordings that came back from the workers are the trials' own: the metrics command reads the same.
    proc = vr_teleop("metrics", str(tmp_path / "rec2" / "teleoperated-seed4.mcap"), "--trial", "teleoperated",
                     "--json", "-", timeout=120)
    assert proc.returncode == 0, proc.stderr
    recorded = json.loads(proc.stdout)
    assert recorded["efficiency_s"] == one["teleoperated"]["runs"][1]["efficiency_s"]


@pytest.mark.timeout(900)
def test_a_trial_lost_with_its_killed_worker_is_redone_once_and_counted_once(tmp_path):
    from distributed import Client, LocalCluster, WorkerPlugin

    class Started(WorkerPlugin):
        """Tells the client, through the scheduler's events, when this worker begins running a task."""

        def setup(self, worker):
            self.worker = worker

        def transition(self, key, start, finish, **kwargs):
            if finish == "executing":
                self.worker.log_event("trial-started", {"key": str(key), "pid": os.getpid()})

    study = small_study()
    jobs = [TrialJob(study, name, seed, f"{name}-{seed}.mcap") for name in ("teleoperated", "autonomous")
            for seed in (1, 2)]
    sequential = {job.key: run_job(job).report.live.to_json_dict() for job in jobs}

    started: list[dict] = []
    killed: dict = {}
    lock = threading.Lock()

    def on_started(event) -> None:
        _time, msg = event
        with lock:
            started.append(msg)
            if not killed and msg["key"].startswith("teleoperated-seed2"):
                killed.update(msg)
                os.kill(msg["pid"], signal.SIGKILL)  # mid-trial: it has just begun running on that worker

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as watcher:
        pids = set(watcher.run(os.getpid).values())
        watcher.register_plugin(Started())
        watcher.subscribe_topic("trial-started", on_started)
        results = list(run_all(run_job, jobs, Workers(scheduler=cluster.scheduler_address), name=lambda j: j.key,
                               progress=False))
        watcher.unsubscribe_topic("trial-started")
    assert killed and killed["pid"] in pids, "the worker running the trial was not killed"
    runs = [m["key"].rsplit("-", 1)[0] for m in started]
    assert runs.count("teleoperated-seed2") == 2, started  # redone once, on a worker still alive
    assert all(runs.count(job.key) == 1 for job in jobs if job.key != "teleoperated-seed2"), started
    assert sorted(job.key for job, _ in results) == sorted(sequential)  # each once
    assert {job.key: done.report.live.to_json_dict() for job, done in results} == sequential
    redone = next(done for job, done in results if job.key == "teleoperated-seed2")
    assert redone.worker_pid != killed["pid"] and redone.recording and redone.report.recording_matches


@pytest.mark.timeout(300)
def test_a_scheduler_that_is_not_there_is_a_clear_error(tmp_path):
    study = one_part_study(tmp_path)
    address = f"tcp://127.0.0.1:{free_port()}"
    proc = vr_teleop("study", "run", str(study), "--all", "--speed", "max", "--scheduler", address,
                     "--record-dir", str(tmp_path / "rec"), timeout=120)
    assert proc.returncode == 1
    assert f"cannot reach the Dask scheduler at {address}" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr and not list((tmp_path / "rec").iterdir())
    proc = vr_teleop("study", "run", str(study), "--all", "--scheduler", "nowhere", timeout=120)
    assert proc.returncode == 1 and "cannot reach the Dask scheduler at nowhere: missing port" in proc.stderr


@pytest.mark.timeout(300)
def test_a_worker_without_the_package_is_named_in_a_clear_error(tmp_path):
    from distributed import LocalCluster

    # A Python that has Dask but not this package: the venv's site-packages on its path, without the site module
    # (so no .pth file installs the editable package's finder) and without this checkout on PYTHONPATH.
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PYTHONPATH"] = sysconfig.get_paths()["purelib"]
    hidden = subprocess.run([sys.executable, "-S", "-c", "import distributed, vr_teleop_server"], env=env,
                            cwd=tmp_path, capture_output=True, text=True, check=False)
    assert "No module named 'vr_teleop_server'" in hidden.stderr
    study = one_part_study(tmp_path)
    with LocalCluster(n_workers=0, processes=True, dashboard_address=None) as cluster:
        worker = subprocess.Popen([sys.executable, "-S", "-m", "distributed.cli.dask_worker", cluster.scheduler_address,
                                   "--no-nanny", "--nthreads", "1"], env=env, cwd=tmp_path,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            proc = vr_teleop("study", "run", str(study), "--all", "--speed", "max", "--scheduler",
                             cluster.scheduler_address, "--record-dir", str(tmp_path / "rec"), timeout=180)
        finally:
            worker.terminate()
            worker.wait(30)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "cannot import vr-teleop-server" in proc.stderr and "No module named 'vr_teleop_server'" in proc.stderr
    assert "worker tcp://" in proc.stderr and "pip install vr-teleop-server==" in proc.stderr
    assert not list((tmp_path / "rec").iterdir())


@pytest.mark.timeout(900)
def test_a_batch_replay_of_three_recordings_writes_one_row_per_session(tmp_path):
    files = []
    for name in ("nod", "wave", "menu-tour"):
        files.append(tmp_path / f"{name}.mcap")
        proc = vr_teleop("synth", name, "--out", str(files[-1]), timeout=120)
        assert proc.returncode == 0, proc.stderr
    # menu-tour records a gesture into the user's gesture directory: a fresh one, so that it is not there already
    proc = vr_teleop("replay", *map(str, files), "--speed", "max", "--workers", "2", "--no-camera", "--quiet",
                     "--summary", str(tmp_path / "summary"), timeout=900, env={"XDG_DATA_HOME": str(tmp_path)})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    with (tmp_path / "summary.csv").open() as f:
        rows = list(csv.DictReader(f))
    table = json.loads((tmp_path / "summary.json").read_text())
    assert [r["file"] for r in rows] == [r["file"] for r in table] == list(map(str, files))
    for row, path in zip(table, files):
        # Each row is that session's own report: every message and call of its recording sent, on the simulated
        # clock, and the head commands they caused tracked.
        steps, _client = load_steps(path)
        assert row["session_s"] == round(steps[-1].t, 2) and row["clock"] == "simulated"
        assert row["messages_sent"] == sum(1 for s in steps if s.kind == "publish") > 0
        assert row["calls_sent"] == row["calls_answered"] == sum(1 for s in steps if s.kind == "call")
        assert row["errors.count"] == 0 and row["tracking_error_deg.n"] > 0
    assert int(rows[2]["menu.selected"]) > 0 and int(rows[0]["menu.selected"]) == 0
    for path in files:
        assert str(path) in proc.stdout  # the printed table: one line per session
    proc = vr_teleop("replay", *map(str, files), "--speed", "2", timeout=60)
    assert proc.returncode == 2 and "--speed max" in proc.stderr
