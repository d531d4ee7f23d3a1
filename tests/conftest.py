"""Shared fixtures: servers on free ports (testbed/server.py) and raw WebSocket clients (see support.py)."""

from __future__ import annotations

import gc
import json
import shutil
import warnings
from collections import defaultdict
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import roslibpy

import testbed  # noqa: F401 (first: it sets the environment, MUJOCO_GL, before anything renders)
from support import RawClient, RunningServer, ServerFactory, Watch


@pytest.fixture
def servers(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerFactory]:
    """Servers for one test (testbed.server.ServerFactory: keywords are ServerSettings'), stopped after it."""
    factory = ServerFactory(tmp_path_factory.mktemp)
    yield factory
    factory.stop_all()


@pytest.fixture(scope="module")
def module_servers(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerFactory]:
    """Servers shared by a module's tests (which must leave them as they found them), stopped after the module."""
    factory = ServerFactory(tmp_path_factory.mktemp)
    yield factory
    factory.stop_all()


@pytest.fixture
def server(servers: ServerFactory) -> RunningServer:
    return servers()


@pytest.fixture
def connect_raw() -> Iterator[Callable[[str], RawClient]]:
    """Opens raw clients to any server URL and closes them after the test."""
    clients: list[RawClient] = []

    def make(url: str) -> RawClient:
        c = RawClient(url)
        clients.append(c)
        return c

    yield make
    for c in clients:
        c.close()


@pytest.fixture
def client_factory(server: RunningServer, connect_raw: Callable[[str], RawClient]) -> Callable[[], RawClient]:
    return lambda: connect_raw(server.url)


@pytest.fixture
def client(client_factory: Callable[[], RawClient]) -> RawClient:
    return client_factory()


@pytest.fixture(scope="module")
def sim_server(module_servers: ServerFactory) -> RunningServer:
    """One server with the MuJoCo stand-in per test module (it takes about a second to start)."""
    return module_servers(backend="sim")


@pytest.fixture
def ros(sim_server: RunningServer) -> Iterator[roslibpy.Ros]:
    """A roslibpy client of the module's stand-in server."""
    client = roslibpy.Ros(host="127.0.0.1", port=sim_server.port)
    client.run(timeout=10)
    yield client
    client.close()


@pytest.fixture
def watch(ros: roslibpy.Ros) -> Iterator[Callable[[str, str], Watch]]:
    """Subscribes the test's roslibpy client to topics (topic, type) and unsubscribes afterwards."""
    made: list[Watch] = []

    def make(topic: str, type_name: str) -> Watch:
        made.append(Watch(ros, topic, type_name))
        return made[-1]

    yield make
    for w in made:
        w.close()


# A full pass of the garbage collector walks every object of the process and holds every thread of it meanwhile: in
# a worker that has run a few hundred tests, 0.2 to 0.3 s (330k objects, both cores busy), long enough for the
# watchdog to hold a headset that a test plays from a thread of this process (a real headset is a process of its
# own, and the server freezes what its start-up made: cli/serve.py). So a test runs with what was there before its
# body frozen, out of the collector's passes; what was frozen is collected before a test's set-up once it has grown
# by COLLECT_AFTER objects. What that pass finds unclosed (an event loop, a socket) was left by earlier tests, not
# this one: it is collected under the default warning filters, so that it shows in the warnings' summary rather than
# failing a test that turns its own warnings into errors (`filterwarnings("error")`).
COLLECT_AFTER = 100_000
_frozen_when_collected = 0


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    global _frozen_when_collected
    if gc.get_freeze_count() - _frozen_when_collected > COLLECT_AFTER:
        gc.unfreeze()
        with warnings.catch_warnings():
            warnings.simplefilter("default")
            gc.collect()
        gc.freeze()
        _frozen_when_collected = gc.get_freeze_count()


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_call(item: pytest.Item) -> None:
    gc.freeze()


# Modules run longest first. With `--dist loadfile` pytest-xdist hands a free worker the next whole module in the
# collection's order, so a long module collected last keeps one worker busy while the other has nothing left: longest
# first (LPT) ends both workers at about the same time. DURATIONS holds each module's seconds (its tests' set-up, call
# and tear-down, from a run of it; `pytest --record-durations` rewrites the entries of the modules a run ran); a
# module not in it yet goes first, as if it were the longest, so a long new one is never the one left at the end.
DURATIONS = Path(__file__).with_name("durations.json")


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--record-durations", action="store_true",
                     help=f"write the time of each module this run ran into {DURATIONS.name}")


def pytest_configure(config: pytest.Config) -> None:
    """xdist sorts modules by their number of tests unless told not to: the order below is the one to keep."""
    if config.getoption("record_durations") and (config.option.markexpr or config.option.keyword):
        raise pytest.UsageError("--record-durations times whole modules: run it without -m or -k")
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


_spent: defaultdict[str, float] = defaultdict(float)  # seconds by module in this run


def _module(nodeid: str) -> str:
    return nodeid.split("::", 1)[0]


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A test that opens pages is a browser test (and a slow one: Chromium and SwiftShader start per module).
    Modules are ordered longest first (DURATIONS); a module's tests keep their order."""
    for item in items:
        if "browser" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.browser)
            item.add_marker(pytest.mark.slow)
    seconds = json.loads(DURATIONS.read_text())
    items.sort(key=lambda item: -seconds.get(_module(item.nodeid), float("inf")))  # stable: modules stay whole


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    """Each phase's time, counted to its module (under xdist the controller receives every worker's reports)."""
    _spent[_module(report.nodeid)] += report.duration


def pytest_sessionfinish(session: pytest.Session) -> None:
    config = session.config
    if not config.getoption("record_durations") or hasattr(config, "workerinput"):  # the controller writes it
        return
    seconds = json.loads(DURATIONS.read_text())
    seconds.update({module: round(s, 1) for module, s in _spent.items()})
    DURATIONS.write_text(json.dumps(dict(sorted(seconds.items())), indent=1) + "\n")


@pytest.fixture(scope="module")
def browser():
    """Debian's Chromium, driven by Playwright, for the dashboard's tests."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.fail("Chromium is not installed: `make test` installs it (scripts/install-system-packages.sh)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        # WebGL (the operator page) by SwiftShader on the CPU: Chromium asks for the flag before it falls back to it
        b = p.chromium.launch(executable_path=chromium, args=["--no-sandbox", "--enable-unsafe-swiftshader"])
        yield b
        b.close()
