"""The import rule, read from the source: no cycle between modules, and no import against the layer order.

The table below is the architecture (README, "Architecture"): layers from low to high; a module may import from
its own layer or a lower one, and a package with an entry in MAY_IMPORT only from the packages listed there (and
itself). A module in no package of the table fails too, so that a new package is placed on purpose.

The benches (bench/) and the shared fakes and harnesses (testbed/) import nothing from tests/: what both need
lives in testbed/, the top layer, which nothing of the server's may import.
"""

from __future__ import annotations

import ast
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SERVER = "vr_teleop_server"

LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("leaves", ("client_protocol", "robot_models", "menus", "sim", "netem", "worker_process", "simclock")),
    ("core, robot, recording, teleop, media", (
        f"{SERVER}.core", f"{SERVER}.robot", f"{SERVER}.recording", f"{SERVER}.teleop", f"{SERVER}.media",
        f"{SERVER}.questionnaires", f"{SERVER}.client", SERVER)),  # SERVER: the package's own __init__ (a docstring)
    ("features, study", (f"{SERVER}.features", f"{SERVER}.study")),
    ("app", (f"{SERVER}.app", f"{SERVER}.settings")),
    ("tools, cli", (f"{SERVER}.tools", f"{SERVER}.cli")),
    ("testbed", ("testbed",)),  # fakes and harnesses of the tests and the benches: above everything they drive
)
LEAVES = LAYERS[0][1]
# Narrower rules than the layer order: whom these packages may import at all (besides themselves).
MAY_IMPORT: dict[str, tuple[str, ...]] = {
    "client_protocol": ("simclock",),  # the registry stamps headers on the server's one clock
    "robot_models": ("client_protocol",),
    "menus": ("client_protocol",),
    "sim": ("client_protocol", "robot_models", "worker_process", "simclock"),
    "netem": (),
    "worker_process": (),
    "simclock": (),
    f"{SERVER}.core": ("client_protocol", "simclock"),
    f"{SERVER}.robot": LEAVES,  # knows nothing of the bus
    f"{SERVER}.teleop": LEAVES,  # pure mapping maths
    f"{SERVER}.recording.format": LEAVES,  # reading a recording needs no bus
    f"{SERVER}.questionnaires": ("client_protocol",),
    # A client knows the wire protocol only, never the server's inside: what it does, an outside client can do.
    f"{SERVER}.client": ("client_protocol",),
    f"{SERVER}.media": LEAVES + (f"{SERVER}.core", f"{SERVER}.robot"),  # never features or the app
}
PACKAGES = ("client_protocol", "robot_models", "menus", "sim", "netem", "worker_process", "simclock", SERVER, "testbed")


@dataclass(frozen=True)
class Import:
    source: str  # the importing module
    target: str  # the imported module (or package)
    file: Path
    line: int


def modules_under(root: Path, packages: Iterable[str]) -> dict[str, Path]:
    found = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")) if (root / package).is_dir() else ():
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join(parts)] = path
    return found


def _type_checking_only(node: ast.AST, parents: dict[ast.AST, ast.AST]) -> bool:
    while node in parents:
        node = parents[node]
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            return True
    return False


def imports_of(modules: dict[str, Path]) -> list[Import]:
    """Every import of one of our modules by another, lazy ones inside functions included."""
    ours = set(modules)
    found = []
    for name, path in modules.items():
        tree = ast.parse(path.read_text(), str(path))
        parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base_name = ".".join(base + ([node.module] if node.module else []))
                else:
                    base_name = node.module or ""
                targets = [f"{base_name}.{a.name}" if f"{base_name}.{a.name}" in ours else base_name
                           for a in node.names]
            else:
                continue
            if _type_checking_only(node, parents):
                continue
            for target in targets:
                while target and target not in ours:  # `import a.b.c` of a package: the deepest module we have
                    target = target.rpartition(".")[0]
                if target and target != name:
                    found.append(Import(name, target, path, node.lineno))
    return found


def owner(module: str, candidates: Iterable[str]) -> str | None:
    """The most specific entry of `candidates` that `module` belongs to."""
    best = None
    for c in candidates:
        if (module == c or module.startswith(c + ".")) and (best is None or len(c) > len(best)):
            best = c
    return best


