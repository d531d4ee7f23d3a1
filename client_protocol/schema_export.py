"""JSON Schemas of every op, every known ROS type and every event kind's detail, for client developers (the Unity
team codes against them), and the `.msg`/`.srv` files of the non-standard packages in a ROS package layout (ROS#'s message generation and
other code generators read those, not JSON Schemas).

A copy lives in client_protocol/schemas/ (the ROS packages under schemas/msg/); a test regenerates both and fails
when they drift apart.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from .definitions import MESSAGES, SERVICES
from .events import KINDS, EventKind, EventLevel
from .interface import endpoints
from .ops import CLIENT_OPS, SERVER_OPS, op_name
from .registry import TypeRegistry, normalize_type_name

SCHEMA_DIR = Path(__file__).with_name("schemas")
MSG_SUBDIR = "msg"  # DIR/msg/<package>/{msg,srv}/Type.{msg,srv} and DIR/msg/<package>/package.xml
# Packages every ROS installation (or ROS# itself) already ships: their definitions are not written out.
STANDARD_PACKAGES = frozenset({
    "std_msgs", "std_srvs", "geometry_msgs", "sensor_msgs", "rosgraph_msgs", "actionlib_msgs", "actionlib",
    "rosapi", "audio_common_msgs", "file_server", "rospy_tutorials",
})
_GENERATED = "# Generated from client_protocol/definitions.py by `vr-teleop schema`; edit that file, not this one.\n"


def all_schemas() -> dict[str, dict[str, Any]]:
    """File name -> schema."""
    schemas: dict[str, dict[str, Any]] = {}
    for model in dict.fromkeys(CLIENT_OPS + SERVER_OPS):
        name = op_name(model)
        schema = model.model_json_schema()
        schema["title"] = f"rosbridge op '{name}'"
        directions = [d for d, group in (("client to server", CLIENT_OPS), ("server to client", SERVER_OPS))
                      if model in group]
        schema["description"] = f"{(model.__doc__ or '').strip()} Direction: {' and '.join(directions)}.".strip()
        schemas[f"op.{name}.json"] = schema
    registry = TypeRegistry()
    for type_name in registry.message_names():
        schemas[f"msg.{type_name.replace('/', '.')}.json"] = _type_schema(registry, type_name, type_name)
    for service in registry.service_names():
        request, response = registry.service_parts(service)
        schemas[f"srv.{service.replace('/', '.')}.Request.json"] = _type_schema(registry, request, f"{service} request")
        schemas[f"srv.{service.replace('/', '.')}.Response.json"] = _type_schema(registry, response,
                                                                                  f"{service} response")
    for kind, spec in KINDS.items():
        schema = spec.model.model_json_schema()
        schema["title"] = f"event {kind.value}"
        schema["description"] = (f"vr_teleop_msgs/Event kind {kind.value!r} (source {spec.source!r}): {spec.doc}. "
                                 "This is its detail, a JSON object sent as a string.")
        schemas[f"event.{kind.value}.json"] = schema
    schemas["events.json"] = {
        "title": "the server's event kinds",
        "description": "vr_teleop_msgs/Event's kind and level values; each kind's detail is described by "
                       "event.<kind>.json beside this file.",
        "kind": {"enum": [k.value for k in EventKind]}, "level": {"enum": [v.value for v in EventLevel]},
        "sources": {k.value: spec.source for k, spec in KINDS.items()},
    }
    schemas["interface.json"] = {
        "title": "the server's topics and services",
        "description": "Every topic and service a client uses: type, direction (client's side), rate, and one "
                       "example frame each. Types are described by the msg.* and srv.* schemas beside this file.",
        "endpoints": endpoints(),
    }
    return schemas


def _type_schema(registry: TypeRegistry, type_name: str, title: str) -> dict[str, Any]:
    schema = registry.model(type_name).model_json_schema()
    schema["title"] = title
    schema["description"] = (f"ROS type {title}. Missing fields take ROS's defaults; time is {{secs, nsecs}} "
                             f"or {{sec, nanosec}}.")
    return schema


def message_files() -> dict[str, str]:
    """Relative path (under DIR/msg/) -> text: one `.msg`/`.srv` per type of a non-standard package, and a
    minimal catkin `package.xml` per package naming the packages its fields use."""
    files: dict[str, str] = {}
    depends: dict[str, set[str]] = {}
    for kind, definitions in (("msg", MESSAGES), ("srv", SERVICES)):
        for name, text in definitions.items():
            package, type_name = normalize_type_name(name).split("/")
            if package in STANDARD_PACKAGES:
                continue
            files[f"{package}/{kind}/{type_name}.{kind}"] = _GENERATED + text.strip("\n") + "\n"
            used = depends.setdefault(package, set())
            for line in text.splitlines():
                words = line.split("#", 1)[0].split()
                if words and "/" in words[0]:
                    used.add(words[0].split("/")[0])
                elif words and words[0].rstrip("[]0123456789") == "Header":
                    used.add("std_msgs")
    for package, used in depends.items():
        deps = "".join(f"  <depend>{d}</depend>\n" for d in sorted(used - {package}))
        files[f"{package}/package.xml"] = (
            '<?xml version="1.0"?>\n<package format="2">\n'
            f"  <name>{package}</name>\n  <version>0.1.0</version>\n"
            f"  <description>{package} types of vr-teleop-server (generated by `vr-teleop schema`)</description>\n"
            '  <maintainer email="vr-teleop@example.org">vr-teleop-server</maintainer>\n'
            "  <license>MIT</license>\n  <buildtool_depend>catkin</buildtool_depend>\n"
            f"  <build_depend>message_generation</build_depend>\n{deps}"
            "  <exec_depend>message_runtime</exec_depend>\n</package>\n")
    return dict(sorted(files.items()))


def write_message_files(out_dir: Path) -> list[Path]:
    """Writes message_files() under out_dir/msg/, removing generated files of types that no longer exist."""
    root = out_dir / MSG_SUBDIR
    files = message_files()
    if root.is_dir():
        for stale in root.rglob("*"):
            if stale.is_file() and stale.relative_to(root).as_posix() not in files:
                stale.unlink()
    written = []
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
        written.append(path)
    return written


def render(schema: dict[str, Any]) -> str:
    return json.dumps(schema, indent=2, sort_keys=True) + "\n"


def write_schemas(out_dir: Path) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    schemas = all_schemas()
    for stale in out_dir.glob("*.json"):
        if stale.name not in schemas:
            stale.unlink()
    written = []
    for name, schema in sorted(schemas.items()):
        path = out_dir / name
        path.write_text(render(schema), encoding="utf-8")
        written.append(path)
    return written + write_message_files(out_dir)
