"""Names defined once: client_protocol/names.py holds every topic and service name, and nothing else spells one."""

from __future__ import annotations

import ast
from pathlib import Path

from client_protocol import names
from client_protocol.interface import ENDPOINTS
from robot_models import load_qtrobot

ROOT = Path(__file__).resolve().parent.parent


def literal_names(path: Path, known: set[str]) -> list[tuple[int, str]]:
    """Known names written as whole string literals (docstrings and f-string pieces aside)."""
    tree = ast.parse(path.read_text(), str(path))
    skip = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.JoinedStr):
            skip.update(id(n) for n in ast.walk(node))
        if isinstance(node, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                skip.add(id(first.value))
    return [(n.lineno, n.value) for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and n.value in known and id(n) not in skip]


def test_each_name_is_defined_once():
    everything = names.all_names()
    values = list(everything.values())
    assert len(values) == len(set(values)), sorted(v for v in values if values.count(v) > 1)
    assert names.PART_COMMAND_TOPICS["head"] == "/qt_robot/head_position/command"  # the wire name, unchanged
    assert dict(names.COMMAND_TOPIC_PARTS) == {t: p for p, t in names.PART_COMMAND_TOPICS.items()}


def test_the_part_map_covers_the_robot_models_parts():
    assert set(names.PART_COMMAND_TOPICS) == set(load_qtrobot().parts)


def test_every_interface_endpoint_is_a_defined_name():
    defined = set(names.all_names().values())
    missing = sorted({e.name for e in ENDPOINTS} - defined)
    assert not missing, f"endpoints of client_protocol/interface.py not in client_protocol/names.py: {missing}"


def test_no_module_spells_a_name_itself():
    known = set(names.all_names().values())
    files = [*sorted((ROOT / "vr_teleop_server").rglob("*.py")), ROOT / "client_protocol" / "interface.py"]
    found = [f"{path.relative_to(ROOT)}:{line}: {value!r} (use client_protocol.names)"
             for path in files for line, value in literal_names(path, known)]
    assert not found, "names spelled out instead of taken from client_protocol/names.py:\n  " + "\n  ".join(found)


def test_the_literal_check_sees_a_spelled_name(tmp_path):
    module = tmp_path / "m.py"
    module.write_text('"""Publishes on "/vr_teleop/events"."""\nTOPIC = "/vr_teleop/events"\nf"{TOPIC}/x"\n')
    assert literal_names(module, {names.EVENT_TOPIC}) == [(2, "/vr_teleop/events")]
