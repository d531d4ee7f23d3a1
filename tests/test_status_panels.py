"""The status panels (issue 42) on the operator page in Chromium with IWER's Quest 3: picked from the status menu
(X), they open over a reduced camera view, show what their topic carries (checked against the topic, in the
panel's canvas and in the pixels the headset's left eye renders), take the motivation controls, and close with B
or by picking the item again."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

from support import wait_for
from test_operator_page import SLOW, choose_in_menu, close_page, enter_vr, frames, iwer, open_page, press

__all__ = ["iwer"]  # the fixture, shared with test_operator_page.py
SHOTS = Path("/tmp/status_panels")
WEB = Path(__file__).resolve().parent.parent / "vr_teleop_server" / "web"
BLUE_FILL = (47, 128, 237)  # a bar's fill (#2f80ed); its empty part is a dark grey


def is_fill(rgba: list[int]) -> bool:
    r, g, b = rgba[0], rgba[1], rgba[2]
    return b > 180 and b - r > 110


def is_empty(rgba: list[int]) -> bool:
    return rgba[2] < 140


def canvas_pixel(page, x: float, y: float) -> list[int]:
    return page.evaluate(f"Array.from(window.operator.statusCanvas.getContext('2d')"
                         f".getImageData({int(x)}, {int(y)}, 1, 1).data)")


def eye_pixel(page, fx: float, fy: float) -> list[int]:
    """The left eye's rendered pixel where the panel's canvas point fx, fy is seen."""
    frames(page)
    return page.evaluate(f"window.operator.readPixels(window.operator.statusPoint({fx}, {fy}), 1)")


def bar_points(bar: dict, fraction: float, size: int = 1024) -> tuple[tuple[float, float], tuple[float, float]]:
    """A point inside the bar's filled part and one inside its empty part, in canvas pixels."""
    y = bar["y"] + bar["h"] / 2
    return (bar["x"] + bar["w"] * fraction / 2, y), (bar["x"] + bar["w"] * (fraction + (1 - fraction) / 2), y)


def test_the_motors_panel_shows_each_joint_as_the_topic_says_and_closes_with_b(browser, iwer, sim_server, watch):
    motors = watch("/vr_teleop/status/motors", "vr_teleop_msgs/MotorsStatus")
    page = open_page(browser, sim_server, headset=iwer)
    try:
        enter_vr(page)
        page.wait_for_function("window.operator.nav.tree !== null", timeout=SLOW)
        choose_in_menu(page, "left", "x-button", "Status", (0, 1), "status.motors")  # the bottom item
        page.wait_for_function("window.operator.state.statusPanel === 'motors' && !window.operator.nav.open"
                               " && window.operator.state.motors !== null", timeout=SLOW)
        assert page.evaluate("window.operator.panel.children[0].scale.x") == 0.5  # the view, reduced, runs on
        assert wait_for(lambda: len(motors.messages) >= 2, 30)
        shown = page.evaluate("window.operator.state.motors")
        assert shown["name"] == motors.latest["name"] and len(shown["name"]) >= 8
        # the page's values are one of the topic's messages (the page may be one ahead of this test's subscriber)
        assert wait_for(lambda: motors.any(lambda m: m["header"] == shown["header"] and m["position_normalized"] ==
                                           shown["position_normalized"]), 30)
        n = len(shown["name"])
        frames(page, 5)
        for i, name in enumerate(shown["name"]):
            fraction = shown["position_normalized"][i]  # nobody commands the robot: it holds still
            if not 0.15 < fraction < 0.85:
                continue
            bar = page.evaluate(f"window.operator.statusPanels.motorBar(1024, {n}, {i})")
            (fx, fy), (ex, ey) = bar_points(bar, fraction)
            assert is_fill(canvas_pixel(page, fx, fy)), (name, fraction)
            assert is_empty(canvas_pixel(page, ex, ey)), (name, fraction)
            assert is_fill(eye_pixel(page, fx / 1024, fy / 1024)), name  # drawn in the headset's view
            assert is_empty(eye_pixel(page, ex / 1024, ey / 1024)), name
        SHOTS.mkdir(exist_ok=True)
        page.screenshot(path=str(SHOTS / "motors.png"))
        press(page, "right", "b-button")  # B closes the panel (it does not open the emotion menu)
        page.wait_for_function("window.operator.state.statusPanel === null", timeout=SLOW)
        assert page.evaluate("window.operator.nav.open") is False
        assert page.evaluate("window.operator.panel.children[0].scale.x") == 1
        assert page.errors == []
    finally:
        close_page(page)


