"""The `vr-teleop qam|sus|tlx|godspeed` commands: templates, scoring, JSON, charts and error exit codes."""

from __future__ import annotations

import csv
import json
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from matplotlib import image as mpimg

from vr_teleop_server.cli import main
from vr_teleop_server.questionnaires.godspeed import load_godspeed_definition

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "qam_paper_table1.csv"
EXECUTABLE = Path(sys.executable).with_name("vr-teleop")


def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", f"{path} is not a PNG"
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def assert_sensible_png(path: Path, min_size=(800, 500), max_size=(4000, 3000)) -> None:
    width, height = png_size(path)
    assert min_size[0] <= width <= max_size[0] and min_size[1] <= height <= max_size[1], (width, height)
    pixels = mpimg.imread(path)  # decodes the whole file: catches truncated output
    assert pixels.shape[:2] == (height, width)
    assert pixels[..., :3].std() > 0.05  # not a blank canvas


def test_qam_example_scores_and_plots(tmp_path, capsys):
    out_png, out_json = tmp_path / "fig.png", tmp_path / "scores.json"
    code = main(["qam", "score", str(EXAMPLE), "--plot", str(out_png), "--json", str(out_json)])
    stdout = capsys.readouterr().out
    assert code == 0
    assert "Bystander (Student, Educational Professional)" in stdout
    assert "Wilcoxon signed-rank test: not run, n too small." in stdout
    assert f"Wrote chart: {out_png}" in stdout and f"Wrote JSON: {out_json}" in stdout
    report = json.loads(out_json.read_text())
    medians = {p["id"]: (p["expected"]["median"], p["perceived"]["median"]) for p in report["subsets"][0]["parameters"]}
    assert medians[26] == (3, 5) and medians[29] == (3, 5) and medians[14] == (5, 5) and medians[4] == (None, None)
    assert_sensible_png(out_png, min_size=(1600, 700))


def test_qam_packaged_example(capsys):
    assert main(["qam", "score", "--example"]) == 0
    assert "packaged example" in capsys.readouterr().out


def test_qam_by_condition_plot_has_a_panel_per_condition(tmp_path, capsys):
    header = ["respondent_id", "phase", "condition"] + [f"P{i}" for i in range(1, 34)]
    rng = np.random.default_rng(1)
    path = tmp_path / "multi.csv"
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for condition in ("VR", "tablet"):
            for i in range(8):
                for phase in ("expected", "perceived"):
                    values = [str(v) for v in rng.integers(1, 6, 33)]
                    values[3:6] = ["-", "-", "-"]
                    writer.writerow([f"S{i}", phase, condition] + values)
    single, double = tmp_path / "one.png", tmp_path / "two.png"
    assert main(["qam", "score", str(path), "--plot", str(single)]) == 0
    assert main(["qam", "score", str(path), "--by", "condition", "--plot", str(double)]) == 0
    stdout = capsys.readouterr().out
    assert "== condition: VR: 8 expected rows, 8 perceived rows, 8 raters in both phases ==" in stdout
    assert "== condition: tablet:" in stdout and "pairs" in stdout
    assert png_size(double)[1] > png_size(single)[1]
    assert_sensible_png(double, min_size=(1600, 1000))


