"""The operator page's comfort vignette and the robot's reticle (issue 36), in Chromium with IWER as the headset,
on the MuJoCo stand-in: nothing while the robot's head follows; the view's edges darkening, more as the robot's
head trails further (the emulated headset turned past HeadYaw's 60 degree limit, so the robot's head stops there);
the reticle where the robot looks; off from the page's address, its checkbox and the status menu.

The page's own figures come from window.operator.comfort (a read-only hook); the darkening is also checked once on
the pixels the page shows.
"""

from __future__ import annotations

import io
import json
import math

from PIL import Image, ImageStat

from support import wait_for
from test_operator_page import (SLOW, choose_in_menu, close_page, enter_vr, frames, open_page, press, screenshot,
                                set_head, settles, take_control, take_control_by_key)
from test_operator_page import iwer  # noqa: F401  (the fixture)

COMFORT = "window.operator.comfort.snapshot()"
HEAD_YAW_LIMIT = 60.0  # robot_models/data/qtrobot.yaml


def comfort(page) -> dict:
    return page.evaluate(COMFORT)


def reticle_direction(page) -> tuple[float, float]:
    """(yaw left, pitch up) in degrees of the reticle as placed in the scene, seen from the operator's eyes."""
    x, y, z = page.evaluate("(() => { const r = window.operator.comfort.reticle.position,"
                            " h = window.operator.state.head.position; return [r.x - h.x, r.y - h.y, r.z - h.z]; })()")
    return math.degrees(math.atan2(-x, -z)), math.degrees(math.atan2(y, math.hypot(x, z)))


def settled(page) -> dict:
    """The snapshot once the eased strength has reached what the lag asks for (a few frames)."""
    page.wait_for_function(f"(() => {{ const c = {COMFORT}; return Math.abs(c.strength - c.target) < 0.01; }})()",
                           timeout=SLOW)
    return comfort(page)


def brightness(page) -> tuple[float, float]:
    """Mean grey level of the view's right edge band and of its centre, at mid height (the page's screenshot)."""
    image = Image.open(io.BytesIO(page.screenshot())).convert("L")
    w, h = image.size
    band = lambda x0, x1: image.crop((int(x0 * w), int(0.35 * h), int(x1 * w), int(0.6 * h)))  # noqa: E731
    return ImageStat.Stat(band(0.9, 0.98)).mean[0], ImageStat.Stat(band(0.45, 0.55)).mean[0]


def select_vignette(page) -> None:
    """Status (X) › Vignette: the second list item, on the top-right diagonal; by the left stick and trigger."""
    choose_in_menu(page, "left", "x-button", "Status", (0.7, -0.7), "status.vignette")


