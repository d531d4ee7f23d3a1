"""The status panels (issue 42) on the operator page in Chromium with IWER's Quest 3: picked from the status menu
(X), they open over a reduced camera view, show what their topic carries (checked against the topic, in the
panel's canvas and in the pixels the headset's left eye renders), take the motivation controls, and close with B
or by picking the item again."""

from __future__ import annotations

import json
import math
import re
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


def save_canvas(page, expression: str, name: str) -> None:
    """The panel's canvas itself, at its own resolution, as a PNG to look at."""
    import base64

    SHOTS.mkdir(exist_ok=True)
    data = page.evaluate(f"{expression}.toDataURL('image/png')")
    (SHOTS / name).write_bytes(base64.b64decode(data.split(",", 1)[1]))


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
import {{Trends, dialogChoices, hardwareRows, motorCondition, motivationStep, moveDialog, wrapText}}
  from {json.dumps(str(WEB / 'status_panels.js'))};
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
const ctx = {{measureText: (text) => ({{width: text.length * 10}})}};  // ten pixels a character
out.wrapped = wrapText(ctx, "Let's try that again together, shall we?", 150, 2);
out.long = wrapText(ctx, "Supercalifragilisticexpialidocious", 200, 2);
const items = [
  {{id: "emotion.happy", parent: "emotion", command: "show_emotion", args: '{{"name": "happy"}}', label: "Happy"}},
  {{id: "speech.sentences.b", parent: "speech.sentences", command: "say", args: "", label: "B", position: 1}},
  {{id: "speech.sentences.a", parent: "speech.sentences", command: "say", args: "", label: "A", position: 0}},
  {{id: "emotion.all.sad", parent: "emotion.all", command: "show_emotion", args: '{{"name": "sad"}}', label: "sad"}},
  {{id: "emotion.all.happy", parent: "emotion.all", command: "show_emotion", args: '{{"name": "happy"}}',
    label: "happy"}},
];
const choices = dialogChoices(items);
out.choices = [choices.sentences.map((c) => c.id), choices.faces.map((c) => c.id)];
out.args = [choices.sentences.map((c) => c.args), choices.faces.map((c) => c.args)];
out.moved = [moveDialog({{sentence: 0, face: 0}}, choices, -1, 1), moveDialog({{sentence: 1, face: 1}}, choices, 1, 1)];
const t = (key, vars = {{}}) => key + (Object.keys(vars).length ? JSON.stringify(vars) : "");
const ros1 = {{backend: "ros", source: "measured", connected: false, motors: 8, has_motor_temperature: true,
  hottest_motor: "HeadYaw", motor_temperature_c: 41.4, has_motor_voltage: false, motor_faults: 2,
  has_battery: false, has_cpu: false, has_memory: false, has_temperature: false,
  missing: ["motor_voltage", "battery", "cpu", "memory", "temperature"],
  missing_reason: ["no_reading", "interface", "interface", "interface", "interface"]}};
