"""Hands instead of controllers on the operator page (issue 36): IWER's hand input (the Quest with its controllers
put down) in Debian's Chromium against the stand-in. A pinch is the trigger and selects in the menus (the hand's
ray points); a fist held is an arm's dead-man, published as the grip of the same Joy the controllers send, so the
server's explicit control moves the arm only while it is held; the head follows throughout; the HUD says which
input is active; the controllers take over again mid-session, and the hands after them."""

from __future__ import annotations

import json
import math
import subprocess

import numpy as np
import pytest

from support import physics_ran, wait_for
from test_operator_page import (ROOT, SLOW, close_page, enter_vr, frames, hud, open_page, screenshot, set_head,
                                settles, take_control)
from test_operator_page import iwer  # noqa: F401  (the fixture)

pytestmark = pytest.mark.timeout(300)

HEAD = np.array([0.0, 1.6, 0.0])  # IWER's headset position; the head looks straight ahead (-z) unless turned
# Where main.js hangs its head-locked panels (metres from the eyes, the head looking ahead): the HUD's centre, and
# the menu's centre and size, its canvas 1400 x 1000 with the ring's centre and radii of panels.js.
HUD_CENTRE = HEAD + [0.0, -0.48, -1.0]
MENU_CENTRE, MENU_SIZE = HEAD + [0.0, 0.04, -0.85], (0.84, 0.6)
RING = {"cx": 700, "cy": 540, "rx": 0.365 * 1400, "ry": 0.33 * 1000, "w": 1400, "h": 1000}

# A closed fist for IWER: its "point" pose (middle, ring and little fingers curled) with the index finger curled
# the same way, the middle finger's joints moved over to the index finger's metacarpal. Both hands share the
# poses (IWER mirrors them for the right hand).
ADD_FIST = """(() => {
  const poses = xrDevice.hands.right[IWER.P_HAND_INPUT].poses;
  if (poses.fist) return;
  const point = poses.point.jointTransforms, at = (name) => Array.from(point[name].offsetMatrix).slice(12, 15);
  const shift = at("index-finger-metacarpal").map((v, i) => v - at("middle-finger-metacarpal")[i]);
  const joints = {...point};
  for (const part of ["metacarpal", "phalanx-proximal", "phalanx-intermediate", "phalanx-distal", "tip"]) {
    const m = Array.from(point[`middle-finger-${part}`].offsetMatrix);
    m[12] += shift[0]; m[13] += shift[1]; m[14] += shift[2];
    joints[`index-finger-${part}`] = {offsetMatrix: m, radius: point[`middle-finger-${part}`].radius};
  }
  poses.fist = {jointTransforms: joints, gripOffsetMatrix: poses.point.gripOffsetMatrix};
})()"""


def aim(page, hand: str, position, target) -> None:
    """Puts IWER's hand at `position` with its ray (its -z) pointing at `target` (WebXR metres)."""
    position = np.asarray(position, float)
    d = np.asarray(target, float) - position
    d /= np.linalg.norm(d)
    forward = np.array([0.0, 0.0, -1.0])
    axis, cos = np.cross(forward, d), float(np.dot(forward, d))
    if np.linalg.norm(axis) < 1e-9:
        q = [0.0, 0.0, 0.0, 1.0] if cos > 0 else [0.0, 1.0, 0.0, 0.0]
    else:
        axis /= np.linalg.norm(axis)
        half = math.acos(max(-1.0, min(1.0, cos))) / 2
        q = [*(axis * math.sin(half)), math.cos(half)]
    page.evaluate(f"xrDevice.hands.{hand}.position.set({position[0]}, {position[1]}, {position[2]});"
                  f"xrDevice.hands.{hand}.quaternion.set({q[0]}, {q[1]}, {q[2]}, {q[3]})")
    frames(page)


def pinch(page, hand: str) -> None:
    """Thumb to index finger and apart again (IWER moves the joints to its pinch pose and back)."""
    page.evaluate(f"xrDevice.hands.{hand}.updatePinchValue(1)")
    page.wait_for_function(f"window.operator.hands.gestures.{hand}.pinch", timeout=SLOW)
    page.evaluate(f"xrDevice.hands.{hand}.updatePinchValue(0)")
    page.wait_for_function(f"!window.operator.hands.gestures.{hand}.pinch", timeout=SLOW)


