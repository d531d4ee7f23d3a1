"""JSON Schemas of every op and every known ROS type, for client developers (the Unity team codes against them).

A copy lives in client_protocol/schemas/; a test regenerates it and fails when the two drift apart.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from .interface import endpoints
from .ops import CLIENT_OPS, SERVER_OPS, op_name
from .registry import TypeRegistry

SCHEMA_DIR = Path(__file__).with_name("schemas")


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
    return written
