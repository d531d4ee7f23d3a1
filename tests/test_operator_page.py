"""The operator page (/operator) in a real browser: Debian's Chromium driven by Playwright, WebGL by SwiftShader,
the headset emulated by IWER (Meta's WebXR emulation runtime, npm `iwer`), end to end on the MuJoCo stand-in.

IWER is installed into the page with Playwright's add_init_script, before the page's own scripts run; the page
itself knows nothing of it. The tests press what a teacher would: Enter VR, the right trigger to take control,
the grip to move an arm, B for the emotion menu.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
from pathlib import Path

import pytest
from scipy.spatial.transform import Rotation

from support import RawClient, RunningServer, Headset, engage, physics_ran, wait_for
from testbed.pages import INSTALL_HEADSET, IWER, READY

ROOT = Path(__file__).resolve().parent.parent
SCREENSHOTS = ROOT / ".pytest_cache" / "screenshots"
VIEWPORT = {"width": 960, "height": 600}  # SwiftShader renders every pixel on the CPU of a busy machine
SLOW = 30_000  # ms: generous waits for a page, a stand-in and a renderer sharing two cores with others


@pytest.fixture(scope="module")
def iwer() -> Path:
    if not IWER.is_file():
        pytest.fail(f"{IWER} is missing: `make test` installs it (npm ci), or run `npm ci` in {ROOT}")
    return IWER


def open_page(browser, server: RunningServer, *, headset: Path | None = None, viewport=VIEWPORT, ready=READY,
              camera: str = "jpeg", init_scripts: tuple[str, ...] = ()):
    """A new page at /operator, its errors collected; with `headset`, IWER is the WebXR device. Its camera on the
    JPEG topic (and the robot's audio on its topic) unless camera="webrtc" (test_operator_page_media.py)."""
    context = browser.new_context(viewport=viewport)
    page = context.new_page()
    page.errors = []  # type: ignore[attr-defined]
    page.on("pageerror", lambda exc: page.errors.append(str(exc)))
    if headset is not None:
        page.add_init_script(path=str(headset))
        page.add_init_script(script=INSTALL_HEADSET)
    for script in init_scripts:
        page.add_init_script(script=script)
    page.goto(f"http://127.0.0.1:{server.port}/operator#camera={camera}")
    page.wait_for_function(ready, timeout=SLOW)
    return page


def close_page(page) -> None:
    context = page.context
    page.close()
    context.close()


def enter_vr(page) -> None:
    page.get_by_role("button", name="Enter VR").click()
    page.wait_for_function("window.operator.state.xr !== null && window.operator.state.frameCount > 10",
                           timeout=SLOW)


def frames(page, n: int = 3) -> None:
    """Lets the page run n more frames (IWER applies button changes at the next frame)."""
    start = page.evaluate("window.operator.state.frameCount")
    page.wait_for_function(f"window.operator.state.frameCount >= {start + n}", timeout=SLOW)


def press(page, hand: str, button: str) -> None:
    page.evaluate(f"xrDevice.controllers.{hand}.updateButtonValue({button!r}, 1)")
    frames(page)
    page.evaluate(f"xrDevice.controllers.{hand}.updateButtonValue({button!r}, 0)")
    frames(page)


def take_control_by_key(page) -> None:
    """E takes control, as the page's help says, once the page shows that nobody holds it: the page needs the
    control state first, and a page a module's earlier test closed may still be letting go of it on a busy
    machine (E pressed before then was refused, and the wait for control ran out under two test workers)."""
    control = "(document.getElementById('hud-control')?.textContent ?? '')"
    page.wait_for_function(f"{control}.startsWith('no one in control')", timeout=SLOW)
    page.keyboard.press("e")
    try:
        page.wait_for_function(f"{control}.startsWith('YOU HAVE CONTROL')", timeout=SLOW)
    except Exception as exc:  # what the page said instead (a refusal is on its message line)
        said = page.evaluate("document.getElementById('hud').innerText")
        raise AssertionError(f"E did not take control; the HUD says: {said!r}") from exc


def choose_in_menu(page, hand: str, button: str, title: str, stick: tuple[float, float], item: str) -> None:
    """Opens the menu on `hand`'s `button` (titled `title`), points its stick at `item` and pulls the trigger."""
    press(page, hand, button)
    page.wait_for_function(f"document.getElementById('menu-title').textContent === {title!r}", timeout=SLOW)
    page.evaluate(f"xrDevice.controllers.{hand}.updateAxes('thumbstick', {stick[0]}, {stick[1]})")
    page.wait_for_function("window.operator.nav.level.entries[window.operator.nav.highlight]?.item.id"
                           f" === {item!r}", timeout=SLOW)
    page.evaluate(f"xrDevice.controllers.{hand}.updateAxes('thumbstick', 0, 0)")
    press(page, hand, "trigger")


def set_head(page, yaw_left_deg: float, pitch_up_deg: float = 0.0) -> None:
    """WebXR: +y up, -z forward; turning left is positive about +y, looking down negative about +x."""
    q = Rotation.from_euler("YX", [yaw_left_deg, pitch_up_deg], degrees=True).as_quat()
    page.evaluate(f"xrDevice.quaternion.set({q[0]}, {q[1]}, {q[2]}, {q[3]})")


def hud(page, line: str) -> str:
    return page.text_content(f"#hud-{line}") or ""


def take_control(page) -> None:
    press(page, "right", "trigger")
    page.wait_for_function("document.getElementById('hud-control')?.textContent.startsWith('YOU HAVE CONTROL')",
                           timeout=SLOW)


def settles(standin, joint: str, target: float, tolerance: float, timeout: float = 30.0) -> bool:
    """The stand-in's `joint` reaches target ± tolerance and is still there after 0.3 s more of its physics (one
    passing through on its way elsewhere is not)."""
    def there() -> bool:
        return abs(standin.joint_positions()[joint] - target) <= tolerance
    return wait_for(lambda: there() and physics_ran(standin, 0.3) and there(), timeout)


def pixels_differ(a: list[int], b: list[int]) -> float:
    return sum(abs(x - y) for x, y in zip(a, b)) / len(a)


def screenshot(page, name: str) -> None:
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SCREENSHOTS / name))


