"""The operator page in a Chromium of its own with IWER (Meta's WebXR emulation runtime, npm `iwer`) as its headset:
for a page driven from an emulator's namespace (tests/test_nat_turn.py, bench/wan_page.py) and the constants the
page tests share (tests/test_operator_page.py)."""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
IWER = ROOT / "node_modules" / "iwer" / "build" / "iwer.min.js"
INSTALL_HEADSET = ("window.xrDevice = new IWER.XRDevice(IWER.metaQuest3);"
                   "window.xrDevice.installRuntime({forceInstall: true});")

READY = "window.operator && window.operator.ros.connected && window.operator.state.teleop"


@contextmanager
def operator_in_namespace(playwright, origin: str, camera: str, viewport: dict, timeout_ms: float,
                          home: Path | None = None) -> Iterator[tuple[object, list[str]]]:
    """The operator page at `origin` in a Chromium of its own, IWER as its headset, connected and ready, with its
    errors as they come: for a page driven from an emulator's namespace (test_nat_turn.py, bench/wan_page.py),
    where the origin is a plain-HTTP address the browser must treat as secure. `home`: the browser's HOME (its NSS
    database of trusted authorities)."""
    env = {**os.environ, "HOME": str(home)} if home else None
    browser = playwright.chromium.launch(executable_path=shutil.which("chromium"), env=env, args=[
        "--no-sandbox", "--enable-unsafe-swiftshader", f"--unsafely-treat-insecure-origin-as-secure={origin}"])
    try:
        page = browser.new_context(viewport=viewport).new_page()
        errors: list[str] = []
        console: list[str] = []
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.on("console", lambda msg: console.append(f"{msg.type}: {msg.text}"))
        page.on("requestfailed", lambda request: console.append(f"request failed: {request.url} "
                                                                f"({request.failure})"))
        page.add_init_script(path=str(IWER))
        page.add_init_script(script=INSTALL_HEADSET)
        page.goto(f"{origin}/operator#camera={camera}")
        try:
            page.wait_for_function(READY, timeout=timeout_ms)
        except Exception as exc:  # what the page had come to, for the failure's message
            state = page.evaluate("({operator: !!window.operator, connected: window.operator?.ros?.connected ?? null,"
                                  " teleop: !!window.operator?.state?.teleop,"
                                  " hud: document.getElementById('hud-message')?.textContent ?? null})")
            raise AssertionError(f"the operator page at {origin} was not ready: {state}; errors {errors}; "
                                 f"console {console[-20:]}") from exc
        yield page, errors
    finally:
        browser.close()
