"""The checked-in JSON Schemas match the models; `vr-teleop schema` writes them."""

from __future__ import annotations

import json
import subprocess
import sys

from client_protocol.schema_export import SCHEMA_DIR, all_schemas, render


def test_checked_in_schemas_match_the_models():
    expected = all_schemas()
    on_disk = {p.name: p.read_text(encoding="utf-8") for p in SCHEMA_DIR.glob("*.json")}
    missing = sorted(set(expected) - set(on_disk))
    stale = sorted(set(on_disk) - set(expected))
    changed = sorted(n for n in expected if n in on_disk and render(expected[n]) != on_disk[n])
    assert not (missing or stale or changed), (
        f"client_protocol/schemas/ drifted from the models (missing {missing}, stale {stale}, changed {changed}); "
        f"run `make schema` and commit the result")


def test_schema_command_writes_one_file_per_op_and_type(tmp_path):
    out = subprocess.run([sys.executable, "-m", "vr_teleop_server.cli", "schema", "--out", str(tmp_path)],
                         capture_output=True, text=True, check=True)
    assert "schemas to" in out.stdout
    names = {p.name for p in tmp_path.iterdir()}
    assert {"op.publish.json", "op.subscribe.json", "op.png.json", "msg.geometry_msgs.PoseStamped.json",
            "srv.std_srvs.SetBool.Request.json"} <= names
    pose = json.loads((tmp_path / "msg.geometry_msgs.PoseStamped.json").read_text())
    assert set(pose["properties"]) == {"header", "pose"}
    audio = json.loads((tmp_path / "msg.audio_common_msgs.AudioData.json").read_text())
    assert audio["properties"]["data"]["contentEncoding"] == "base64"