def test_the_page_and_its_scripts_are_served_from_the_package(sim_server):
    import urllib.request

    base = f"http://127.0.0.1:{sim_server.port}"
    with urllib.request.urlopen(base + "/operator") as r:
        page = r.read().decode()
    assert "Enter VR" in page and "/vendor/three/three.module.js" in page
    for path in ("/operator/main.js", "/vendor/three/three.module.js", "/vendor/three/three.core.js"):
        with urllib.request.urlopen(base + path) as r:
            assert "javascript" in r.headers["Content-Type"], path
    assert "http" not in page.split("<body>")[0].replace("http-equiv", "")  # nothing from another site


def test_the_head_follows_the_headset_and_the_panel_shows_the_robots_view(browser, iwer, sim_server, watch):
    standin = sim_server.server.robot.standin
    state = watch("/vr_teleop/teleop_state", "vr_teleop_msgs/TeleopState")
    page = open_page(browser, sim_server, headset=iwer)
    try:
        enter_vr(page)
        page.wait_for_function("window.operator.state.xr.frameRate === 120", timeout=SLOW)  # Quest 3's highest
        take_control(page)
        page.wait_for_function("window.operator.camera.uploaded >= 3", timeout=SLOW)
        assert settles(standin, "HeadYaw", 0.0, 2.0)
        before = page.evaluate("window.operator.readPixels()")
        screenshot(page, "operator_vr.png")

        set_head(page, 30.0)  # 30 degrees to the left
        assert settles(standin, "HeadYaw", 30.0, 2.0), standin.joint_positions()
        uploaded = page.evaluate("window.operator.camera.uploaded")
        page.wait_for_function(f"window.operator.camera.uploaded >= {uploaded + 3}", timeout=SLOW)
        after = page.evaluate("window.operator.readPixels()")
        assert pixels_differ(before, after) > 5, "the camera panel did not change as the robot's head turned"

        set_head(page, 30.0, -10.0)  # and 10 degrees down: QTrobot's HeadPitch is positive looking down
        assert settles(standin, "HeadPitch", 10.0, 2.0), standin.joint_positions()
        assert abs(standin.joint_positions()["HeadYaw"] - 30.0) <= 2.0
        screenshot(page, "operator_vr_turned.png")

        # The HUD: a round trip in milliseconds (on the link's line), and who holds control.
        page.wait_for_function("/round trip \\d+ ms/.test((document.getElementById('hud-link')?.textContent ?? ''))",
                               timeout=SLOW)
        assert state.latest["engaged"] and state.latest["holder"]
        assert "camera frame" in hud(page, "numbers") and "ms old" in hud(page, "numbers")
        assert page.errors == []
    finally:
        close_page(page)
    # Closing the page holds the robot: the server's watchdog sees the holder go.
    assert wait_for(lambda: state.latest.get("state") == "disconnected" and not state.latest["engaged"], 30)
    held = standin.joint_positions()["HeadYaw"]
    assert physics_ran(standin, 0.5)  # what the head would have moved in, had a command come after the hold
    assert abs(standin.joint_positions()["HeadYaw"] - held) < 1.0


