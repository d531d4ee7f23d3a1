"""Names defined once: client_protocol/names.py holds every topic and service name, and nothing else spells one."""

from __future__ import annotations

import ast
import re
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


# ---- the pages (vr_teleop_server/web): names.js, generated from names.py ------------------------------------------
WEB = ROOT / "vr_teleop_server" / "web"
NAMES_JS = WEB / "names.js"
JS_STRING = re.compile(r"""(["'`])((?:\\.|(?!\1).)*?)\1""")


def js_literal_names(text: str, known: set[str]) -> list[tuple[int, str]]:
    """Known names written as whole string literals in JavaScript (comments aside)."""
    found = []
    for number, line in enumerate(text.splitlines(), 1):
        code = line.split("//", 1)[0] if not line.lstrip().startswith("*") else ""
        found += [(number, m.group(2)) for m in JS_STRING.finditer(code) if m.group(2) in known]
    return found


def test_the_pages_names_module_is_current():
    assert NAMES_JS.read_text() == names.javascript_module(), (
        "vr_teleop_server/web/names.js is not what client_protocol/names.py gives: run "
        "`vr-teleop schema --out client_protocol/schemas --names-js vr_teleop_server/web/names.js`")


def test_no_page_spells_a_name_itself():
    known = set(names.all_names().values())
    files = [p for p in sorted(WEB.rglob("*.js")) if "vendor" not in p.parts and p != NAMES_JS]
    assert len(files) > 5
    found = [f"{path.relative_to(ROOT)}:{line}: {value!r} (import it from names.js)"
             for path in files for line, value in js_literal_names(path.read_text(), known)]
    assert not found, "names spelled out in the pages instead of taken from web/names.js:\n  " + "\n  ".join(found)


def test_the_page_check_sees_a_spelled_name():
    text = 'const A = "/vr_teleop/events";  // "/vr/head/pose"\nconst B = `/vr_teleop/events/x`;\n'
    assert js_literal_names(text, {names.EVENT_TOPIC, names.HEAD_POSE_TOPIC}) == [(1, "/vr_teleop/events")]