out.rows = hardwareRows(ros1, null, t).map((r) => [r.kind, r.label, r.value, r.fraction, r.level]);
console.log(JSON.stringify(out));
""")
    result = subprocess.run(["node", str(script)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)
    assert out["args"] == [["", ""], ['{"say":""}', '{"say":""}']]  # a dialog's face says no words of its own
    assert out["one"] == 0  # one value: no trend yet
    assert out["two"] == [-1, 0, 0]  # 0.1 of 90 falls; 0.05 of 90 (under 0.09) is steady
    assert out["later"] == [0, 1]  # the fall is older than five seconds; curiosity just rose by 0.5
    assert out["states"] == ["holding", "holding", "free", "clamped"]
    assert out["step"] == 2
    assert out["wrapped"] == ["Let's try that", "again together…"]  # broken at spaces; what does not fit is marked
    assert out["long"] == ["Supercalifragilisti…"]  # a word wider than the panel ends in a visible mark
    assert out["choices"] == [["speech.sentences.a", "speech.sentences.b"], ["emotion.happy", "emotion.all.sad"]]
    assert out["moved"] == [{"sentence": 1, "face": 1}, {"sentence": 0, "face": 0}]  # around both lists
    assert out["rows"] == [
        ["heading", 'panel.hw_robot_measured{"backend":"panel.hw_backend_ros"}', "", None, "info"],
        ["figure", "panel.hw_connection", "panel.hw_disconnected", None, "error"],
        ["figure", 'panel.hw_motor_temperature{"motor":"HeadYaw"}', "41 °C", 0.414, "info"],
        ["missing", "panel.hw_motor_voltage", "panel.hw_why_no_reading", None, "muted"],
        ["figure", "panel.hw_motor_faults", "2", None, "error"],
        ["missing", "panel.hw_battery", "panel.hw_why_interface", None, "muted"],
        ["missing", "panel.hw_robot_cpu", "panel.hw_why_interface", None, "muted"],
        ["missing", "panel.hw_robot_memory", "panel.hw_why_interface", None, "muted"],
        ["missing", "panel.hw_robot_temperature", "panel.hw_why_interface", None, "muted"],
        ["heading", "panel.hw_server", "", None, "info"],
        ["missing", "panel.hw_cpu", "panel.waiting", None, "muted"]]


# ---- the hardware and dialog panels -------------------------------------------------------------------------------

def is_highlight(rgba: list[int]) -> bool:
    """The dialog panel's chosen row: its blue wash over the dark ground."""
    return rgba[2] > 100 and rgba[2] - rgba[0] > 70


def stamp(msg: dict) -> float:
    s = msg["header"]["stamp"]
    return s["secs"] + s["nsecs"] / 1e9


def row_named(rows: list[dict], label_start: str) -> int:
    return next(i for i, r in enumerate(rows) if r["label"].startswith(label_start))


def test_the_hardware_panel_shows_the_robots_figures_and_the_servers_as_their_topics_say(browser, iwer, sim_server,
                                                                                         watch):
    robot_hw = watch("/vr_teleop/status/robot_hardware", "vr_teleop_msgs/RobotHardwareStatus")
    server_hw = watch("/vr_teleop/status/hardware", "vr_teleop_msgs/HardwareStatus")
    motors = watch("/vr_teleop/status/motors", "vr_teleop_msgs/MotorsStatus")
    page = open_page(browser, sim_server, headset=iwer)
    try:
        enter_vr(page)
        page.wait_for_function("window.operator.nav.tree !== null", timeout=SLOW)
        choose_in_menu(page, "left", "x-button", "Status", (-1, 0), "status.hardware")  # the left item
        page.wait_for_function("window.operator.state.statusPanel === 'hardware' && !window.operator.nav.open"
                               " && window.operator.state.robotHardware !== null"
                               " && window.operator.state.hardware !== null", timeout=SLOW)
        assert page.evaluate("window.operator.panel.children[0].scale.x") == 0.5
        # the page's messages and the rows it draws from them, read at one moment
        seen = page.evaluate("({robot: window.operator.state.robotHardware, server: window.operator.state.hardware,"
                             " rows: window.operator.statusPanels.hardwareRows()})")
        shown, server, rows = seen["robot"], seen["server"], seen["rows"]
        assert wait_for(lambda: robot_hw.any(lambda m: m["header"] == shown["header"]), 30)  # one of the topic's
        # The stand-in's report: its motors' modelled temperatures, the rest named as not simulated.
        assert (shown["backend"], shown["source"], shown["connected"]) == ("sim", "modelled", True)
        assert shown["has_motor_temperature"] and not shown["has_battery"] and not shown["has_cpu"]
        assert dict(zip(shown["missing"], shown["missing_reason"])) == {
            name: "not_modelled" for name in ("motor_voltage", "battery", "cpu", "memory", "temperature")}
        # the hottest motor is the motors topic's, published in the same tick (read a moment apart: a motor within
        # a tenth of a degree of the hottest may lead in either)
        at = stamp(shown)
        assert wait_for(lambda: motors.any(lambda m: abs(stamp(m) - at) < 0.1), 30)
        same = min(motors.messages, key=lambda m: abs(stamp(m) - at))
        hottest = max(same["temperature"])
        assert abs(shown["motor_temperature_c"] - hottest) < 0.1
        assert same["temperature"][same["name"].index(shown["hottest_motor"])] > hottest - 0.1
        assert shown["motors"] == len(same["name"])
        # one figure a row: what the rows say is what the topics say
        assert wait_for(lambda: server_hw.any(lambda m: m["header"] == server["header"]), 30)
        motor_row = rows[row_named(rows, f"Hottest motor ({shown['hottest_motor']})")]
        assert motor_row["value"] == f"{as_shown(shown['motor_temperature_c'])} °C"
        assert rows[row_named(rows, "Battery")] == {"kind": "missing", "label": "Battery", "value": "not simulated",
                                                    "fraction": None, "level": "muted"}
        memory = rows[row_named(rows, "Memory")]
        assert memory["value"] == f"{as_shown(server['memory_percent'])} %"
        assert rows[row_named(rows, "This server")]["kind"] == "heading"
        assert row_named(rows, "This server") > row_named(rows, "Robot's computer temperature")  # a section apart
        frames(page, 5)
        for row in (row_named(rows, "Memory"), row_named(rows, "Hottest motor")):
            fraction = rows[row]["fraction"]
            # room for a filled and an empty pixel (an idle 24 GiB machine uses 4 % of its memory)
            assert 0.02 < fraction < 0.98, rows[row]
            place = page.evaluate(f"window.operator.statusPanels.hardwareRow(1024, {len(rows)}, {row})")
            (fx, fy), (ex, ey) = bar_points(place["bar"], fraction)
            assert is_fill(canvas_pixel(page, fx, fy)) and is_empty(canvas_pixel(page, ex, ey)), rows[row]
            assert is_fill(eye_pixel(page, fx / 1024, fy / 1024)), rows[row]  # drawn in the headset's view
            assert is_empty(eye_pixel(page, ex / 1024, ey / 1024)), rows[row]
        SHOTS.mkdir(exist_ok=True)
        page.screenshot(path=str(SHOTS / "hardware.png"))
        save_canvas(page, "window.operator.statusCanvas", "hardware_canvas.png")
        press(page, "right", "b-button")
        page.wait_for_function("window.operator.state.statusPanel === null", timeout=SLOW)
        assert page.errors == []
    finally:
        close_page(page)