def test_a_clamped_joint_is_shown_and_felt(browser, iwer, sim_server):
    standin = sim_server.server.robot.standin
    page = open_page(browser, sim_server, headset=iwer)
    try:
        enter_vr(page)
        take_control(page)
        pulses = page.evaluate("window.operator.state.pulses")
        set_head(page, 85.0)  # past HeadYaw's 60 degree limit
        page.wait_for_function("(document.getElementById('hud-clamped')?.textContent ?? '') === 'clamped joints: HeadYaw'",
                               timeout=SLOW)
        page.wait_for_function(f"window.operator.state.pulses > {pulses}", timeout=SLOW)  # a haptic pulse
        assert settles(standin, "HeadYaw", 60.0, 2.0)
        set_head(page, 0.0)
        page.wait_for_function("(document.getElementById('hud-clamped')?.textContent ?? '') === 'clamped joints: none'",
                               timeout=SLOW)
        assert page.errors == []
    finally:
        close_page(page)


def test_release_calibrate_and_estop_from_the_controllers(browser, iwer, sim_server, watch):
    state = watch("/vr_teleop/teleop_state", "vr_teleop_msgs/TeleopState")
    events = watch("/vr_teleop/events", "vr_teleop_msgs/Event")
    page = open_page(browser, sim_server, headset=iwer)
    try:
        enter_vr(page)
        take_control(page)
        press(page, "right", "trigger")  # again: release
        page.wait_for_function("(document.getElementById('hud-control')?.textContent ?? '').startsWith('no one in control')",
                               timeout=SLOW)
        assert wait_for(lambda: state.latest.get("state") == "released" and not state.latest["engaged"], 30)

        take_control(page)
        standin = sim_server.server.robot.standin
        set_head(page, 20.0)  # the operator faces 20 degrees left of where control was taken
        assert settles(standin, "HeadYaw", 20.0, 2.0), standin.joint_positions()
        page.evaluate("xrDevice.controllers.left.position.set(-0.75, 1.45, 0.0);"
                      "xrDevice.controllers.right.position.set(0.75, 1.45, 0.0)")  # a T-pose
        frames(page, 5)
        press(page, "right", "thumbstick")  # the right stick alone: calibrate, and while in control recenter
        page.wait_for_function("(document.getElementById('hud-message')?.textContent ?? '').startsWith('calibrated: ')"
                               " && document.getElementById('hud-message').textContent.includes('recentered')",
                               timeout=SLOW)
        assert wait_for(lambda: events.any(lambda e: e["source"] == "teleop" and e["kind"] == "calibrate"), 30)
        assert wait_for(lambda: events.any(lambda e: e["source"] == "teleop" and e["kind"] == "recenter"), 30)
        # where the operator faces is straight ahead now: the robot's head comes back to the centre
        assert settles(standin, "HeadYaw", 0.0, 2.0), standin.joint_positions()

        page.evaluate("xrDevice.controllers.left.updateButtonValue('thumbstick', 1);"
                      "xrDevice.controllers.right.updateButtonValue('thumbstick', 1)")  # both sticks: e-stop
        frames(page)
        page.evaluate("xrDevice.controllers.left.updateButtonValue('thumbstick', 0);"
                      "xrDevice.controllers.right.updateButtonValue('thumbstick', 0)")
        page.wait_for_function("(document.getElementById('hud-control')?.textContent ?? '').startsWith('E-STOPPED')",
                               timeout=SLOW)
        assert wait_for(lambda: state.latest.get("state") == "estopped" and not state.latest["engaged"], 30)
        frames(page, 30)  # the right stick's release, part of the e-stop, did not calibrate as well
        assert sum(1 for e in events.messages if e["source"] == "teleop" and e["kind"] == "calibrate") == 1
        assert page.errors == []
    finally:
        close_page(page)


