"""`make screenshots`: the documentation's pictures, taken from the real pages.

Starts `vr-teleop serve` on the MuJoCo stand-in (a free loopback port, stopped by its process id), then drives the
operator page in Debian's Chromium through Playwright: flat, and in VR with IWER as the headset (as
tests/test_operator_page.py does), and the supervisor's dashboard. Each picture is written as a small PNG (256
colours) into the output directory; the names are what the guides link to.

    python scripts/screenshots.py --out docs/images [--only NAME ...]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path

from PIL import Image

ROOT = Path(__file__).resolve().parent.parent
IWER = ROOT / "node_modules" / "iwer" / "build" / "iwer.min.js"
INSTALL_HEADSET = ("window.xrDevice = new IWER.XRDevice(IWER.metaQuest3);"
                   "window.xrDevice.installRuntime({forceInstall: true});")
READY = "window.operator && window.operator.ros.connected && window.operator.state.teleop"
VIEWPORT = {"width": 1000, "height": 620}
SLOW = 120_000  # ms: a page, the stand-in and a software renderer share a busy machine
CALM = 60_000  # ms: how long a picture waits for the link to be good
# The server's flags per set of pictures: the teleoperation pictures without autonomy turning the head or
# proposing; the autonomy pictures with a rule that answers a pupil's line and a minute to decide.
SETS = {"headset": ("--autonomy", "teleoperated"), "flat": ("--autonomy", "teleoperated"),
        "hands": ("--autonomy", "teleoperated"), "comfort": ("--autonomy", "teleoperated"),
        "status": ("--autonomy", "teleoperated"),
        "autonomy": ("--autonomy", "supervised", "--autonomy-rules", "RULES", "--bystander-interval", "0")}
# The link warnings a picture must not show (Shots.warnings): [text] from the operator page's or the dashboard's state.
WARNINGS = """(allow) => {
  if (window.operator) {
    return window.operator.hud().filter((l) => !allow.includes(l.id) && (l.level === "error"
      || (l.id === "link" && l.level === "warning")
      || (l.id === "control" && l.text.startsWith("YOU HAVE CONTROL") && l.level !== "ok")
      || (l.id === "numbers" && l.text.includes("no frames yet")))).map((l) => `HUD ${l.id}: ${l.text}`);
  }
  const out = [], link = document.getElementById("teleop-link"), age = document.getElementById("camera-age");
  if (link && link.className && !allow.includes("link")) out.push(`dashboard link: ${link.textContent}`);
  if (age && age.textContent.includes("no frames yet")) out.push(`dashboard camera: ${age.textContent}`);
  return out;
}"""
AUTONOMY_RULES = """timeout_s: 60
on_timeout: drop
rules:
  - {id: nod, when: speech_ended, min_speech_s: 0.5, action: motion.play.list.nod,
     reason: a pupil has just said something, confidence: 0.74}
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """`vr-teleop serve --backend sim` in its own process, on loopback."""

    def __init__(self, workdir: Path, *extra: str) -> None:
        self.port = free_port()
        env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
        self.process = subprocess.Popen(
            [sys.executable, "-m", "vr_teleop_server.cli", "serve", "--backend", "sim", "--host", "127.0.0.1",
             "--port", str(self.port), "--gesture-dir", str(workdir / "gestures"), "--audio-dir",
             str(workdir / "audio"), "--log-level", "warning", *extra], cwd=ROOT, env=env)
        deadline = time.monotonic() + 120
        while True:
            if self.process.poll() is not None:
                raise SystemExit(f"vr-teleop serve exited with {self.process.returncode}")
            try:
                urllib.request.urlopen(f"http://127.0.0.1:{self.port}/", timeout=2).close()
                return
            except OSError:
                if time.monotonic() > deadline:
                    self.stop()
                    raise SystemExit("vr-teleop serve did not answer within 120 s") from None
                time.sleep(0.3)

    def stop(self) -> None:
        self.process.terminate()
        try:
            self.process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