def as_shown(value: float) -> str:
    """A figure as the panels write it (JavaScript's toFixed(0)): a half rounds up, where Python's format rounds it
    to even (a memory of 14.5 % is "15 %" on the panel and "14" by f"{x:.0f}": a full run failed on it)."""
    return f"{math.floor(value + 0.5):.0f}"


def spy_on(sim_server, service_name: str, field: str) -> tuple[list[tuple[str, str]], list[object], object]:
    """Records each call of one of the server's own services (what the robot gets) with its caller as it comes,
    and the service's answer once the service has done; returns the calls, the answers and a function that
    restores the service."""
    from vr_teleop_server.core.bus import Bus

    calls: list[tuple[str, str]] = []
    answers: list[object] = []
    service = sim_server.call(lambda: sim_server.server.bus.services[service_name])
    provider = service.provider

    async def spy(request, timeout):
        calls.append((getattr(request, field), Bus.caller()))
        answer = await provider(request, timeout)
        answers.append(answer)
        return answer

    sim_server.call(lambda: setattr(service, "provider", spy))
    return calls, answers, lambda: sim_server.call(lambda: setattr(service, "provider", provider))


def test_the_dialog_panel_says_the_chosen_sentence_with_the_chosen_face(browser, iwer, sim_server, watch):
    standin = sim_server.server.robot.standin
    faces, _, restore_faces = spy_on(sim_server, "/qt_robot/emotion/show", "name")
    said, spoken, restore_said = spy_on(sim_server, "/qt_robot/speech/say", "message")
    page = open_page(browser, sim_server, headset=iwer)
    try:
        enter_vr(page)
        page.wait_for_function("window.operator.nav.tree !== null", timeout=SLOW)
        choose_in_menu(page, "left", "x-button", "Status", (0, -1), "status.dialog")  # the top item
        page.wait_for_function("window.operator.state.statusPanel === 'dialog' && !window.operator.nav.open",
                               timeout=SLOW)
        choices = page.evaluate("window.operator.state.dialogChoices")
        sentences = [line for line in (WEB.parent.parent / "menus" / "data" / "sentences.en.txt").read_text()
                     .splitlines() if line.strip() and not line.startswith("#")]
        labels = [s["label"] for s in choices["sentences"]]  # the speech menu's, in the robot's language, with
        assert len(labels) == len(sentences)                  # {pupil} filled in while the robot attends to one
        assert all(re.fullmatch(re.escape(line).replace(re.escape("{pupil}"), r"(\{pupil\}|\w+)"), label)
                   for line, label in zip(sentences, labels)), labels
        names = [f["name"] for f in choices["faces"]]
        assert names[:4] == ["happy", "sad", "surprise", "neutral"]  # the quick ones first, then every other once
        assert sorted(names) == sorted(set(sim_server.server.robot.model.emotions))
        face = next(i for i, name in enumerate(names) if name != standin.emotion and i > 0)
        n = len(sentences)

        def push(x: float, y: float) -> None:
            page.evaluate(f"xrDevice.controllers.left.updateAxes('thumbstick', {x}, {y})")
            frames(page)
            page.evaluate("xrDevice.controllers.left.updateAxes('thumbstick', 0, 0)")
            frames(page)

        push(0, 1)  # down twice: the third sentence
        push(0, 1)
        for _ in range(face):
            push(1, 0)  # right: the next face
        page.wait_for_function(f"window.operator.state.dialog.sentence === 2"
                               f" && window.operator.state.dialog.face === {face}", timeout=SLOW)
        frames(page, 5)
        chosen = page.evaluate(f"window.operator.statusPanels.dialogRow(1024, {n}, 2, 2)")
        other = page.evaluate(f"window.operator.statusPanels.dialogRow(1024, {n}, 2, 0)")
        for box, lit in ((chosen, True), (other, False)):  # the wash is on the chosen sentence only
            x, y = box["x"] + 9, box["y"] + box["h"] / 2
            assert is_highlight(canvas_pixel(page, x, y)) is lit, box
            assert is_highlight(eye_pixel(page, x / 1024, y / 1024)) is lit, box
        SHOTS.mkdir(exist_ok=True)
        page.screenshot(path=str(SHOTS / "dialog.png"))
        save_canvas(page, "window.operator.statusCanvas", "dialog_canvas.png")
        press(page, "right", "trigger")  # the pick: the sentence said with the face
        assert wait_for(lambda: standin.emotion == names[face], 30)
        assert wait_for(lambda: [m for m, _ in said] == [sentences[2]], 30), said
        assert [name for name, _ in faces] == [names[face]]
        assert all(caller.startswith("/rosbridge_websocket/client_") for _, caller in faces + said)  # the page's
        # the robot said it to its end: the stand-in's face talked for the sentence's length, uncut (its mouth may
        # have closed again before this thread looks, so the answer is the witness, not is_talking())
        assert wait_for(lambda: len(spoken) == 1, 60), said
        assert spoken[0]["status"] is True, spoken
        assert page.evaluate("window.operator.state.teleop.holder") == ""  # the trigger picked; it took no control
        press(page, "right", "b-button")
        page.wait_for_function("window.operator.state.statusPanel === null", timeout=SLOW)
        assert page.errors == []
    finally:
        restore_faces()
        restore_said()
        close_page(page)