def test_the_grip_moves_the_right_arm_and_releasing_it_holds(browser, iwer, sim_server):
    standin = sim_server.server.robot.standin
    arm = ("RightShoulderPitch", "RightShoulderRoll", "RightElbowRoll")

    def right_arm() -> list[float]:
        j = standin.joint_positions()
        return [j[n] for n in arm]

    page = open_page(browser, sim_server, headset=iwer)
    try:
        enter_vr(page)
        page.evaluate("xrDevice.controllers.right.position.set(0.2, 1.1, -0.1)")  # the hand hanging, roughly
        take_control(page)
        start = right_arm()
        page.evaluate("xrDevice.controllers.right.updateButtonValue('squeeze', 1)")
        page.wait_for_function("window.operator.state.teleop.right_arm_following", timeout=SLOW)
        page.evaluate("xrDevice.controllers.right.position.set(0.25, 1.45, -0.55)")  # forward and up
        assert wait_for(lambda: max(abs(a - b) for a, b in zip(right_arm(), start)) > 20, 30), (start, right_arm())

        page.evaluate("xrDevice.controllers.right.updateButtonValue('squeeze', 0)")
        page.wait_for_function("!window.operator.state.teleop.right_arm_following", timeout=SLOW)
        assert physics_ran(standin, 0.5)  # the arm comes to rest at the last goal it was given
        held = right_arm()
        page.evaluate("xrDevice.controllers.right.position.set(0.2, 1.0, 0.0)")  # the hand drops: the arm stays
        frames(page, 30)
        assert physics_ran(standin, 0.5)  # what the arm would have moved in, had the dropped hand moved it
        assert max(abs(a - b) for a, b in zip(right_arm(), held)) < 2.0, (held, right_arm())
        assert page.errors == []
    finally:
        close_page(page)


def test_the_emotion_menu_shows_happy_on_the_robots_face(browser, iwer, sim_server, watch):
    standin = sim_server.server.robot.standin
    events = watch("/vr_teleop/events", "vr_teleop_msgs/Event")
    if standin.emotion == "happy":
        other = RawClient(sim_server.url)
        other.send({"op": "publish", "topic": "/qt_robot/emotion/show", "msg": {"data": "sad"}})
        assert wait_for(lambda: standin.emotion == "sad", 30)
        other.close()
    # A spy on the server's /qt_robot/emotion/show service (the menu command calls it on the bus), restored after.
    calls: list[tuple[str, str]] = []
    service = sim_server.call(lambda: sim_server.server.bus.services["/qt_robot/emotion/show"])
    provider = service.provider

    async def spy(request, timeout):
        from vr_teleop_server.core.bus import Bus

        calls.append((request.name, Bus.caller()))
        return await provider(request, timeout)

    sim_server.call(lambda: setattr(service, "provider", spy))
    page = open_page(browser, sim_server, headset=iwer)
    try:
        enter_vr(page)
        page.wait_for_function("window.operator.nav.tree !== null", timeout=SLOW)
        press(page, "right", "b-button")  # B on the right: the emotion menu (menus/data/emotion.yaml)
        page.wait_for_function("document.getElementById('menu-title').textContent === 'Emotions'", timeout=SLOW)
        page.evaluate("xrDevice.controllers.right.updateAxes('thumbstick', 0, -1)")  # pushed forward: the top item
        page.wait_for_function("window.operator.nav.highlight >= 0 && window.operator.nav.level"
                               ".entries[window.operator.nav.highlight].item.id === 'emotion.happy'", timeout=SLOW)
        page.evaluate("xrDevice.controllers.right.updateAxes('thumbstick', 0, 0)")
        screenshot(page, "operator_vr_menu.png")
        press(page, "right", "trigger")
        assert wait_for(lambda: standin.emotion == "happy", 30)
        assert wait_for(lambda: events.any(lambda e: e["source"] == "menu" and e["kind"] == "select" and json.loads(
            e["detail"]).get("result") == "showing happy"), 30)  # /qt_robot/emotion/show ran for the menu
        page.wait_for_function("window.operator.state.footer?.text === 'Happy: showing happy'", timeout=SLOW)
        assert [name for name, _caller in calls] == ["happy"]  # /qt_robot/emotion/show carried it, once
        assert calls[0][1].startswith("/rosbridge_websocket/client_")  # on behalf of the page's session
        assert page.errors == []
    finally:
        sim_server.call(lambda: setattr(service, "provider", provider))
        close_page(page)


