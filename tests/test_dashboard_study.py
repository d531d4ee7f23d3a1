"""The dashboard's study controls in a real browser (Debian's Chromium, Playwright) against a live trial on the
stand-in: the experimenter labels the participant's actions with keys, overrides, preempts, and watches the live
metrics; a spectator cannot label."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest
from study_support import on_loop, prepared, small_study
from support import RunningServer, wait_for
from test_dashboard import SCREENSHOTS, TOKENS, open_page

from vr_teleop_server.recording.format import read_recording


@pytest.fixture(scope="module")
def study_server(module_servers, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("dashboard_study")
    return module_servers(backend="sim", record=tmp / "session.mcap", record_camera_fps=0.0,
                          operator_token=TOKENS["operator"], supervisor_token=TOKENS["supervisor"],
                          spectator_token=TOKENS["spectator"])


def recorded(server: RunningServer, topic: str) -> list:
    server.server.recorder.flush()
    return [m.data for m in read_recording(Path(server.settings.record)) if m.topic == topic]


def text(page, selector: str) -> str:
    return page.text_content(selector) or ""


def test_the_experimenter_labels_overrides_and_preempts_a_trial_from_the_page(browser, study_server):
    # The behaviour tree drives the robot; nobody plays the participant: the experimenter labels what the
    # participant does, from the page, as it happens.
    study = small_study(dashboard={"perception": "static", "decision": "scripted", "motion": "online"})
    page = open_page(browser, study_server, "supervisor")
    page.on("dialog", lambda dialog: dialog.accept())  # the preempt button asks first
    runtime = prepared(study_server, study, "dashboard")
    running = asyncio.run_coroutine_threadsafe(runtime.run(), study_server.loop)
    try:
        page.wait_for_function("document.getElementById('trial-badge').textContent === 'dashboard: running'")
        assert text(page, "#trial-modules") == "static / scripted / online"
        # The plan fetches and hands over the first part, then waits for the participant to take it: the page
        # offers that action for labelling.
        page.wait_for_function("document.getElementById('trial-current').textContent === 'awaiting human: take_bottom'",
                               timeout=60_000)
        page.wait_for_function("document.getElementById('label-action').value === 'take_bottom'")
        elapsed = text(page, "#trial-elapsed")
        page.wait_for_function(f"document.getElementById('trial-elapsed').textContent !== {elapsed!r}")
        page.click("header h1")  # focus off the inputs: keys are shortcuts
        page.keyboard.press("h")
        page.wait_for_function("document.getElementById('updates').textContent.includes('human take_bottom started')")
        page.keyboard.press("j")
        page.wait_for_function("document.getElementById('updates').textContent.includes('human take_bottom stopped')")
        # The plan moved on to the next human action; the participant is slow, so the experimenter overrides.
        page.wait_for_function("document.getElementById('label-action').value === 'position_bottom'", timeout=30_000)
        page.keyboard.press("o")
        page.wait_for_function("document.getElementById('labels').textContent.includes('position_bottom marked done')")
        page.wait_for_function("document.getElementById('m-interventions').textContent === '1'")
        # The live metrics count the labelled and overridden human actions.
        page.wait_for_function("document.getElementById('m-actions').textContent.startsWith('2 /')", timeout=5_000)
        page.wait_for_function("document.getElementById('m-h_idle').textContent !== '–'")
        page.screenshot(path=str(SCREENSHOTS / "study.png"), full_page=True)
        # A label for an action that is not running is refused, and the refusal shows where it was asked.
        page.fill("#label-action", "not_started")
        page.click("header h1")
        page.keyboard.press("j")
        page.wait_for_function("document.getElementById('labels').textContent.includes('label not taken')")
        page.click("#preempt")
        page.wait_for_function("document.getElementById('trial-badge').textContent === 'dashboard: preempted'")
        result = running.result(30)
        assert result.outcome == "preempted" and result.interventions == 2
        page.screenshot(path=str(SCREENSHOTS / "study-preempted.png"), full_page=True)
        assert page.errors == []
    finally:
        page.close()
        if not running.done():
            running.cancel()
        on_loop(study_server, runtime.close())
    # Everything is in the session recording: the labels as pressed, the state updates they made, the interventions.
    assert wait_for(lambda: any(u["action"] == "take_bottom" and u["finished"] and u["source"] == "label"
                                for u in recorded(study_server, "/study/state_updates")), 30)
    kinds = [e["kind"] for e in recorded(study_server, "/study/labels")]
    assert kinds[:2] == ["human_action_start", "human_action_stop"], kinds
    assert [i["kind"] for i in recorded(study_server, "/study/interventions")] == ["override", "preempt"]


def test_a_spectator_cannot_label_or_override(browser, study_server):
    page = open_page(browser, study_server, "spectator")
    try:
        page.wait_for_selector("#label-start")
        before = len(recorded(study_server, "/study/labels"))
        page.click("header h1")
        page.keyboard.press("h")
        page.wait_for_function("document.getElementById('labels').textContent.includes('spectator')")
        page.click("#override-ok")
        page.wait_for_function("/spectator may not call.*\\/decision\\/override/.test(document.getElementById('labels').textContent)")
        page.screenshot(path=str(SCREENSHOTS / "study-spectator.png"), full_page=True)
    finally:
        page.close()
    # Both refusals are answers on the page's connection: a label taken would have been recorded before them.
    assert len(recorded(study_server, "/study/labels")) == before