def test_sheet_errors_exit_2_and_are_all_listed(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    header = ["respondent_id", "phase"] + [f"P{i}" for i in range(1, 34)] + ["mood"]
    rows = [[f"R{i}", "expected"] + ["3"] * 33 + [""] for i in range(1, 5)]
    rows[3][2 + 11] = "7"  # row 5 (header is row 1), column P12
    rows[1][1] = ""
    Path("answers.csv").write_text("\n".join(",".join(r) for r in [header, *rows]) + "\n")
    code = main(["qam", "score", "answers.csv", "--plot", "never.png"])
    captured = capsys.readouterr()
    assert code == 2 and captured.out == "" and not Path("never.png").exists()
    assert captured.err.splitlines() == [
        'answers.csv, row 1, column mood: unknown column "mood" (the columns are respondent_id, phase, role, '
        "condition, P1..P33)",
        "answers.csv, row 3, column phase: the phase is missing (use expected or perceived)",
        'answers.csv, row 5, column P12: "7" is outside 1-5 (use 1-5, or "-" for missing)',
        "3 problems in answers.csv; nothing was scored.",
    ]


def test_missing_file_and_arguments(tmp_path, capsys):
    assert main(["sus", "score", str(tmp_path / "none.csv")]) == 2
    assert "none.csv: file not found" in capsys.readouterr().err
    assert main(["qam", "score"]) == 2
    assert "no sheet given" in capsys.readouterr().err
    assert main(["qam", "score", str(EXAMPLE), "--example"]) == 2
    with pytest.raises(SystemExit) as info:
        main(["qam", "score", str(EXAMPLE), "--by", "colour"])
    assert info.value.code == 2


@pytest.mark.parametrize("tool, columns", [
    ("qam", ["respondent_id", "phase", "role", "condition"] + [f"P{i}" for i in range(1, 34)]),
    ("sus", ["respondent_id", "role", "condition"] + [f"Q{i}" for i in range(1, 11)]),
    ("tlx", ["respondent_id", "role", "condition", "mental_demand", "physical_demand", "temporal_demand",
             "performance", "effort", "frustration", "w_mental_demand", "w_physical_demand", "w_temporal_demand",
             "w_performance", "w_effort", "w_frustration"]),
    ("godspeed", ["respondent_id", "role", "condition"] + [i.id for i in load_godspeed_definition().items]),
])
def test_templates(tool, columns, tmp_path, capsys):
    out = tmp_path / f"{tool}.csv"
    assert main([tool, "template", "--out", str(out), "--respondents", "3"]) == 0
    lines = out.read_text().splitlines()
    assert lines[0].split(",") == columns
    assert len(lines) == 1 + 3 * (2 if tool == "qam" else 1)
    assert f"Wrote {out}" in capsys.readouterr().out
    # an untouched template scores: everything counted as missing, nothing invented
    assert main([tool, "score", str(out)]) == 0
    capsys.readouterr()
    # never overwrite an existing sheet by accident
    assert main([tool, "template", "--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert main([tool, "template", "--out", str(out), "--force", "--respondents", "0"]) == 0
    assert len(out.read_text().splitlines()) == 1
    json_out = tmp_path / f"{tool}.json"
    assert main([tool, "template", "--out", str(json_out)]) == 0
    assert json.loads(json_out.read_text())["questionnaire"] == tool


def fill(path: Path, header: list[str], rows: list[list[str]]) -> Path:
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        writer.writerows(rows)
    return path


def test_sus_score_json_to_stdout_and_plot(tmp_path, capsys):
    header = ["respondent_id", "condition"] + [f"Q{i}" for i in range(1, 11)]
    sheet = fill(tmp_path / "sus.csv", header, [
        ["A", "VR", "5", "4", "2", "1", "2", "3", "2", "4", "5", "2"],  # Brooke's example: 55
        ["B", "VR", "5", "1", "5", "1", "5", "1", "5", "1", "5", "1"],
        ["C", "tablet", "3", "3", "3", "3", "3", "3", "3", "3", "3", "3"],
    ])
    png = tmp_path / "sus.png"
    assert main(["sus", "score", str(sheet), "--json", "-", "--by", "condition", "--plot", str(png)]) == 0
    captured = capsys.readouterr()
    report = json.loads(captured.out)  # stdout is pure JSON
    assert [r["score"] for r in report["respondents"]] == [55.0, 100.0, 50.0]
    assert [s["score"]["mean"] for s in report["subsets"]] == [77.5, 50.0]
    assert f"Wrote chart: {png}" in captured.err
    assert_sensible_png(png)
    assert main(["sus", "score", str(sheet), "--per-respondent"]) == 0
    assert "55" in capsys.readouterr().out


def test_tlx_score_and_plot(tmp_path, capsys):
    header = ["respondent_id", "mental_demand", "physical_demand", "temporal_demand", "performance", "effort",
              "frustration", "w_mental_demand", "w_physical_demand", "w_temporal_demand", "w_performance",
              "w_effort", "w_frustration"]
    sheet = fill(tmp_path / "tlx.csv", header, [
        ["A", "70", "20", "55", "30", "60", "45", "5", "0", "3", "2", "4", "1"],
        ["B", "50", "50", "50", "50", "50", "50", "", "", "", "", "", ""],
    ])
    png, out = tmp_path / "tlx.png", tmp_path / "tlx.json"
    assert main(["tlx", "score", str(sheet), "--json", str(out), "--plot", str(png)]) == 0
    stdout = capsys.readouterr().out
    assert "Weighted TLX" in stdout
    report = json.loads(out.read_text())
    assert report["respondents"][0]["weighted"] == pytest.approx(860 / 15)
    assert report["respondents"][1]["weighted"] is None
    assert_sensible_png(png)


def test_godspeed_with_custom_items_and_plot(tmp_path, capsys):
    import yaml

    from vr_teleop_server.questionnaires.definitions import data_file
    document = yaml.safe_load(data_file("godspeed.yaml").read_text())
    document["series"][4]["items"][2]["reverse"] = True
    items = tmp_path / "items.yaml"
    items.write_text(yaml.safe_dump(document))
    ids = [i.id for i in load_godspeed_definition().items]
    sheet = fill(tmp_path / "g.csv", ["respondent_id"] + ids,
                 [["A"] + ["5"] * len(ids), ["B"] + ["1"] * len(ids)])
    png = tmp_path / "g.png"
    assert main(["godspeed", "score", str(sheet), "--items", str(items), "--plot", str(png), "--json", "-"]) == 0
    report = json.loads(capsys.readouterr().out)
    safety = [r["series"]["perceived_safety"] for r in report["respondents"]]
    assert safety == [pytest.approx((5 + 5 + 1) / 3), pytest.approx((1 + 1 + 5) / 3)]
    assert_sensible_png(png)
    assert main(["godspeed", "score", str(sheet), "--items", str(tmp_path / "missing.yaml")]) == 2
    assert "missing.yaml: file not found" in capsys.readouterr().err


def test_real_executable(tmp_path):
    png = tmp_path / "paper.png"
    result = subprocess.run([str(EXECUTABLE), "qam", "score", str(EXAMPLE), "--plot", str(png)],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert "Social acceptance" in result.stdout
    assert_sensible_png(png, min_size=(1600, 700))
    bad = tmp_path / "bad.csv"
    bad.write_text("respondent_id,phase,P1\nR1,expected,9\n")
    result = subprocess.run([str(EXECUTABLE), "qam", "score", str(bad)], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 2 and result.stdout == ""
    assert f'{bad}, row 2, column P1: "9" is outside 1-5 (use 1-5, or "-" for missing)' in result.stderr
