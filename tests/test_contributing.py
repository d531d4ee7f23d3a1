"""docs/guides/contributing.md against the code: the tables it names list what it says they list, and the files,
make targets, markers and harness names it gives exist."""

from __future__ import annotations

import json
import re
import tomllib
from pathlib import Path

import pytest

import menus.commands
import support
import testbed
from client_protocol import ops
from sim import StandIn
from testbed import processes, server
from vr_teleop_server.core.session import dispatch
from vr_teleop_server.core.transport import PAGES
from vr_teleop_server.features import menu_service
from vr_teleop_server.robot import backends
from vr_teleop_server.robot.backends import BACKENDS
from vr_teleop_server.study.kind import StudyKind
from vr_teleop_server.study.kinds import KINDS

ROOT = Path(__file__).resolve().parent.parent
PAGE = (ROOT / "docs" / "guides" / "contributing.md").read_text(encoding="utf-8")


def bullet(table: str) -> str:
    """The page's bullet that names `table`."""
    found = [b for b in re.split(r"\n- ", PAGE) if f"`{table}`" in b]
    assert len(found) == 1, f"one bullet should name {table}"
    return found[0]


def today(table: str) -> list[str]:
    """The names the bullet of `table` says it holds today: "(today `a`, `b` and `c`)"."""
    match = re.search(r"today\s+([^)]*)\)", bullet(table))
    assert match, f"the bullet of {table} says what it holds today"
    return re.findall(r"`([^`]+)`", match.group(1))


def test_the_tables_hold_what_the_page_says():
    assert today("BACKENDS") == list(BACKENDS)
    assert {"/" + p.lstrip("/") for p in PAGES} == set(today("PAGES"))
    assert today("KINDS") == list(KINDS)


@pytest.mark.parametrize("table, module", [
    ("BACKENDS", backends), ("BackendFactory", backends), ("CLIENT_OPS", ops), ("OP_HANDLERS", dispatch),
    ("Command", menus.commands), ("COMMANDS", menus.commands), ("MENU_HANDLERS", menu_service)])
def test_each_table_it_names_is_in_the_file_it_names(table, module):
    """Where a new backend, op or menu command is registered: the bullet naming the table names its file."""
    path = Path(module.__file__).relative_to(ROOT).as_posix()
    files = re.findall(r"`([\w./-]+\.py)`", bullet(table))
    assert hasattr(module, table) and any(path.endswith(f) for f in files), (table, path, files)


def test_the_study_kind_bullet_names_the_protocol():
    """Every method a kind must give is named in its bullet, and every lower-case name there is one of StudyKind's."""
    named = set(re.findall(r"`([a-z_]+)`", bullet("KINDS").split("\n\n")[0]))
    required = set(StudyKind.__abstractmethods__) | {"model", "metrics", "conditions"}
    assert required <= named, sorted(required - named)
    unknown = {n for n in named if not hasattr(StudyKind, n) and n not in StudyKind.__annotations__}
    assert unknown <= {"task", "classroom", "load_study"}, unknown


def test_the_files_it_names_exist():
    named = {p for p in re.findall(r"`([\w./-]+\.(?:py|md|yaml|toml))`", PAGE)}
    assert "robot/backends/__init__.py" in named  # the scan sees the page's paths
    missing = [p for p in named if not any((base / p).exists() for base in (ROOT, ROOT / "vr_teleop_server", ROOT / "tests"))]
    assert not missing, missing


def test_the_commands_markers_and_harness_it_names_exist():
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    for target in re.findall(r"`make ([\w-]+)", PAGE):
        assert re.search(rf"^{re.escape(target)}:", makefile, re.M), f"no make target {target}"
    markers = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["pytest"]["ini_options"]
    declared = {m.split(":")[0] for m in markers["markers"]}
    assert set(re.findall(r"^\| `(\w+)` \|", PAGE, re.M)) == declared
    assert "MUJOCO_GL" in testbed.ENVIRONMENT
    for module, names in ((server, ("in_loop", "server_settings", "RunningServer", "ServerFactory", "wait_for",
                                    "until", "Pace")),
                          (processes, ("serve", "stop", "free_port", "environment")),
                          (support, ("still", "physics_ran", "Headset")), (StandIn, ("wait_camera_stopped",))):
        for name in names:
            assert f"{name}" in PAGE and hasattr(module, name), name


def test_the_durations_file_names_only_modules_there_are():
    """tests/durations.json orders the modules longest first (conftest.py): an entry of a module renamed or removed
    is stale (a new module needs none to run: it goes first until it has one)."""
    assert "`tests/durations.json`" in PAGE and "`pytest --record-durations" in PAGE
    seconds = json.loads((ROOT / "tests" / "durations.json").read_text(encoding="utf-8"))
    assert set(seconds) <= {f"tests/{p.name}" for p in (ROOT / "tests").glob("test_*.py")}
    assert all(s >= 0 for s in seconds.values())


@pytest.mark.parametrize("fixture", ["servers", "module_servers", "browser"])
def test_the_fixtures_it_names_exist(fixture):
    assert f"`{fixture}`" in PAGE
    assert re.search(rf"@pytest.fixture[^\n]*\ndef {fixture}\(", (ROOT / "tests" / "conftest.py").read_text())