def layer_of(module: str) -> int | None:
    packages = [p for _, ps in LAYERS for p in ps]
    pkg = owner(module, packages)
    return None if pkg is None else next(i for i, (_, ps) in enumerate(LAYERS) if pkg in ps)


def violations(imports: list[Import], modules: Iterable[str]) -> list[str]:
    problems = [f"{m}: in no layer of tests/test_architecture.py's LAYERS; add its package there"
                for m in modules if layer_of(m) is None]
    for imp in imports:
        where = f"{imp.file.relative_to(ROOT) if imp.file.is_relative_to(ROOT) else imp.file}:{imp.line}"
        rule = owner(imp.source, MAY_IMPORT)
        if rule is not None:
            if owner(imp.target, (rule, *MAY_IMPORT[rule])) is None:
                problems.append(f"{where}: {imp.source} imports {imp.target}, but {rule} may import only "
                                f"{', '.join(MAY_IMPORT[rule]) or 'nothing of ours'}")
                continue
        src, dst = layer_of(imp.source), layer_of(imp.target)
        if src is not None and dst is not None and dst > src:
            problems.append(f"{where}: {imp.source} (layer '{LAYERS[src][0]}') imports {imp.target} from the "
                            f"higher layer '{LAYERS[dst][0]}'")
    return problems


def imports_from_tests(files: Iterable[Path], tests: Path) -> list[str]:
    """Where `files` reach into `tests` (a directory of modules imported by their bare names, pytest's way): an
    import of one of its modules, or a sys.path entry naming it."""
    test_modules = {p.stem for p in tests.glob("*.py")}
    problems = []
    for path in files:
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level:
                names = [node.module or ""]
            else:
                names = []
            reached = [n for n in names if n.split(".")[0] in test_modules or n.split(".")[0] == tests.name]
            if reached:
                problems.append((path.name, node.lineno, f"imports {', '.join(reached)} from {tests.name}/"))
            elif (isinstance(node, ast.Call) and "sys.path" in ast.unparse(node.func)
                  or isinstance(node, ast.Assign) and "sys.path" in ast.unparse(node.targets[0])) \
                    and repr(tests.name) in ast.unparse(node).replace('"', "'"):
                problems.append((path.name, node.lineno, f"puts {tests.name}/ on sys.path"))
    return [f"{name}:{line} {what}" for name, line, what in sorted(problems)]


