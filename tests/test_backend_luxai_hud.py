"""The operator page (Chromium, the flat view) on the QTrobot v3 backend: what only a real robot reports reaches the
operator's HUD. A module of its own: the browser fixture's Playwright must not share a module with asyncio tests."""

from __future__ import annotations

from testbed.luxai_hub import FakeQtrobotV3
from testbed.processes import free_port
from support import wait_subscribed
from test_backend_luxai import luxai_server

from client_protocol import names


def test_the_operators_hud_shows_motor_faults_and_a_voice_in_the_room(servers, browser):
    """The operator page (Chromium) on the v3 backend: a motor fault and a voice the robot's microphone array hears
    appear on the HUD, and go when they end."""
    hub = FakeQtrobotV3(camera=False).start()
    server = luxai_server(servers, robot_url=f"tcp://127.0.0.1:{hub.hub_port}",
                          camera_url=f"tcp://127.0.0.1:{free_port()}")
    context = browser.new_context(viewport={"width": 960, "height": 600})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    slow = 30_000
    try:
        page.goto(f"http://127.0.0.1:{server.port}/operator#camera=jpeg")
        page.wait_for_function("window.operator && window.operator.ros.connected && window.operator.state.teleop",
                               timeout=slow)
        assert wait_subscribed(server, names.EVENT_TOPIC)
        hub.faults = {"LeftShoulderRoll": {"temperature_limit": True}}
        hub.mic_event = {"activity": True, "direction": 120}
        page.wait_for_function("(document.getElementById('hud-motors')?.textContent ?? '')"
                               " === 'MOTOR FAULT: LeftShoulderRoll (temperature_limit)'", timeout=slow)
        page.wait_for_function("(document.getElementById('hud-voice')?.textContent ?? '')"
                               " === 'someone in the room is speaking (from 120°)'", timeout=slow)
        hub.faults = {"LeftShoulderRoll": {}}
        hub.mic_event = {"activity": False, "direction": 120}
        page.wait_for_function("!document.getElementById('hud-motors') && !document.getElementById('hud-voice')",
                               timeout=slow)
        assert not errors, errors
    finally:
        page.close()
        context.close()
        server.stop()
        hub.stop()
