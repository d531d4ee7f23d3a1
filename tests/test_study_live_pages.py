"""The participant's page (/participant#token=...) in Chromium with touch, against a live study on the stand-in:
what is due, one block per screen, Next only once every item has an answer or "prefer not to answer", an answer
out of its scale refused naming the item, then sent and recorded in the study folder."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from client_protocol import names
from vr_teleop_server.client.rosbridge import connect

ROOT = Path(__file__).resolve().parent.parent
FORM = "classroom v1 2026-11"
SUPERVISOR = "sup-token-participant-page"


@pytest.fixture(scope="module")
def live(module_servers, tmp_path_factory):
    folder = tmp_path_factory.mktemp("participant_page") / "study"
    server = module_servers(backend="sim", study=ROOT / "examples" / "classroom.yaml", study_dir=folder,
                            record_camera_fps=0.0, bystander_interval=0.0, supervisor_token=SUPERVISOR)
    return server, folder


def enrol(server) -> dict:
    async def main() -> dict:
        client = await connect(f"{server.url}/?token={SUPERVISOR}")
        try:
            return await client.call(names.STUDY_PARTICIPANT_ADD_SERVICE,
                                     {"consent": True, "consent_form": FORM, "group": ""})
        finally:
            await client.close()
    # Playwright's sync API holds this thread's event loop: the client runs on the server's
    return asyncio.run_coroutine_threadsafe(main(), server.loop).result(60)


def test_a_participant_fills_in_what_is_due_by_touch(browser, live):
    server, folder = live
    added = enrol(server)
    context = browser.new_context(has_touch=True, is_mobile=True, viewport={"width": 800, "height": 1280})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    try:
        page.goto(f"http://127.0.0.1:{server.port}/participant#token={added['token']}")
        page.wait_for_function("document.getElementById('progress').textContent.includes('page 1 of')")
        assert added["participant"] in page.text_content("#title")
        # first the study file's demographic questions, in bands: one tap each (or prefer not to answer)
        assert page.text_content("#block-title") == "About you"
        questions = page.locator("fieldset.item")
        for index in range(questions.count()):
            assert page.is_disabled("#next")
            button = "button.decline" if index == 0 else "button.choice >> nth=0"
            questions.nth(index).locator(button).tap()
        assert page.text_content("#next") == "Send"
        page.tap("#next")
        page.wait_for_function("document.getElementById('progress').textContent.includes('Quick Assessment')")
        assert "Quick Assessment Method" in page.text_content("#progress")
        screens = int(page.text_content("#progress").split("page 1 of ")[1].split(" ")[0])
        assert screens > 1  # one block of items per screen
        out_of_scale = declined = None
        for screen in range(screens):
            boxes = page.locator("fieldset.item")
            for index in range(boxes.count()):
                assert page.is_disabled("#next")  # nothing moves on before every item has an answer
                box = boxes.nth(index)
                item = box.get_attribute("data-item")
                if box.locator("input.number").count():
                    box.locator("input.number").tap()
                    if out_of_scale is None:
                        out_of_scale = item
                        box.locator("input.number").fill("150")
                    else:
                        box.locator("input.number").fill("50")
                elif declined is None:
                    declined = item
                    box.locator("button.decline").tap()
                else:
                    box.locator("button.choice", has_text="3").first.tap()
            assert page.is_enabled("#next")
            page.tap("#next")
        assert out_of_scale is not None and declined is not None
        # the send is refused, naming the item out of its scale; nothing was taken
        page.wait_for_function("document.getElementById('message').className === 'refused'")
        message = page.text_content("#message")
        assert out_of_scale in message and "outside its scale" in message
        assert not any(json.loads(line)["what"] == "questionnaire"
                       for line in (folder / "events.jsonl").read_text().splitlines())
        for _ in range(screens - 1):  # back to the item, corrected
            page.tap("#back")
        page.locator(f"fieldset[data-item='{out_of_scale}'] input.number").fill("40")
        for _ in range(screens - 1):
            page.tap("#next")
        assert page.text_content("#next") == "Send"
        page.tap("#next")
        page.wait_for_function("document.getElementById('block-title').textContent.startsWith('Nothing to fill in')")
        assert not errors, errors
    finally:
        context.close()
    given = [json.loads(line) for line in (folder / "events.jsonl").read_text().splitlines()]
    answers = next(e for e in given if e["what"] == "questionnaire" and e["participant"] == added["participant"])
    assert answers["questionnaire"] == "qam" and answers["phase"] == "expected"
    assert answers["answers"][out_of_scale] == 40 and answers["answers"][declined] is None
    about = next(e for e in given if e["what"] == "demographics" and e["participant"] == added["participant"])
    assert list(about["values"].values())[0] == "prefer_not_to_answer"


def test_the_page_is_served_and_a_wrong_token_is_told(browser, live):
    server, _ = live
    page = browser.new_page()
    try:
        page.goto(f"http://127.0.0.1:{server.port}/participant#token=not-a-token")
        page.wait_for_function("document.getElementById('message').textContent !== ''")
        assert "not known to the server" in page.text_content("#message")
    finally:
        page.close()


def test_the_experimenter_runs_a_participant_from_the_dashboard_with_the_keyboard(browser, live):
    """The Study panel as the console: enrol with consent, start the next trial, a note, end it, what is due next;
    keys and Tab/Enter only, no mouse."""
    server, folder = live
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    try:
        page.goto(f"http://127.0.0.1:{server.port}/#token={SUPERVISOR}&camera=jpeg")
        page.wait_for_selector("#live-study", state="visible")
        assert "classroom (classroom, within, latin)" in page.text_content("#study-name")
        # a refusal is shown, and nothing changes: consent on a form that is not the study's
        page.focus("#enrol-consent")
        page.keyboard.press("Space")
        page.focus("#enrol-form")
        page.keyboard.type("v0")
        page.focus("#enrol")
        page.keyboard.press("Enter")
        page.wait_for_function("document.getElementById('labels').textContent.includes(\"consent form 'v0'\")")
        rows = page.locator("#participants tbody tr").count()
        page.fill("#enrol-form", FORM)
        page.focus("#enrol")
        page.keyboard.press("Enter")
        page.wait_for_function(f"document.querySelectorAll('#participants tbody tr').length === {rows + 1}")
        link = page.text_content("#enrol-link")
        pid = link.split("'s questionnaire page")[0]
        assert f"/participant#token=" in link
        assert page.input_value("#trial-participant") == pid
        page.wait_for_function(f"document.getElementById('study-due').textContent.includes('hand the tablet to {pid}')")
        page.click("header h1")  # focus off the fields: keys are shortcuts
        page.keyboard.press("s")
        page.wait_for_function(f"document.getElementById('study-due').textContent.startsWith('running: {pid}')")
        page.wait_for_function("document.getElementById('trial-badge').textContent.endsWith(': running')")
        page.keyboard.press("t")  # the note field, focused, without a stray t
        assert page.evaluate("document.activeElement.id") == "study-note"
        page.keyboard.type("the participant laughed")
        page.keyboard.press("Enter")
        page.wait_for_function("document.getElementById('labels').textContent.includes('note: noted')")
        page.focus("#trial-end-completed")
        page.keyboard.press("Enter")
        page.wait_for_function(f"document.getElementById('study-due').textContent.includes('hand the tablet to {pid}')")
        assert "sus after" in page.text_content("#study-due") and "tlx after" in page.text_content("#study-due")
        assert not errors, errors
    finally:
        page.close()
    log = [json.loads(line) for line in (folder / "events.jsonl").read_text().splitlines()]
    mine = [e["what"] for e in log if e.get("participant") == pid]
    assert mine == ["enrol", "consent", "trial_start", "note", "trial_end"]
    assert next(e for e in log if e["what"] == "note" and e.get("participant") == pid)["text"] == \
        "the participant laughed"