def test_the_vignette_grows_as_the_robots_head_trails_and_the_reticle_shows_where_it_looks(browser, iwer,
                                                                                          sim_server, watch):
    standin = sim_server.server.robot.standin
    events = watch("/vr_teleop/events", "vr_teleop_msgs/Event")
    page = open_page(browser, sim_server, headset=iwer)
    try:
        enter_vr(page)
        c = comfort(page)
        assert c["enabled"] and not c["active"] and not c["vignetteVisible"] and not c["reticleVisible"]
        take_control(page)
        page.wait_for_function("window.operator.camera.uploaded >= 3", timeout=SLOW)

        # The robot's head follows: no vignette; the reticle where the robot looks, which is where we look.
        set_head(page, 20.0)
        assert settles(standin, "HeadYaw", 20.0, 2.0), standin.joint_positions()
        frames(page, 10)
        c = settled(page)
        assert c["active"] and c["lagDeg"] < 5.0 and c["strength"] == 0 and not c["vignetteVisible"], c
        assert c["reticleVisible"]
        yaw, pitch = reticle_direction(page)
        assert abs(yaw - standin.joint_positions()["HeadYaw"]) < 2.5 and abs(pitch) < 2.5, (yaw, pitch)

        # 70 degrees: the robot's head stops at its 60 degree limit, 10 behind: a faint, wide vignette.
        set_head(page, 70.0)
        assert settles(standin, "HeadYaw", HEAD_YAW_LIMIT, 2.0), standin.joint_positions()
        page.wait_for_function(f"{COMFORT}.vignetteVisible", timeout=SLOW)
        faint = settled(page)
        assert 7.0 < faint["lagDeg"] < 13.0 and 0 < faint["strength"] < 0.5, faint

        # 85 degrees left and 10 down: 25 behind, the vignette at its darkest and narrowest; the reticle stays with
        # the robot's head (60 left, 10 down), not with ours.
        set_head(page, 85.0, -10.0)
        assert settles(standin, "HeadPitch", 10.0, 2.0), standin.joint_positions()
        page.wait_for_function(f"{COMFORT}.strength > 0.95", timeout=SLOW)
        full = settled(page)
        assert full["lagDeg"] > 22.0, full
        assert full["opacity"] > faint["opacity"] and full["scale"] < faint["scale"], (faint, full)
        robot = standin.joint_positions()
        yaw, pitch = reticle_direction(page)
        assert abs(yaw - robot["HeadYaw"]) < 2.5 and abs(pitch + robot["HeadPitch"]) < 2.5, (yaw, pitch, robot)
        frames(page, 5)
        screenshot(page, "operator_vr_vignette.png")
        edge_on, centre_on = brightness(page)

        # Off from the status menu: the page switches it at once, the server records the choice.
        select_vignette(page)
        page.wait_for_function(f"!{COMFORT}.enabled", timeout=SLOW)
        page.wait_for_function(f"!{COMFORT}.vignetteVisible && !{COMFORT}.reticleVisible", timeout=SLOW)
        assert wait_for(lambda: events.any(lambda e: e["source"] == "menu" and e["kind"] == "select" and json.loads(
            e["detail"]).get("result") == "comfort vignette off"), 30)
        press(page, "left", "x-button")  # the menu closed: the pixels are the view's alone
        page.wait_for_function("document.getElementById('menu-title').textContent === ''", timeout=SLOW)
        frames(page, 5)
        edge_off, centre_off = brightness(page)
        print(f"grey levels, edge and centre: vignette on {edge_on:.0f}, {centre_on:.0f}; off {edge_off:.0f}, "
              f"{centre_off:.0f}")
        # The pixels: the right edge (the camera panel there) much darker with the vignette than without it,
        # relative to the centre, which it leaves nearly as it was.
        assert edge_on / max(centre_on, 1) < 0.6 * edge_off / max(centre_off, 1), (edge_on, centre_on, edge_off,
                                                                                   centre_off)
        assert edge_off > 40, (edge_off, "the camera panel is not at the right edge: the check would prove nothing")

        # And on again from the menu, the robot still held at its limit: the vignette is back.
        select_vignette(page)
        page.wait_for_function(f"{COMFORT}.enabled && {COMFORT}.strength > 0.95", timeout=SLOW)
        assert wait_for(lambda: events.any(lambda e: e["source"] == "menu" and e["kind"] == "select" and json.loads(
            e["detail"]).get("result") == "comfort vignette on"), 30)
        press(page, "left", "x-button")

        # Back within the limit: the robot's head catches up, the vignette goes.
        set_head(page, 0.0)
        assert settles(standin, "HeadYaw", 0.0, 2.0), standin.joint_positions()
        page.wait_for_function(f"!{COMFORT}.vignetteVisible", timeout=SLOW)
        assert comfort(page)["reticleVisible"]
        assert page.errors == []
    finally:
        close_page(page)


def test_the_address_and_the_checkbox_switch_it_on_the_flat_page(browser, sim_server):
    standin = sim_server.server.robot.standin
    page = open_page(browser, sim_server, camera="jpeg&vignette=off")
    try:
        assert not page.is_checked("#vignette") and not comfort(page)["enabled"]
        take_control_by_key(page)
        # mouse-look 85 degrees to the left (0.25 degrees a pixel): past HeadYaw's limit
        page.mouse.move(880, 300)
        page.mouse.down()
        for i in range(1, 18):
            page.mouse.move(880 - 20 * i, 300)
        page.mouse.up()
        assert settles(standin, "HeadYaw", HEAD_YAW_LIMIT, 2.0), standin.joint_positions()
        frames(page, 10)
        c = settled(page)
        assert c["active"] and c["lagDeg"] > 20 and c["strength"] == 0 and not c["vignetteVisible"], c
        assert not c["reticleVisible"]

        page.click("#vignette")  # on
        page.wait_for_function(f"{COMFORT}.enabled && {COMFORT}.strength > 0.95 && {COMFORT}.reticleVisible",
                               timeout=SLOW)
        assert page.is_checked("#vignette")
        page.click("#vignette")  # off again
        page.wait_for_function(f"!{COMFORT}.enabled && !{COMFORT}.vignetteVisible && !{COMFORT}.reticleVisible",
                               timeout=SLOW)
        page.keyboard.press("e")  # the page's keys still work after the clicks: release control
        page.wait_for_function("(document.getElementById('hud-control')?.textContent ?? '')"
                               ".startsWith('no one in control')", timeout=SLOW)
        assert not comfort(page)["active"]
        assert page.errors == []
    finally:
        close_page(page)
