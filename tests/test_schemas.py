"""The checked-in JSON Schemas match the models; `vr-teleop schema` writes them."""

from __future__ import annotations

import json
import subprocess
import sys

import xml.etree.ElementTree as ET

from client_protocol.registry import TypeRegistry, parse_definition
from client_protocol.schema_export import MSG_SUBDIR, SCHEMA_DIR, all_schemas, message_files, render


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
    state = (tmp_path / "msg" / "vr_teleop_msgs" / "msg" / "TeleopState.msg").read_text()
    assert "string holder" in state
    assert (tmp_path / "msg" / "vr_teleop_msgs" / "srv" / "MenuSelect.srv").is_file()
    kinds = json.loads((tmp_path / "events.json").read_text())
    assert "gesture_recording" in kinds["kind"]["enum"] and kinds["level"]["enum"] == ["info", "warning", "danger"]
    recording = json.loads((tmp_path / "event.gesture_recording.json").read_text())
    assert recording["properties"]["recording"]["type"] == "boolean" and recording["required"] == ["recording"]
    assert {f"event.{kind}.json" for kind in kinds["kind"]["enum"]} <= names


def test_checked_in_message_files_match_the_definitions():
    expected = message_files()
    root = SCHEMA_DIR / MSG_SUBDIR
    on_disk = {p.relative_to(root).as_posix(): p.read_text(encoding="utf-8") for p in root.rglob("*") if p.is_file()}
    missing = sorted(set(expected) - set(on_disk))
    stale = sorted(set(on_disk) - set(expected))
    changed = sorted(n for n in expected if n in on_disk and expected[n] != on_disk[n])
    assert not (missing or stale or changed), (
        f"client_protocol/schemas/msg/ drifted from client_protocol/definitions.py (missing {missing}, stale "
        f"{stale}, changed {changed}); run `make schema` and commit the result")


def test_message_files_are_every_project_type_in_a_ros_package_layout():
    files = message_files()
    registry = TypeRegistry()
    own_messages = {n for n in registry.message_names() if n.startswith("vr_teleop_msgs/")}
    own_services = {n for n in registry.service_names() if n.startswith("vr_teleop_msgs/")}
    assert {f"vr_teleop_msgs/msg/{n.split('/')[1]}.msg" for n in own_messages} <= set(files)
    assert {f"vr_teleop_msgs/srv/{n.split('/')[1]}.srv" for n in own_services} <= set(files)
    assert not any(p.startswith(("std_msgs/", "geometry_msgs/", "sensor_msgs/")) for p in files)
    for path, text in files.items():
        package = path.split("/")[0]
        if path.endswith("package.xml"):
            assert ET.fromstring(text).findtext("name") == package
            continue
        type_name = f"{package}/{path.rsplit('/', 1)[1].split('.')[0]}"
        if path.endswith(".srv"):
            request, sep, response = text.partition("---")
            assert sep, f"{path} has no --- between request and response"
            # the file's fields are the registry's (what the server validates against)
            got = [f.name for f in parse_definition(type_name, response).fields]
            assert got == [f.name for f in registry.spec(f"{type_name}Response").fields]
            if package == "vr_teleop_msgs":  # a refusal must be readable inside the response (issue 18)
                assert got[:2] == ["success", "message"], f"{type_name} response lacks success and message"
        else:
            got = [f.name for f in parse_definition(type_name, text).fields]
            assert got == [f.name for f in registry.spec(type_name).fields]
        assert (f"{package}/package.xml") in files