def test_the_motivation_panel_raises_and_lowers_a_variable_and_closes_when_picked_again(browser, iwer, sim_server,
                                                                                       watch):
    motivation = watch("/vr_teleop/status/motivation", "vr_teleop_msgs/Motivation")
    assert wait_for(lambda: motivation.latest.get("name"), 30)
    pain = motivation.latest["value"][motivation.latest["name"].index("pain")]
    page = open_page(browser, sim_server, headset=iwer)
    try:
        enter_vr(page)
        page.wait_for_function("window.operator.nav.tree !== null", timeout=SLOW)
        choose_in_menu(page, "left", "x-button", "Status", (1, 0), "status.motivation")  # the right item
        page.wait_for_function("window.operator.state.statusPanel === 'motivation'"
                               " && window.operator.state.motivation !== null", timeout=SLOW)
        assert page.evaluate("window.operator.state.motivation.name")[0] == "pain"
        # The left stick pushed right raises the chosen variable (the first, pain) by a tenth of its range.
        page.evaluate("xrDevice.controllers.left.updateAxes('thumbstick', 1, 0)")
        frames(page)
        page.evaluate("xrDevice.controllers.left.updateAxes('thumbstick', 0, 0)")
        assert wait_for(lambda: motivation.latest["value"][0] == min(10, pain + 2), 30), motivation.latest
        page.wait_for_function(f"window.operator.state.motivation.value[0] === {min(10, pain + 2)}", timeout=SLOW)
        frames(page, 5)
        fraction = (min(10, pain + 2) + 10) / 20
        bar = page.evaluate("window.operator.statusPanels.motivationBar(1024, 0)")
        (fx, fy), (ex, ey) = bar_points(bar, fraction)
        assert is_fill(canvas_pixel(page, fx, fy)) and is_empty(canvas_pixel(page, ex, ey))
        assert is_fill(eye_pixel(page, fx / 1024, fy / 1024)) and is_empty(eye_pixel(page, ex / 1024, ey / 1024))
        SHOTS.mkdir(exist_ok=True)
        page.screenshot(path=str(SHOTS / "motivation.png"))
        # Down chooses the next variable (frustration); right raises it by 9.
        before = motivation.latest["value"][1]
        page.evaluate("xrDevice.controllers.left.updateAxes('thumbstick', 0, 1)")
        page.wait_for_function("window.operator.state.panelRow === 1", timeout=SLOW)
        page.evaluate("xrDevice.controllers.left.updateAxes('thumbstick', 0, 0)")
        frames(page)
        page.evaluate("xrDevice.controllers.left.updateAxes('thumbstick', 1, 0)")
        frames(page)
        page.evaluate("xrDevice.controllers.left.updateAxes('thumbstick', 0, 0)")
        assert wait_for(lambda: motivation.latest["value"][1] > before + 8, 30), motivation.latest
        # Picking the item again closes the panel.
        choose_in_menu(page, "left", "x-button", "Status", (1, 0), "status.motivation")
        page.wait_for_function("window.operator.state.statusPanel === null", timeout=SLOW)
        assert page.errors == []
    finally:
        close_page(page)