def test_another_holder_is_shown_and_the_refused_engage_is_said(browser, iwer, sim_server, ros, watch):
    state = watch("/vr_teleop/teleop_state", "vr_teleop_msgs/TeleopState")
    headset = Headset(ros).start()
    try:
        engage(ros)
        assert wait_for(lambda: state.latest.get("engaged") and state.latest.get("holder"), 30)
        holder = state.latest["holder"]
        page = open_page(browser, sim_server, headset=iwer)
        try:
            enter_vr(page)
            page.wait_for_function(f"(document.getElementById('hud-control')?.textContent ?? '')"
                                   f".includes('control held by {holder}')", timeout=SLOW)
            press(page, "right", "trigger")
            page.wait_for_function("(document.getElementById('hud-message')?.textContent ?? '')"
                                   ".startsWith('taking control refused: control is held by another client')",
                                   timeout=SLOW)
            assert state.latest["holder"] == holder
            frames(page, 10)
            assert page.errors == []
        finally:
            close_page(page)
    finally:
        headset.stop()
        call_release(ros)


def call_release(ros) -> None:
    from support import call

    call(ros, "/vr_teleop/control/engage", "std_srvs/SetBool", {"data": False})


def test_the_flat_view_drives_the_head_with_the_mouse(browser, sim_server):
    standin = sim_server.server.robot.standin
    page = open_page(browser, sim_server, viewport={"width": 1000, "height": 640})
    try:
        assert page.get_by_role("button", name="Enter VR").is_disabled()  # no headset: the flat view
        take_control_by_key(page)
        page.mouse.move(500, 300)
        page.mouse.down()
        for i in range(1, 11):
            page.mouse.move(500 - 8 * i, 300)  # drag 80 px to the left: 20 degrees (0.25 degrees a pixel)
        page.mouse.up()
        assert settles(standin, "HeadYaw", 20.0, 2.0), standin.joint_positions()
        # The keyboard drives the menus: A opens the commands menu.
        page.keyboard.press("a")
        page.wait_for_function("document.getElementById('menu-title').textContent === 'Commands'", timeout=SLOW)
        page.keyboard.press("ArrowRight")
        frames(page, 5)
        screenshot(page, "operator_flat.png")
        page.keyboard.press("Backspace")
        page.wait_for_function("document.getElementById('menu-title').textContent === ''", timeout=SLOW)
        # A denied microphone is said, and the page keeps running.
        page.keyboard.down("t")
        page.wait_for_function("document.getElementById('hud-message')?.textContent.startsWith('microphone')",
                               timeout=SLOW)
        page.keyboard.up("t")
        frames(page, 10)
        assert page.errors == []
    finally:
        close_page(page)


def test_the_hud_shows_the_links_quality_and_warns_after_a_hold(browser, sim_server):
    """The link line follows this page's entry of /vr_teleop/telemetry: measured and named on loopback; after the
    page stalls long enough for the watchdog to hold the robot, it warns and says so."""
    page = open_page(browser, sim_server)
    try:
        take_control_by_key(page)
        # loopback: good, or degraded (or poor: a busy machine stalls the page, and the watchdog holds) but measured
        page.wait_for_function("/^(link good · round trip \\d+ ms|LINK (DEGRADED|POOR): .+)$/.test("
                               "document.getElementById('hud-link')?.textContent ?? '')", timeout=SLOW)
        holds = page.evaluate("window.operator.state.link?.watchdog_holds ?? 0")
        # the page's thread busy for 1.5 s: no poses, the watchdog (ceiling 0.5 s) holds the robot once more (a busy
        # machine may have made it hold before: the count goes up by this one, whatever it was; its failure in CI
        # under two test workers waited for "held 1 time" while the line said more)
        page.evaluate("() => { const t = performance.now(); while (performance.now() - t < 1500) {} }")
        page.wait_for_function(f"(window.operator.state.link?.watchdog_holds ?? 0) > {holds} && /held \\d+ times? in "
                               "the last minute/.test(document.getElementById('hud-link')?.textContent ?? '')",
                               timeout=SLOW)
        assert hud(page, "link").startswith(("LINK DEGRADED: ", "LINK POOR: "))
        assert page.get_attribute("#hud-link", "class") in ("warning", "error")
        assert page.errors == []
    finally:
        close_page(page)
    assert wait_for(lambda: sim_server.call(lambda: sim_server.server.control.holder) is None, 30)