def test_the_dashboard_shows_the_hardware_and_dialog_panels_and_says_with_a_face(browser, sim_server, watch):
    standin = sim_server.server.robot.standin
    robot_hw = watch("/vr_teleop/status/robot_hardware", "vr_teleop_msgs/RobotHardwareStatus")
    server_hw = watch("/vr_teleop/status/hardware", "vr_teleop_msgs/HardwareStatus")
    said, _, restore_said = spy_on(sim_server, "/qt_robot/speech/say", "message")
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    try:
        page.goto(f"http://127.0.0.1:{sim_server.port}/#camera=jpeg")
        page.wait_for_function("window.dashboard?.panels?.robotHardware && window.dashboard.panels.hardware"
                               " && window.dashboard.panels.dialog.choices.sentences.length > 2", timeout=SLOW)
        shown = page.evaluate("window.dashboard.panels.robotHardware")
        assert wait_for(lambda: robot_hw.any(lambda m: m["header"] == shown["header"]), 30)
        rows = page.evaluate("""(async () => {
            const p = await import('/status_panels.js'), {t} = await import('/i18n.js');
            const {robotHardware, hardware} = window.dashboard.panels;  // what the canvas was last drawn from
            const rows = p.hardwareRows(robotHardware, hardware, t);
            const i = rows.findIndex((r) => r.label === 'Memory');
            return {rows, i, place: p.hardwareRow(1024, rows.length, i), server: hardware};
        })()""")
        server = rows["server"]
        memory = rows["rows"][rows["i"]]
        assert memory["value"] == f"{as_shown(server['memory_percent'])} %"
        assert wait_for(lambda: server_hw.any(lambda m: m["header"] == server["header"]), 30)  # one of the topic's
        (fx, fy), (ex, ey) = bar_points(rows["place"]["bar"], memory["fraction"])
        pixel = "Array.from(document.getElementById('hardware-panel').getContext('2d').getImageData(%d, %d, 1, 1).data)"
        assert is_fill(page.evaluate(pixel % (fx, fy))) and is_empty(page.evaluate(pixel % (ex, ey)))
        # the dialog panel: a sentence and a face chosen in its lists, said and shown together by its button
        choices = page.evaluate("window.dashboard.panels.dialog.choices")
        face = next(i for i, f in enumerate(choices["faces"]) if f["name"] != standin.emotion)
        page.select_option("#dialog-sentence", "1")
        page.select_option("#dialog-face", str(face))
        page.wait_for_function(f"window.dashboard.panels.dialog.choice.sentence === 1"
                               f" && window.dashboard.panels.dialog.choice.face === {face}", timeout=SLOW)
        box = page.evaluate(f"(async () => (await import('/status_panels.js')).dialogRow(1024, "
                            f"{len(choices['sentences'])}, 1, 1))()")
        lit = "Array.from(document.getElementById('dialog-panel').getContext('2d').getImageData(%d, %d, 1, 1).data)"
        assert is_highlight(page.evaluate(lit % (box["x"] + 9, box["y"] + box["h"] / 2)))
        SHOTS.mkdir(exist_ok=True)
        page.locator("#status-panels").screenshot(path=str(SHOTS / "dashboard_all.png"))
        save_canvas(page, "document.getElementById('hardware-panel')", "dashboard_hardware_canvas.png")
        page.click("#dialog-say")
        assert wait_for(lambda: standin.emotion == choices["faces"][face]["name"], 30)
        assert wait_for(lambda: [m for m, _ in said] == [choices["sentences"][1]["label"]], 30), said
        assert errors == []
    finally:
        restore_said()
        page.close()


