"""What a teacher does on the dashboard and on the operator page is recorded under what was pressed or typed: a
button under its menu item's id, free text from the dashboard's Say box as said text (a call of the speech
service), never under a sentence's id the teacher did not choose. Read back from the session's recording."""

from __future__ import annotations

import json
from pathlib import Path

from support import wait_for
from test_operator_page import SLOW, close_page, enter_vr, iwer, open_page, press  # noqa: F401 (a fixture)
from vr_teleop_server.recording.format import read_recording

TYPED = "Hello class, open your books"


def teacher_actions(record: Path) -> tuple[list[tuple[str, str]], list[tuple[str, str]], list[dict]]:
    """(menu item id, by whom) of every selection, (text, by whom) of every call of the speech service a client
    made, and every selection's detail: as the recording has them."""
    selected, said, details = [], [], []
    for m in read_recording(record):
        if m.topic == "/vr_teleop/events" and m.data.get("source") == "menu" and m.data.get("kind") == "select":
            detail = json.loads(m.data["detail"])
            selected.append((detail["id"], detail["by"]))
            details.append(detail)
        elif m.topic == "/rosbridge/in" and m.data.get("op") == "call_service" \
                and m.data.get("service") == "/qt_robot/speech/say":
            said.append((m.data["args"]["message"], m.sender))
    return selected, said, details


def test_every_action_is_recorded_under_what_was_pressed_or_typed(browser, iwer, servers, tmp_path):
    record = tmp_path / "session.mcap"
    server = servers(backend="sim", record=record)
    standin = server.server.robot.standin
    dashboard = browser.new_page(viewport={"width": 1400, "height": 1000})
    dashboard.errors = []  # type: ignore[attr-defined]
    dashboard.on("pageerror", lambda exc: dashboard.errors.append(str(exc)))
    dashboard.goto(f"http://127.0.0.1:{server.port}/#camera=jpeg")
    events = "document.getElementById('events').textContent"
    try:
        dashboard.wait_for_selector("button[data-item='emotion.sad']", timeout=SLOW)
        dashboard.click("button[data-item='emotion.sad']")
        dashboard.wait_for_function(f"{events}.includes('emotion.sad: showing sad')", timeout=SLOW)
        dashboard.click("button[data-item='speech.sentences.well_done']")
        dashboard.wait_for_function(f"{events}.includes('speech.sentences.well_done: said')", timeout=SLOW)
        dashboard.fill("#say-text", TYPED)
        dashboard.press("#say-text", "Enter")
        dashboard.wait_for_function(f"{events}.includes({json.dumps('said ' + json.dumps(TYPED))})", timeout=SLOW)
        assert dashboard.errors == []
    finally:
        dashboard.close()
    page = open_page(browser, server, headset=iwer)
    try:
        enter_vr(page)
        page.wait_for_function("window.operator.nav.tree !== null", timeout=SLOW)
        press(page, "right", "b-button")  # the emotion menu; the stick pushed forward: its top item
        page.wait_for_function("document.getElementById('menu-title').textContent === 'Emotions'", timeout=SLOW)
        page.evaluate("xrDevice.controllers.right.updateAxes('thumbstick', 0, -1)")
        page.wait_for_function("window.operator.nav.level?.entries[window.operator.nav.highlight]?.item.id"
                               " === 'emotion.happy'", timeout=SLOW)
        page.evaluate("xrDevice.controllers.right.updateAxes('thumbstick', 0, 0)")
        press(page, "right", "trigger")
        assert wait_for(lambda: standin.emotion == "happy", 30)
        assert page.errors == []
    finally:
        close_page(page)

    def read() -> tuple[list, list, list]:
        server.call(lambda: server.server.recorder.flush())
        return teacher_actions(record)

    assert wait_for(lambda: len(read()[0]) >= 3, 30)
    selected, said, details = read()
    assert [item for item, _by in selected] == ["emotion.sad", "speech.sentences.well_done", "emotion.happy"]
    on_dashboard, on_headset = selected[0][1], selected[2][1]
    assert selected[1][1] == on_dashboard != on_headset  # the two pages are two clients
    assert said == [(TYPED, on_dashboard)]  # the typed text went to the speech service as it is, from the dashboard
    assert not any(TYPED in str(d.get("result", "")) for d in details)  # and under no menu item's id