def test_the_dashboard_shows_the_same_panels_and_its_buttons_change_motivation(browser, sim_server, watch):
    motivation = watch("/vr_teleop/status/motivation", "vr_teleop_msgs/Motivation")
    motors = watch("/vr_teleop/status/motors", "vr_teleop_msgs/MotorsStatus")
    assert wait_for(lambda: motivation.latest.get("name") and motors.latest.get("name"), 30)
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    try:
        page.goto(f"http://127.0.0.1:{sim_server.port}/#camera=jpeg")
        page.wait_for_function("window.dashboard?.panels?.motors && window.dashboard.panels.motivation"
                               " && document.querySelectorAll('#motivation-controls button.raise').length === 4",
                               timeout=SLOW)
        shown = page.evaluate("window.dashboard.panels.motors")
        # the page may be a message ahead of this test's own subscriber: wait for the watcher to see it too
        assert wait_for(lambda: motors.any(lambda m: m["header"] == shown["header"]
                                           and m["position"] == shown["position"]), 30)
        n = len(shown["name"])
        for i, fraction in enumerate(shown["position_normalized"]):  # the canvas drew what the topic said
            if not 0.15 < fraction < 0.85:
                continue
            bar = page.evaluate(f"(async () => (await import('/status_panels.js')).motorBar(1024, {n}, {i}))()")
            (fx, fy), (ex, ey) = bar_points(bar, fraction)
            pixel = ("Array.from(document.getElementById('motors-panel').getContext('2d')"
                     ".getImageData(%d, %d, 1, 1).data)")
            assert is_fill(page.evaluate(pixel % (fx, fy))) and is_empty(page.evaluate(pixel % (ex, ey)))
        curiosity = motivation.latest["name"].index("curiosity")
        before = motivation.latest["value"][curiosity]
        page.locator("#motivation-controls button.lower").nth(curiosity).click()  # a tenth of 0..90 down
        assert wait_for(lambda: motivation.latest["value"][curiosity] <= before - 8.5, 30), motivation.latest
        page.wait_for_function(f"window.dashboard.panels.motivation.value[{curiosity}] <= {before - 8.5}",
                               timeout=SLOW)
        SHOTS.mkdir(exist_ok=True)
        page.locator("#status-panels").screenshot(path=str(SHOTS / "dashboard.png"))
        assert errors == []
    finally:
        page.close()


def test_the_trend_and_a_motors_state_under_node(tmp_path):
    """The panels' pure parts, run by Node on the page's own module: a variable's trend over the last five seconds
    (a change under a thousandth of its range is steady) and what a motor's row says."""
    script = tmp_path / "check.mjs"
    script.write_text(f"""
import {{Trends, motorCondition, motivationStep}} from {json.dumps(str(WEB / 'status_panels.js'))};
const trends = new Trends(), out = {{}};
const msg = (f, c, p) => ({{name: ["frustration", "curiosity", "pain"], value: [f, c, p]}});
trends.add(msg(9, 70, 0), 0);
out.one = trends.trend("frustration", 90);
trends.add(msg(8.9, 70.05, 0), 1000);
out.two = [trends.trend("frustration", 90), trends.trend("curiosity", 90), trends.trend("pain", 20)];
for (let k = 2; k <= 9; k++) trends.add(msg(8.9, 70.05 + (k === 9 ? 0.5 : 0), 0), k * 1000);
out.later = [trends.trend("frustration", 90), trends.trend("curiosity", 90)];
out.states = [motorCondition("on", false), motorCondition("brake", false), motorCondition("off", false),
              motorCondition("off", true)];
out.step = motivationStep({{min: [-10], max: [10]}}, 0);
console.log(JSON.stringify(out));
""")
    result = subprocess.run(["node", str(script)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)
    assert out["one"] == 0  # one value: no trend yet
    assert out["two"] == [-1, 0, 0]  # 0.1 of 90 falls; 0.05 of 90 (under 0.09) is steady
    assert out["later"] == [0, 1]  # the fall is older than five seconds; curiosity just rose by 0.5
    assert out["states"] == ["holding", "holding", "free", "clamped"]
    assert out["step"] == 2
