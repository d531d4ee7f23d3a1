"""`vr-teleop study pilot`: simulated participants through the live study's own services on a simulated clock,
then the report over the folder it filled."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_a_pilot_runs_the_whole_protocol_and_the_report_reads_it(tmp_path):
    # The shipped study with a ten-second lesson, on `--perception rendered`: the study test whose lessons' faces
    # come from frames drawn and searched by the real detector (the others run on modelled, the pilot's default).
    study = tmp_path / "classroom.yaml"
    study.write_text((ROOT / "examples" / "classroom.yaml").read_text().replace("lesson_s: 180", "lesson_s: 10"))
    folder = tmp_path / "study"
    cli = [sys.executable, "-m", "vr_teleop_server.cli", "study"]
    done = subprocess.run([*cli, "pilot", str(study), "--study-dir", str(folder), "--participants", "2",
                           "--speed", "max", "--seed", "3", "--perception", "rendered"], capture_output=True, text=True, cwd=ROOT, timeout=900)
    assert done.returncode == 0, done.stderr
    assert "2 participants (P01, P02), 6 trials (6 completed)" in done.stdout
    log = [json.loads(line) for line in (folder / "events.jsonl").read_text().splitlines()]
    for pid in ("P01", "P02"):
        mine = [e for e in log if e.get("participant") == pid]
        starts = [e["condition"] for e in mine if e["what"] == "trial_start"]
        enrol = next(e for e in mine if e["what"] == "enrol")
        assert starts == enrol["order"]  # the balanced order, through /study/trial/start
        assert (folder / pid / f"{starts[0]}.mcap").stat().st_size > 0
        # every questionnaire of the file, from the participant's own page: before, after each, after the last
        given = [(e["questionnaire"], e.get("condition"), e.get("phase")) for e in mine if e["what"] == "questionnaire"]
        assert given[0] == ("qam", None, "expected") and given[-1] == ("qam", None, "perceived")
        assert sorted(c for q, c, _ in given if q == "sus") == sorted(starts)
        assert any(e["what"] == "demographics" for e in mine)
        assert all(e["who"] == f"participant:{pid}" for e in mine if e["what"] in ("questionnaire", "demographics"))
    csv = tmp_path / "long.csv"
    report = subprocess.run([*cli, "report", str(folder), "--csv", str(csv)], capture_output=True, text=True,
                            cwd=ROOT, timeout=300)
    assert report.returncode == 0, report.stderr
    assert "== sus ==" in report.stdout and "chi2(2, N = 2)" in report.stdout  # Friedman's, across conditions
    rows = csv.read_text().splitlines()
    assert rows[0] == "participant,group,condition,position,measure,value,source,note"
    assert sum(",sus," in row for row in rows) == 6