def menu_item(page, item_id: str):
    """Where the menu's item `item_id` is drawn (the ring's entry at its angle), in WebXR metres."""
    angle = page.evaluate(f"window.operator.nav.level.entries.find((e) => e.item.id === {item_id!r}).angle")
    x = RING["cx"] + RING["rx"] * math.cos(math.radians(angle))
    y = RING["cy"] - RING["ry"] * math.sin(math.radians(angle))
    return MENU_CENTRE + [(x / RING["w"] - 0.5) * MENU_SIZE[0], (0.5 - y / RING["h"]) * MENU_SIZE[1], 0.0]


def hands_on(page) -> None:
    page.evaluate("xrDevice.primaryInputMode = 'hand'")
    page.wait_for_function("document.getElementById('hud-input')?.textContent === 'input: hands'", timeout=SLOW)


RIGHT_HAND, DOWN = [0.2, 1.2, -0.3], [0.3, 0.0, -0.6]  # the right hand, pointing at the floor (not at a panel)


def test_a_pinch_selects_in_the_menus_and_is_the_trigger_and_the_controllers_take_over_again(
        browser, iwer, sim_server, watch):
    standin = sim_server.server.robot.standin
    events = watch("/vr_teleop/events", "vr_teleop_msgs/Event")
    page = open_page(browser, sim_server, headset=iwer)
    try:
        enter_vr(page)
        page.wait_for_function("window.operator.nav.tree !== null", timeout=SLOW)
        page.wait_for_function("document.getElementById('hud-input')?.textContent === 'input: controllers'",
                               timeout=SLOW)
        hands_on(page)
        assert "right pinch takes control" in hud(page, "control")

        # Point at the HUD and pinch: the ring of menus; point at Emotions, pinch: in; point at Happy, pinch.
        aim(page, "right", RIGHT_HAND, HUD_CENTRE)
        pinch(page, "right")
        page.wait_for_function("document.getElementById('menu-title').textContent === 'Menus'", timeout=SLOW)
        aim(page, "right", RIGHT_HAND, menu_item(page, "emotion"))
        page.wait_for_function("window.operator.nav.level.entries[window.operator.nav.highlight]?.item.id"
                               " === 'emotion'", timeout=SLOW)
        pinch(page, "right")
        page.wait_for_function("document.getElementById('menu-title').textContent === 'Menus › Emotions'",
                               timeout=SLOW)
        aim(page, "right", RIGHT_HAND, menu_item(page, "emotion.happy"))
        page.wait_for_function("window.operator.nav.level.entries[window.operator.nav.highlight]?.item.id"
                               " === 'emotion.happy'", timeout=SLOW)
        screenshot(page, "operator_vr_hands_menu.png")
        if standin.emotion == "happy":  # a previous test left it so: the selection must be seen to change it
            page.evaluate("window.operator.ros.publish('/qt_robot/emotion/show', {data: 'sad'})")
            assert wait_for(lambda: standin.emotion == "sad", 30)
        pinch(page, "right")
        assert wait_for(lambda: standin.emotion == "happy", 30), standin.emotion
        assert wait_for(lambda: events.any(lambda e: e["source"] == "menu" and e["kind"] == "select" and json.loads(
            e["detail"]).get("result") == "showing happy"), 30)
        page.wait_for_function("window.operator.state.footer?.text === 'Happy: showing happy'", timeout=SLOW)

        # A pinch pointing off the menu: back one level, then closed. No control was taken by any of it.
        aim(page, "right", RIGHT_HAND, DOWN)
        pinch(page, "right")
        page.wait_for_function("document.getElementById('menu-title').textContent === 'Menus'", timeout=SLOW)
        pinch(page, "right")
        page.wait_for_function("!window.operator.nav.open", timeout=SLOW)
        assert not hud(page, "control").startswith("YOU HAVE CONTROL")

        # A left pinch held talks; the controllers back mid-session end it (nothing stays held across a switch),
        # the HUD says so and the right trigger takes control.
        aim(page, "left", [-0.2, 1.2, -0.3], [-0.3, 0.0, -0.6])
        page.evaluate("xrDevice.hands.left.updatePinchValue(1)")
        page.wait_for_function("window.operator.hands.talking", timeout=SLOW)
        page.evaluate("xrDevice.primaryInputMode = 'controller'")
        page.wait_for_function("!window.operator.hands.talking && !window.operator.hands.gestures.left.pinch",
                               timeout=SLOW)
        page.evaluate("xrDevice.hands.left.updatePinchValue(0)")
        page.wait_for_function("document.getElementById('hud-input')?.textContent === 'input: controllers'",
                               timeout=SLOW)
        take_control(page)
        # And the hands again: the right pinch (off the panels) is the trigger and releases control.
        hands_on(page)
        aim(page, "right", RIGHT_HAND, DOWN)
        pinch(page, "right")
        page.wait_for_function("(document.getElementById('hud-control')?.textContent ?? '')"
                               ".startsWith('no one in control')", timeout=SLOW)
        assert page.errors == []
    finally:
        close_page(page)