# Every state the HUD shows, as it shows it: its lines (id -> text) and whether the view had a camera frame then.
HUD_LOG = """window.hudLog = [];
document.addEventListener('DOMContentLoaded', () => {
  const hud = document.getElementById('hud');
  new MutationObserver(() => window.hudLog.push({
    lines: Object.fromEntries([...hud.children].map((p) => [p.id, p.textContent])),
    frame: !!window.operator && window.operator.camera.frameAge() !== null,
  })).observe(hud, {childList: true});
});"""


def test_the_hud_never_contradicts_itself(browser, iwer, sim_server):
    """Issue 42: one figure per line, each from one source, and the link judged only once there is one. Every state
    the headset's HUD went through, from the page's opening to control held: the round trip on one line at most
    (the link's, from the telemetry), no camera figure while the view waits for its first frame, and no verdict on
    the link (good, degraded, poor) before this page holds control."""
    page = open_page(browser, sim_server, headset=iwer, init_scripts=(HUD_LOG,))
    try:
        enter_vr(page)
        link = "(document.getElementById('hud-link')?.textContent ?? '')"
        page.wait_for_function(f"/^round trip \\d+ ms$/.test({link})", timeout=SLOW)  # measured, not judged
        page.wait_for_function("window.operator.camera.uploaded >= 3", timeout=SLOW)
        SCREENSHOTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(SCREENSHOTS / "operator_hud_before_control.png"))
        take_control(page)
        page.wait_for_function(f"/^(link good · round trip \\d+ ms|LINK (DEGRADED|POOR): .*round trip \\d+ ms.*)$/"
                               f".test({link})", timeout=SLOW)
        page.screenshot(path=str(SCREENSHOTS / "operator_hud_in_control.png"))
        log = page.evaluate("window.hudLog")
        held = [i for i, s in enumerate(log) if s["lines"].get("hud-control", "").startswith("YOU HAVE CONTROL")]
        assert held and any(s["frame"] for s in log), log[-1]
        for s in log:
            lines = s["lines"]
            assert sum("round trip" in text for text in lines.values()) <= 1, lines
            assert not any("no frames yet" in text for text in lines.values()), lines
            # never a camera figure before the first frame (the line is drawn a frame after one arrives)
            assert s["frame"] or "camera frame" not in lines.get("hud-numbers", ""), s
        for s in log[:held[0]]:
            assert re.fullmatch(r"(round trip( \d+ ms|: measuring))?", s["lines"].get("hud-link", "")), s["lines"]
        assert page.errors == []
    finally:
        close_page(page)
    assert wait_for(lambda: sim_server.call(lambda: sim_server.server.control.holder) is None, 30)


def test_an_undrawable_menu_message_is_said_and_the_last_menus_stay(browser, sim_server):
    page = open_page(browser, sim_server)
    try:
        page.wait_for_function("window.operator.nav.tree !== null", timeout=SLOW)
        bad = {"menus": [{"id": "m", "label": "M", "controller": "right", "button": "A", "icon": ""}],
               "items": [{"id": "m.x", "menu": "m", "parent": "nowhere", "label": "X", "slot": "top",
                          "position": 0, "icon": "", "command": "estop", "args": ""}]}
        page.evaluate("(msg) => window.operator.ros.receive({op: 'publish', topic: '/vr_teleop/menus', msg})", bad)
        page.wait_for_function("(document.getElementById('hud-message')?.textContent ?? '').startsWith('menus cannot be "
                               "drawn (item m.x: its parent nowhere is unknown)')", timeout=SLOW)
        page.keyboard.press("b")  # the last good menus still work
        page.wait_for_function("document.getElementById('menu-title').textContent === 'Emotions'", timeout=SLOW)
        assert page.errors == []
    finally:
        close_page(page)