def cycles(imports: list[Import]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each as a sorted list."""
    graph: dict[str, set[str]] = {}
    for imp in imports:
        graph.setdefault(imp.source, set()).add(imp.target)
        graph.setdefault(imp.target, set())
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(graph[node]):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def describe_cycle(component: list[str], imports: list[Import]) -> str:
    members = set(component)
    edges = [f"{i.file.name}:{i.line} {i.source} -> {i.target}" for i in imports
             if i.source in members and i.target in members]
    return "import cycle between " + ", ".join(component) + ":\n    " + "\n    ".join(edges)


@pytest.fixture(scope="module")
def graph() -> tuple[dict[str, Path], list[Import]]:
    modules = modules_under(ROOT, PACKAGES)
    return modules, imports_of(modules)


def test_the_scan_sees_the_server(graph):
    modules, imports = graph
    assert f"{SERVER}.app" in modules and f"{SERVER}.core.bus" in modules
    assert any(i.source == f"{SERVER}.app" and i.target == f"{SERVER}.core.bus" for i in imports)


def test_no_import_against_the_layer_order(graph):
    modules, imports = graph
    problems = violations(imports, modules)
    assert not problems, "imports against the layers:\n  " + "\n  ".join(problems)


def test_no_import_cycles(graph):
    _, imports = graph
    found = cycles(imports)
    assert not found, "\n".join(describe_cycle(c, imports) for c in found)


def test_benches_and_the_testbed_import_nothing_from_tests():
    files = sorted((ROOT / "bench").glob("*.py")) + sorted((ROOT / "testbed").glob("*.py"))
    assert any(f.name == "suite.py" for f in files) and any(f.name == "server.py" for f in files)
    problems = imports_from_tests(files, ROOT / "tests")
    assert not problems, "bench/ and testbed/ must not reach into tests/ (move what both need to testbed/):\n  " \
        + "\n  ".join(problems)


def test_the_checks_catch_a_bad_tree(tmp_path):
    """The rules fail on what they forbid: a core module reaching a feature, and two modules importing each other."""
    server = tmp_path / SERVER
    for d in ("core", "features", "robot"):
        (server / d).mkdir(parents=True)
        (server / d / "__init__.py").write_text("")
    (server / "__init__.py").write_text("")
    (server / "core" / "bus.py").write_text("from ..features.speech import Speaker\n")
    (server / "features" / "speech.py").write_text("from ..core import bus\n")
    (server / "robot" / "interface.py").write_text("def f():\n    from vr_teleop_server.core.bus import Bus\n")
    modules = modules_under(tmp_path, [SERVER])
    imports = imports_of(modules)
    problems = violations(imports, modules)
    assert any("core/bus.py:1" in p and "imports vr_teleop_server.features.speech" in p for p in problems), problems
    assert any("robot/interface.py:2" in p and "vr_teleop_server.core.bus" in p for p in problems), problems
    found = cycles(imports)
    assert found == [[f"{SERVER}.core.bus", f"{SERVER}.features.speech"]]
    assert "bus.py:1" in describe_cycle(found[0], imports)
    tests, bench = tmp_path / "tests", tmp_path / "bench"
    tests.mkdir()
    bench.mkdir()
    (tests / "support.py").write_text("")
    (bench / "one.py").write_text('import sys\nsys.path.insert(0, str(ROOT / "tests"))\nfrom support import x\n')
    (bench / "two.py").write_text('import sys\nsys.path[:0] = [str(HERE), str(ROOT / "tests")]\n'
                                  "from testbed.server import wait_for\n")
    problems = imports_from_tests(sorted(bench.glob("*.py")), tests)
    assert problems == ["one.py:2 puts tests/ on sys.path", "one.py:3 imports support from tests/",
                        "two.py:2 puts tests/ on sys.path"], problems


# ---- sleeps in the tests ----------------------------------------------------------------------------------------------
# A test waits for an event the design guarantees (testbed.waiting's wait_for/until, a message, an acknowledgement, a
# sequence number) or runs on the simulated clock; a real-time source is paced by testbed.waiting.Pace. A sleep left
# says in a comment on its line why nothing else can work. A sleep on the simulated clock (its comment says
# "simulated time") waits for no wall-clock time and is not counted. The bound is 10; 8 are left:
# testbed/waiting.py's two polls and Pace's two waits, test_sim_standin.py's stall of the physics, and test_netem.py's
# packet spacing and its outage's two moments (a link down for 2 s, 7 s into the session).
SLEEPS_ALLOWED = 8
SIMULATED = "simulated time"


def sleeps(files: Iterable[Path]) -> list[tuple[str, str]]:
    """Each `time.sleep(...)` and `asyncio.sleep(...)` call but sleep(0) (a yield, no time), as "file:line", and
    the comment on its line ("" for none)."""
    found = []
    for path in files:
        text = path.read_text(encoding="utf-8")
        lines = text.splitlines()
        for node in ast.walk(ast.parse(text, str(path))):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "sleep"
                    and isinstance(node.func.value, ast.Name) and node.func.value.id in ("time", "asyncio")
                    and not (node.args and isinstance(node.args[0], ast.Constant) and node.args[0].value == 0)):
                line = lines[node.lineno - 1]
                found.append((f"{path.name}:{node.lineno}", line.split("#", 1)[1].strip() if "#" in line else ""))
    return found


def test_the_tests_hold_few_sleeps():
    files = sorted((ROOT / "tests").rglob("*.py")) + sorted((ROOT / "testbed").glob("*.py"))
    found = sleeps(files)
    assert any(where.startswith("waiting.py:") for where, _ in found)  # Pace and the polls of wait_for and until
    wall = [(where, why) for where, why in found if SIMULATED not in why]
    assert len(wall) <= SLEEPS_ALLOWED, (
        f"{len(wall)} wall-clock sleeps in tests/ and testbed/, at most {SLEEPS_ALLOWED}: wait for an event instead "
        "(testbed/waiting.py)\n  " + "\n  ".join(w for w, _ in wall))


def test_the_sleep_count_sees_them(tmp_path):
    (tmp_path / "a.py").write_text("import asyncio, time\ntime.sleep(0.2)\nasyncio.sleep(0)\n"
                                   "async def f():\n    await asyncio.sleep(1)  # a reason\n")
    assert sleeps([tmp_path / "a.py"]) == [("a.py:2", ""), ("a.py:5", "a reason")]