def test_a_held_fist_is_the_arms_dead_man_and_the_head_follows(browser, iwer, sim_server, watch):
    standin = sim_server.server.robot.standin
    state = watch("/vr_teleop/teleop_state", "vr_teleop_msgs/TeleopState")
    arm = ("RightShoulderPitch", "RightShoulderRoll", "RightElbowRoll")

    def right_arm() -> list[float]:
        j = standin.joint_positions()
        return [j[n] for n in arm]

    def moved(since: list[float]) -> float:
        return max(abs(a - b) for a, b in zip(right_arm(), since))

    page = open_page(browser, sim_server, headset=iwer)
    try:
        enter_vr(page)
        page.evaluate(ADD_FIST)
        hands_on(page)
        aim(page, "right", RIGHT_HAND, DOWN)  # the hand low, pointing at the floor
        pinch(page, "right")  # the right pinch: take control
        page.wait_for_function("document.getElementById('hud-control')?.textContent.startsWith('YOU HAVE CONTROL')",
                               timeout=SLOW)
        set_head(page, 20.0)  # the head follows with hands as with controllers
        assert settles(standin, "HeadYaw", 20.0, 2.0), standin.joint_positions()

        # An open hand moving moves no arm: the Joy's grip stays 0 and the server leaves the arm where it is.
        start = right_arm()
        aim(page, "right", [0.25, 1.55, -0.6], [0.3, 1.6, -1.5])  # forward and up, the hand open
        frames(page, 30)
        assert page.evaluate("window.operator.state.joy.right.axes[3]") == 0
        assert not state.latest["right_arm_following"]
        assert moved(start) < 2.0, (start, right_arm())
        aim(page, "right", RIGHT_HAND, DOWN)

        # A fist held: the arm follows the wrist.
        page.evaluate("xrDevice.hands.right.poseId = 'fist'")
        page.wait_for_function("window.operator.state.teleop.right_arm_following", timeout=SLOW)
        assert page.evaluate("window.operator.state.joy.right.axes[3]") == 1
        assert not state.latest["left_arm_following"]  # the left hand is open
        aim(page, "right", [0.25, 1.55, -0.6], [0.3, 1.6, -1.5])
        assert wait_for(lambda: moved(start) > 20, 30), (start, right_arm())

        # The hand opens: the arm holds where it is while the hand keeps moving.
        page.evaluate("xrDevice.hands.right.poseId = 'default'")
        page.wait_for_function("!window.operator.state.teleop.right_arm_following", timeout=SLOW)
        assert physics_ran(standin, 0.5)  # the arm comes to rest at the last goal it was given
        held = right_arm()
        for position in ([0.2, 1.0, 0.0], [0.4, 1.3, -0.2], [0.1, 1.1, -0.4]):
            aim(page, "right", position, DOWN)
            frames(page, 10)
        assert physics_ran(standin, 0.5)  # what the arm would have moved in, had the open hand moved it
        assert moved(held) < 2.0, (held, right_arm())

        set_head(page, -15.0)  # the head still follows
        assert settles(standin, "HeadYaw", -15.0, 2.0), standin.joint_positions()
        assert moved(held) < 2.0, (held, right_arm())
        screenshot(page, "operator_vr_hands.png")

        pinch(page, "right")  # release control
        page.wait_for_function("(document.getElementById('hud-control')?.textContent ?? '')"
                               ".startsWith('no one in control')", timeout=SLOW)
        assert page.errors == []
    finally:
        close_page(page)