def test_a_dropped_connection_is_said_and_the_page_reconnects_by_itself(servers, browser):
    first = servers()
    port = first.port
    page = open_page(browser, first, ready="window.operator && window.operator.ros.connected")
    try:
        first.stop()
        page.wait_for_function("(document.getElementById('hud-connection')?.textContent ?? '').includes('DISCONNECTED')",
                               timeout=SLOW)
        frames(page, 5)  # still running
        second = servers(port=port)
        try:
            page.wait_for_function("(document.getElementById('hud-connection')?.textContent ?? '').startsWith('● connected')",
                                   timeout=SLOW)
            sent = page.evaluate("window.operator.state.posesSent")
            page.wait_for_function(f"window.operator.state.posesSent > {sent + 10}", timeout=SLOW)
            assert page.errors == []
        finally:
            second.stop()
    finally:
        close_page(page)


def test_pure_parts_under_node(tmp_path):
    """The axis change and the menu checks, run by Node on the page's own modules."""
    script = tmp_path / "check.mjs"
    web = ROOT / "vr_teleop_server" / "web" / "operator"
    script.write_text(f"""
import {{rosPosition, rosOrientation, joyFromGamepad}} from {json.dumps(str(web / 'ros_axes.js'))};
import {{parseMenus, MenuNavigator, MenuError}} from {json.dumps(str(web / 'menus.js'))};
const out = {{}};
out.forward = rosPosition({{x: 0, y: 1.6, z: -2}});
const s = Math.sin(Math.PI / 12), c = Math.cos(Math.PI / 12);
out.left = rosOrientation({{x: 0, y: s, z: 0, w: c}});
out.joy = joyFromGamepad({{buttons: [{{value: 0.5, pressed: true}}, {{value: 1, pressed: true}}, null,
  {{value: 1, pressed: true}}, {{value: 1, pressed: true}}, {{value: 0, pressed: false}}], axes: [0, 0, 0.25, -1]}});
try {{ parseMenus({{menus: [], items: [{{id: "a", parent: "x", slot: "top", command: "c"}}]}}); }}
catch (e) {{ out.error = e instanceof MenuError ? e.message : "wrong type"; }}
const tree = parseMenus({{menus: [{{id: "m", label: "M", controller: "right", button: "A"}}], items: [
  {{id: "m.t", parent: "m", slot: "top", label: "T", command: "x"}},
  {{id: "m.l", parent: "m", slot: "left", label: "L", command: "x"}},
  {{id: "m.s", parent: "m", slot: "list", label: "S"}},
  {{id: "m.s.1", parent: "m.s", slot: "list", label: "one", command: "x"}}]}});
const nav = new MenuNavigator(); nav.setTree(tree); nav.press("m");
nav.stick(0, 1, 0); out.up = nav.select()?.id;
nav.stick(-0.8, 0.8, 0); out.diagonal = nav.select(); out.entered = nav.title;
nav.stick(0, -1, 0); out.listItem = nav.select()?.id;
console.log(JSON.stringify(out));
""")
    result = subprocess.run(["node", str(script)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)
    assert out["forward"] == {"x": 2, "y": -0, "z": 1.6}  # -z in WebXR is forward: +x in ROS; y up is z
    yaw = math.degrees(2 * math.atan2(out["left"]["z"], out["left"]["w"]))
    assert abs(yaw - 30) < 1e-9 and out["left"]["x"] == 0  # a turn to the left is +yaw about ROS's z
    assert out["joy"] == {"axes": [0.25, 1, 0.5, 1], "buttons": [1, 0, 1, 0]}
    assert out["error"] == "item a: its parent x is unknown"
    assert out["up"] == "m.t" and out["diagonal"] is None and out["entered"] == "M › S"
    assert out["listItem"] == "m.s.1"


def test_sound_both_ways(browser, sim_server):
    """The robot's speech plays in the page; the operator's voice (Chromium's fake microphone) reaches the server
    while push-to-talk is held, logged as a WAV like any client's."""
    page = open_page(browser, sim_server, viewport={"width": 1000, "height": 640})
    try:
        page.wait_for_function("window.operator.nav.tree !== null", timeout=SLOW)
        page.keyboard.press("y")  # Y: the speech menu
        page.wait_for_function("document.getElementById('menu-title').textContent === 'Speech'", timeout=SLOW)
        page.keyboard.down("ArrowUp")
        page.keyboard.down("ArrowLeft")  # up and left together: the diagonal item, Sentences
        page.keyboard.up("ArrowLeft")
        page.keyboard.up("ArrowUp")
        page.keyboard.press("Enter")
        page.wait_for_function("document.getElementById('menu-title').textContent === 'Speech › Sentences'",
                               timeout=SLOW)
        page.keyboard.press("ArrowDown")
        page.keyboard.press("Enter")  # "Hello everyone, I am QT."
        page.wait_for_function("window.operator.audio.played >= 5", timeout=SLOW)
        assert page.errors == []
    finally:
        close_page(page)


def test_push_to_talk_streams_the_microphone(browser_type_with_fake_microphone, sim_server):
    audio_dir = Path(sim_server.settings.audio_dir)
    before = set(audio_dir.glob("*.wav")) if audio_dir.exists() else set()
    page = open_page(browser_type_with_fake_microphone, sim_server)
    try:
        page.get_by_role("button", name="Hold to talk").hover()
        page.mouse.down()
        page.wait_for_function("window.operator.audio.sentChunks >= 5", timeout=SLOW)
        assert page.evaluate("window.operator.audio.path") == "rosbridge"  # no peer connection: the fallback
        assert "TALKING (rosbridge)" in hud(page, "numbers")
        page.mouse.up()
        sent = page.evaluate("window.operator.audio.sentChunks")
        frames(page, 20)
        assert page.evaluate("window.operator.audio.sentChunks") == sent  # released: silence
        assert wait_for(lambda: any(p.stat().st_size > 44 for p in set(audio_dir.glob("*.wav")) - before), 30)
        assert page.errors == []
    finally:
        close_page(page)


@pytest.fixture
def browser_type_with_fake_microphone(browser):
    """A second Chromium from the same Playwright, with Chromium's fake microphone (a beep) allowed."""
    import shutil

    b = browser.browser_type.launch(executable_path=shutil.which("chromium") or shutil.which("chromium-browser"),
                                    args=["--no-sandbox", "--enable-unsafe-swiftshader",
                                          "--use-fake-device-for-media-stream", "--use-fake-ui-for-media-stream"])
    yield b
    b.close()


def test_the_hud_shows_gesture_recording_from_the_typed_event_whatever_the_menus_say(browser, sim_server, ros,
                                                                                     watch):
    """The recording state is the gesture_recording event's `recording` field: rewording the menu's answer (or
    recording without the menu at all) cannot change what the HUD shows."""
    from support import call

    from menus import Command
    from vr_teleop_server.features.menu_service import MENU_HANDLERS

    events = watch("/vr_teleop/events", "vr_teleop_msgs/Event")
    toggle = MENU_HANDLERS[Command.RECORD_TOGGLE]

    async def reworded(service, args, caller):
        await toggle(service, args, caller)
        return "okay"  # no "recording ..." in it: a page reading sentences would miss the start

    sim_server.call(lambda: MENU_HANDLERS.__setitem__(Command.RECORD_TOGGLE, reworded))
    page = open_page(browser, sim_server)
    try:
        assert page.evaluate("document.getElementById('hud-recording')") is None
        reply = call(ros, "/vr_teleop/menu/select", "vr_teleop_msgs/MenuSelect", {"id": "motion.record", "args": ""})
        assert reply == {"success": True, "message": "okay"}
        page.wait_for_function("(document.getElementById('hud-recording')?.textContent ?? '')"
                               ".startsWith('● RECORDING a gesture')", timeout=SLOW)
        started = next(e for e in events.messages if e["kind"] == "gesture_recording")
        assert started["source"] == "gestures" and json.loads(started["detail"])["recording"] is True
        assert "head" in hud(page, "recording")  # the parts recorded, from the detail's `parts`
        assert page.evaluate("window.operator.state.recording") is True  # the menu's Record switch shows on
        screenshot(page, "operator_hud_recording.png")
        # stopped without the menu: its service answers {status: true}, no sentence at all
        assert call(ros, "/qt_robot/gesture/stop", "qt_gesture_controller/gesture_stop") == {"status": True}
        page.wait_for_function("document.getElementById('hud-recording') === null", timeout=SLOW)
        assert page.evaluate("window.operator.state.recording") is False
        stopped = [json.loads(e["detail"]) for e in events.messages if e["kind"] == "gesture_recording"]
        assert stopped[-1] == {"recording": False, "parts": []}
        assert page.errors == []
    finally:
        sim_server.call(lambda: MENU_HANDLERS.__setitem__(Command.RECORD_TOGGLE, toggle))
        close_page(page)