def test_a_real_robots_report_names_what_its_interface_cannot_give():
    """The default report (the ROS 1 and v3 backends'): the motors' figures as they report them, the battery and the
    robot's computer missing for want of an interface, a motor figure no motor has given yet missing as unread."""
    from robot_models.types import MotorMode
    from vr_teleop_server.robot.interface import NO_INTERFACE, MotorStatus, motors_report

    motors = [MotorStatus("HeadYaw", "head", 0.0, 41.5, None, MotorMode.ON, "measured"),
              MotorStatus("HeadPitch", "head", 0.0, 38.0, None, MotorMode.ON, "measured", fault="overload_limit"),
              MotorStatus("RightElbowRoll", "right_arm", 0.0, None, None, MotorMode.OFF, "measured")]
    report = motors_report(motors, True, NO_INTERFACE)
    assert (report.source, report.motors, report.hottest_motor, report.motor_temperature_c) == \
        ("measured", 2, "HeadYaw", 41.5)
    assert report.motor_faults == 1 and report.motor_voltage_min_v is None
    assert dict(report.missing) == {"battery": "interface", "cpu": "interface", "memory": "interface",
                                    "temperature": "interface", "motor_voltage": "no_reading"}
    volts = [MotorStatus("HeadYaw", "head", 0.0, 30.0, 12.1, MotorMode.ON, "measured"),
             MotorStatus("HeadPitch", "head", 0.0, 31.0, 11.8, MotorMode.ON, "measured")]
    assert motors_report(volts, False, NO_INTERFACE).motor_voltage_min_v == 11.8
    assert "motor_voltage" not in motors_report(volts, False, NO_INTERFACE).missing