class Shots:
    def __init__(self, browser, server: Server, out: Path) -> None:
        self.browser, self.server, self.out = browser, server, out
        self.written: list[Path] = []

    def save(self, page, name: str, stable: str = "", allow: tuple[str, ...] = (), **options) -> None:
        """A PNG of the page in 256 colours (dithered): a third of the full-colour PNG's size, text stays sharp.
        stable: a JS condition that must hold before and after the picture (retaken until it does, ten times).
        Refuses (SystemExit) a picture that shows a link warning, read from the page's state just before and just
        after it is taken; allow: the warnings (HUD line ids) the picture is meant to show."""
        for _ in range(10):
            if stable:
                page.wait_for_function(stable, timeout=SLOW)
            warnings = self.warnings(page, allow)
            png = page.screenshot(**options)
            warnings += [w for w in self.warnings(page, allow) if w not in warnings]
            if not stable or page.evaluate(stable):
                break
        if warnings:
            raise SystemExit(f"{name}.png not written: the picture would show a link warning ({'; '.join(warnings)})."
                             " The machine is probably too busy for a clean link: run it again when it is quiet.")
        path = self.out / f"{name}.png"
        image = Image.open(io.BytesIO(png)).convert("RGB")
        image.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.FLOYDSTEINBERG).save(
            path, optimize=True)
        self.written.append(path)
        print(f"{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}: {path.stat().st_size // 1024} KiB")

    @staticmethod
    def warnings(page, allow: tuple[str, ...] = ()) -> list[str]:
        """What the page shows now that a picture for the docs must not: the operator page's HUD lines (from
        window.operator.hud(), what its canvas and its DOM copy show) that are errors, a link that is not good,
        control not active, no camera frames; the dashboard's operator link when degraded or poor, no frames."""
        return page.evaluate(WARNINGS, list(allow))

    def operator(self, headset: bool):
        context = self.browser.new_context(viewport=VIEWPORT)
        page = context.new_page()
        if headset:
            page.add_init_script(path=str(IWER))
            page.add_init_script(script=INSTALL_HEADSET)
        page.goto(f"http://127.0.0.1:{self.server.port}/operator")  # the camera as a teacher gets it: WebRTC video
        page.wait_for_function(READY, timeout=SLOW)
        return page

    @staticmethod
    def enter_vr(page) -> None:
        page.get_by_role("button", name="Enter VR").click()
        page.wait_for_function("window.operator.state.xr !== null && window.operator.state.frameCount > 10",
                               timeout=SLOW)

    @staticmethod
    def frames(page, n: int = 3) -> None:
        start = page.evaluate("window.operator.state.frameCount")
        page.wait_for_function(f"window.operator.state.frameCount >= {start + n}", timeout=SLOW)

    def press(self, page, hand: str, button: str) -> None:
        page.evaluate(f"xrDevice.controllers.{hand}.updateButtonValue({button!r}, 1)")
        self.frames(page)
        page.evaluate(f"xrDevice.controllers.{hand}.updateButtonValue({button!r}, 0)")
        self.frames(page)

    @staticmethod
    def calm(page) -> None:
        """Waits a while for the HUD's link line to be calm: judged good, or not judged yet (before anyone holds
        control the link has no verdict, and its line is the round trip alone); if it is not, save() refuses the
        picture."""
        from playwright.sync_api import TimeoutError as PlaywrightTimeout

        with contextlib.suppress(PlaywrightTimeout):
            page.wait_for_function("window.operator.hud().some((l) => l.id === 'link' && ['ok', 'info']"
                                   ".includes(l.level))", timeout=CALM)

    def wait_control(self, page) -> None:
        page.wait_for_function("(document.getElementById('hud-control')?.textContent ?? '')"
                               ".startsWith('YOU HAVE CONTROL')", timeout=SLOW)

    # ---- the pictures ---------------------------------------------------------------------------------------------
    def headset(self) -> None:
        """In the headset: the page before entering VR, then the operator's view holding control, a menu open, the
        HUD's warning after the link stalled; the dashboard with the headset's page open, before it takes control."""
        page = self.operator(headset=True)
        try:
            page.wait_for_function("window.operator.camera.uploaded >= 3", timeout=SLOW)
            self.calm(page)
            self.save(page, "operator-enter-vr")
            self.dashboard()  # before anyone holds control: a headless headset's poses come too unevenly for a good link
            self.enter_vr(page)
            self.press(page, "right", "trigger")  # the right trigger takes control
            self.wait_control(page)
            page.wait_for_function("window.operator.camera.uploaded >= 10", timeout=SLOW)
            self.calm(page)
            self.frames(page, 10)
            self.save(page, "operator-vr")
            page.wait_for_function("window.operator.nav.tree !== null", timeout=SLOW)
            self.press(page, "right", "b-button")  # B: the emotion menu
            page.wait_for_function("document.getElementById('menu-title').textContent === 'Emotions'", timeout=SLOW)
            page.evaluate("xrDevice.controllers.right.updateAxes('thumbstick', 0, -1)")  # forward: the top item
            page.wait_for_function("window.operator.nav.highlight >= 0", timeout=SLOW)
            page.evaluate("xrDevice.controllers.right.updateAxes('thumbstick', 0, 0)")
            self.calm(page)
            self.frames(page, 5)
            self.save(page, "operator-vr-menu")
            self.press(page, "right", "b-button")  # B again closes the menu
            page.wait_for_function("document.getElementById('menu-title').textContent === ''", timeout=SLOW)
            # The page's thread busy for 1.5 s: no poses, the watchdog holds the robot, the HUD warns.
            page.evaluate("() => { const t = performance.now(); while (performance.now() - t < 1500) {} }")
            page.wait_for_function("/held \\d+ times? in/.test(document.getElementById('hud-link')?.textContent ?? '')",
                                   timeout=SLOW)
            self.frames(page, 10)
            self.save(page, "operator-vr-hud-warning", allow=("link", "control"))  # the hold it shows
            self.press(page, "right", "trigger")  # release control
        finally:
            page.context.close()

    @staticmethod
    def aim(page, hand: str, position: tuple[float, float, float], target: tuple[float, float, float]) -> None:
        """IWER's hand at `position`, its ray (-z) pointing at `target`."""
        d = [t - p for t, p in zip(target, position)]
        n = math.sqrt(sum(v * v for v in d))
        d = [v / n for v in d]
        axis = (d[1], -d[0], 0.0)  # (0, 0, -1) x d
        s = math.sqrt(axis[0] ** 2 + axis[1] ** 2)
        half = math.acos(max(-1.0, min(1.0, -d[2]))) / 2
        q = [a / s * math.sin(half) for a in axis] + [math.cos(half)] if s > 1e-9 else [0.0, 0.0, 0.0, 1.0]
        page.evaluate(f"xrDevice.hands.{hand}.position.set(...{list(position)});"
                      f"xrDevice.hands.{hand}.quaternion.set(...{q})")

    def pinch(self, page, hand: str) -> None:
        page.evaluate(f"xrDevice.hands.{hand}.updatePinchValue(1)")
        page.wait_for_function(f"window.operator.hands.gestures.{hand}.pinch", timeout=SLOW)
        page.evaluate(f"xrDevice.hands.{hand}.updatePinchValue(0)")
        page.wait_for_function(f"!window.operator.hands.gestures.{hand}.pinch", timeout=SLOW)

    def hands(self) -> None:
        """The controllers put down: the hands' ray on the ring of menus a pinch on the HUD opened."""
        page = self.operator(headset=True)
        try:
            self.enter_vr(page)
            page.wait_for_function("window.operator.nav.tree !== null", timeout=SLOW)
            page.evaluate("xrDevice.primaryInputMode = 'hand'")
            page.wait_for_function("document.getElementById('hud-input')?.textContent === 'input: hands'",
                                   timeout=SLOW)
            hand = (0.2, 1.2, -0.3)
            self.aim(page, "right", hand, (0.0, 1.12, -1.0))  # the HUD's centre
            self.frames(page)
            self.pinch(page, "right")
            page.wait_for_function("document.getElementById('menu-title').textContent === 'Menus'", timeout=SLOW)
            self.aim(page, "right", hand, (0.30, 1.64, -0.85))  # the ring's right place: A's menu (Commands)
            page.wait_for_function("window.operator.nav.highlight >= 0", timeout=SLOW)
            self.calm(page)
            self.frames(page, 5)
            self.save(page, "operator-vr-hands")
        finally:
            page.context.close()

    def comfort(self) -> None:
        """The comfort vignette and the reticle: holding control, the robot's head braked (it holds and ignores
        commands) while the teacher turns 20 degrees left, so the robot's head trails by 20 degrees."""
        page = self.operator(headset=True)
        mode = "window.operator.ros.call('/qt_robot/motors/setControlMode', {parts: ['head'], mode: %d})"
        try:
            page.wait_for_function("window.operator.camera.uploaded >= 3", timeout=SLOW)
            self.enter_vr(page)
            self.press(page, "right", "trigger")
            self.wait_control(page)
            page.evaluate(mode % 2)  # M_BREAK
            page.evaluate("xrDevice.quaternion.set(0, Math.sin(Math.PI / 18), 0, Math.cos(Math.PI / 18))")  # 20 deg
            page.wait_for_function("window.operator.comfort.snapshot().strength > 0.8", timeout=SLOW)
            page.wait_for_function("window.operator.camera.uploaded >= 10", timeout=SLOW)
            self.calm(page)
            self.frames(page, 10)
            self.save(page, "operator-vr-vignette", stable="window.operator.comfort.snapshot().strength > 0.8")
            page.evaluate(mode % 0)  # M_ON
            self.press(page, "right", "trigger")  # release control
        finally:
            page.context.close()

    def autonomy(self) -> None:
        """Supervised autonomy: a pupil speaks, the robot proposes; the headset's card (the teacher holding control:
        on a busy machine the panel's frames lag the face detector's boxes while autonomy turns the head), then the
        dashboard's Autonomy panel, its attention box on the camera, after a proposal accepted and one rejected."""
        page = self.operator(headset=True)
        try:
            page.wait_for_function("window.operator.camera.uploaded >= 3", timeout=SLOW)
            self.enter_vr(page)
            self.press(page, "right", "trigger")  # the teacher holds control: her head turns the robot's
            self.wait_control(page)
            self.speak(page, "child_left", "Can I ask the robot a question?")
            page.wait_for_function("window.operator.autonomy.model.current() !== null", timeout=SLOW)
            self.calm(page)
            self.frames(page, 5)
            self.save(page, "operator-vr-proposal")
            self.press(page, "right", "trigger")  # released: autonomy looks at the pupils again
            dashboard = self.browser.new_context(viewport={"width": 1400, "height": 1000}).new_page()
            try:
                dashboard.goto(f"http://127.0.0.1:{self.server.port}/#camera=jpeg")
                dashboard.wait_for_function("window.dashboard.frames >= 3", timeout=SLOW)
                for who, line, key in (("child_left", "Can I ask the robot a question?", "a"),
                                       ("child_right", "What is your name, robot?", "r"),
                                       ("adult_centre", "Look, it is waving at us.", "")):
                    shown = dashboard.evaluate("window.dashboard.autonomy.current()?.id ?? ''")
                    self.speak(page, who, line)
                    dashboard.wait_for_function(f"(window.dashboard.autonomy.current()?.id ?? '') !== {shown!r} && "
                                                "window.dashboard.autonomy.current() !== null", timeout=SLOW)
                    if key:  # accepted, then rejected: two outcomes in the list
                        dashboard.keyboard.press(key)
                        dashboard.wait_for_function("window.dashboard.autonomy.current() === null", timeout=SLOW)
                camera = dashboard.locator(".panel.camera").bounding_box()
                panel = dashboard.locator("#autonomy").bounding_box()
                top, bottom = camera["y"], panel["y"] + panel["height"]
                # the attention box over a picture from the same moment: the head at rest for two seconds
                rest = """(() => {
                    const h = window.dashboard.robotHead, now = performance.now();
                    const r = window.headRest ??= {yaw: h.yaw, pitch: h.pitch, since: now};
                    if (Math.abs(h.yaw - r.yaw) > 0.5 || Math.abs(h.pitch - r.pitch) > 0.5) {
                        Object.assign(r, {yaw: h.yaw, pitch: h.pitch, since: now});
                    }
                    return now - r.since > 2000 && !document.getElementById('attention-mark').hidden;
                })()"""
                left = min(camera["x"], panel["x"])  # the two panels, wherever the layout puts them
                right = max(camera["x"] + camera["width"], panel["x"] + panel["width"])
                self.save(dashboard, "dashboard-autonomy", stable=rest,
                          clip={"x": left, "y": top, "width": right - left, "height": bottom - top})
            finally:
                dashboard.context.close()
        finally:
            page.context.close()

    @staticmethod
    def speak(page, who: str, text: str) -> None:
        """A stand-in pupil says a line: a voice the robot hears, which the autonomy rules answer."""
        page.evaluate(f"window.operator.ros.call('/sim/bystanders/speak', {{who: {who!r}, text: {text!r}}})")

    def dashboard(self) -> None:
        from playwright.sync_api import TimeoutError as PlaywrightTimeout

        context = self.browser.new_context(viewport={"width": 1400, "height": 1000})
        page = context.new_page()
        try:
            page.goto(f"http://127.0.0.1:{self.server.port}/#camera=jpeg")
            page.wait_for_function("window.dashboard.frames >= 3", timeout=SLOW)
            page.wait_for_selector("button[data-item='emotion.happy']", timeout=SLOW)
            time.sleep(1.0)  # a second of gauges and events
            with contextlib.suppress(PlaywrightTimeout):  # the operator's link judged calm, else save() refuses
                page.wait_for_function("!document.getElementById('teleop-link')?.className", timeout=CALM)
            self.save(page, "dashboard", full_page=True)
        finally:
            context.close()

    def status(self) -> None:
        """The status panels in the headset, each opened from the left controller's Status menu (X) over the reduced
        camera view, and the same panels on the dashboard."""
        page = self.operator(headset=True)
        try:
            page.wait_for_function("window.operator.camera.uploaded >= 3", timeout=SLOW)
            self.enter_vr(page)
            for name, stick in (("motors", (0, 1)), ("motivation", (1, 0)), ("hardware", (-1, 0)),
                                ("dialog", (0, -1))):
                self.press(page, "left", "x-button")
                page.wait_for_function("document.getElementById('menu-title').textContent === 'Status'",
                                       timeout=SLOW)
                page.evaluate(f"xrDevice.controllers.left.updateAxes('thumbstick', {stick[0]}, {stick[1]})")
                page.wait_for_function("window.operator.nav.level.entries[window.operator.nav.highlight]?.item.id"
                                       f" === 'status.{name}'", timeout=SLOW)
                page.evaluate("xrDevice.controllers.left.updateAxes('thumbstick', 0, 0)")
                self.press(page, "left", "trigger")
                page.wait_for_function(f"window.operator.state.statusPanel === '{name}' && !window.operator.nav.open",
                                       timeout=SLOW)
                self.calm(page)
                self.frames(page, 10)
                self.save(page, f"operator-status-{name}")
                self.press(page, "right", "b-button")  # B closes it
                page.wait_for_function("window.operator.state.statusPanel === null", timeout=SLOW)
            dashboard = self.browser.new_context(viewport={"width": 1400, "height": 1000}).new_page()
            try:
                dashboard.goto(f"http://127.0.0.1:{self.server.port}/#camera=jpeg")
                dashboard.wait_for_function("window.dashboard.frames >= 3", timeout=SLOW)
                panels = dashboard.locator("#status-panels")
                dashboard.evaluate("window.scrollTo(0, 0)")  # the box in the page's coordinates, as full_page's
                box = panels.bounding_box()
                self.save(dashboard, "dashboard-status-panels", full_page=True, clip=box)
            finally:
                dashboard.context.close()
        finally:
            page.context.close()

    def flat(self) -> None:
        """The page without a headset: E takes control, the mouse turns the head, A opens the commands menu."""
        page = self.operator(headset=False)
        try:
            page.keyboard.press("e")
            self.wait_control(page)
            page.mouse.move(500, 300)
            page.mouse.down()
            for i in range(1, 11):
                page.mouse.move(500 - 6 * i, 300)
            page.mouse.up()
            page.keyboard.press("a")
            page.wait_for_function("document.getElementById('menu-title').textContent === 'Commands'", timeout=SLOW)
            page.wait_for_function("window.operator.camera.uploaded >= 10", timeout=SLOW)
            self.calm(page)
            self.frames(page, 10)
            self.save(page, "operator-flat")
            page.keyboard.press("Backspace")
            page.keyboard.press("e")  # release
        finally:
            page.context.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images", help="directory for the pictures")
    parser.add_argument("--chromium", default=shutil.which("chromium") or shutil.which("chromium-browser"),
                        help="the Chromium to drive (default: Debian's, from PATH)")
    parser.add_argument("--only", nargs="+", choices=tuple(SETS), default=tuple(SETS),
                        help="take only these sets (headset: its views and the dashboard; autonomy: a proposal in "
                             "the headset and the dashboard's autonomy panel; hands: the menus with hands; "
                             "comfort: the vignette and the reticle in the headset)")
    args = parser.parse_args(argv)
    if not args.chromium:
        parser.error("Chromium is not installed: scripts/install-system-packages.sh installs it")
    if not IWER.is_file():
        parser.error(f"{IWER} is missing: run `npm ci` (make's set-up does)")
    args.out.mkdir(parents=True, exist_ok=True)
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory(prefix="vr-teleop-shots-") as tmp, sync_playwright() as p:
        browser = p.chromium.launch(executable_path=args.chromium,
                                    args=["--no-sandbox", "--enable-unsafe-swiftshader"])
        rules = Path(tmp) / "rules.yaml"
        rules.write_text(AUTONOMY_RULES, encoding="utf-8")
        try:
            for flags in dict.fromkeys(SETS[name] for name in args.only):  # one server per set of flags
                server = Server(Path(tmp), *(f.replace("RULES", str(rules)) for f in flags))
                try:
                    shots = Shots(browser, server, args.out)
                    steps: dict[str, Callable[[], None]] = {"headset": shots.headset, "flat": shots.flat,
                                                            "autonomy": shots.autonomy, "hands": shots.hands,
                                                            "comfort": shots.comfort, "status": shots.status}
                    for name in args.only:
                        if SETS[name] == flags:
                            steps[name]()
                finally:
                    server.stop()
        finally:
            browser.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