def test_hand_gestures_under_node(tmp_path):
    """hands.js's pure parts, run by Node: the pinch's and the fist's hysteresis, the dead-man's hold time, the Joy,
    the input's name and the ring of menus."""
    script = tmp_path / "check.mjs"
    web = ROOT / "vr_teleop_server" / "web" / "operator"
    script.write_text(f"""
import * as h from {json.dumps(str(web / 'hands.js'))};
import {{parseMenus, MenuNavigator}} from {json.dumps(str(web / 'menus.js'))};
const open = {{index: 1.9, middle: 1.9, ring: 1.8, pinky: 1.6}};
const fist = {{index: 0.8, middle: 0.8, ring: 0.7, pinky: 0.7}};
const r = (pinch, curl) => ({{pinch, curl}});
const g = new h.HandGesture(), out = {{}};
const seq = (steps) => steps.map(([reading, t]) => {{ g.update(reading, t); return [g.pinch, g.fist, g.deadman]; }});
out.pinch = seq([[r(0.03, open), 0], [r(0.015, open), 10], [r(0.035, open), 20], [r(0.045, open), 30]]);
out.fist = seq([[r(0.09, fist), 100], [r(0.09, fist), 100 + h.FIST_HOLD_MS - 1], [r(0.09, fist), 100 + h.FIST_HOLD_MS],
                [r(0.09, {{...fist, index: 1.2}}), 500], [r(0.09, {{...fist, index: 1.4}}), 510]]);
out.joyHeld = (g.update(r(0.09, fist), 600), g.update(r(0.09, fist), 1000), g.joy());
out.lost = seq([[null, 1010]]);
out.fistPinch = seq([[r(0.005, fist), 2000]]);  // thumb on the curled index finger: a fist, not a pinch
out.kinds = [h.inputKind([{{handedness: "left", hand: {{}}}}, {{handedness: "right", hand: {{}}}}]),
             h.inputKind([{{handedness: "left", gamepad: {{}}}}, {{handedness: "none"}}]),
             h.inputKind([{{handedness: "left", hand: {{}}}}, {{handedness: "right", gamepad: {{}}}}]),
             h.inputKind([])];
const tree = h.withHandMenu(parseMenus({{menus: [{{id: "e", label: "E", controller: "right", button: "B"}},
  {{id: "s", label: "S", controller: "left", button: "X"}}], items: [
  {{id: "e.t", parent: "e", slot: "top", label: "T", command: "x"}},
  {{id: "s.t", parent: "s", slot: "top", label: "U", command: "y"}}]}}));
const nav = new MenuNavigator(); nav.setTree(tree); nav.press(h.HAND_MENU_ID);
out.ring = nav.level.entries.map((e) => [e.item.id, e.angle]);
nav.stick(0, -1, 0); out.entered = nav.select(); out.title = nav.title;
nav.stick(0, 1, 0); out.item = nav.select()?.id;
out.buttonMenus = tree.menus.map((m) => m.id);
console.log(JSON.stringify(out));
""")
    result = subprocess.run(["node", str(script)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)
    # 3 cm is not yet a pinch, 1.5 cm is; it holds to 3.5 cm and lets go past 4.
    assert [p for p, _f, _d in out["pinch"]] == [False, True, True, False]
    # A fist is the dead-man only once held FIST_HOLD_MS; it stays a fist to FIST_OFF, and opens past it.
    assert out["fist"] == [[False, True, False], [False, True, False], [False, True, True], [False, True, True],
                           [False, False, False]]
    assert out["joyHeld"] == {"axes": [0, 0, 0, 1], "buttons": [0, 0, 0, 0]}
    assert out["lost"] == [[False, False, False]]  # tracking lost: nothing held
    assert out["fistPinch"] == [[False, True, False]]
    assert out["kinds"] == ["hands", "controllers", "a hand and a controller", None]
    # The ring of menus: X's menu left, B's bottom; the button menus themselves are unchanged.
    assert out["ring"] == [["s", 180], ["e", 270]]
    assert out["entered"] is None and out["title"] == "Menus › E" and out["item"] == "e.t"
    assert out["buttonMenus"] == ["e", "s"]
