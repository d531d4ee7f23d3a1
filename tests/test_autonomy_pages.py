"""Supervised autonomy on both pages (issue 34), in Chromium through Playwright, IWER as the headset: the robot's
proposal on the HUD with its reason and countdown, decided by the right thumbstick (and never by the buttons that
take control, stop the robot or open menus), the attention target on the camera panel, the level; the dashboard's
buttons and keys, its level switch, the outcomes as they come; a spectator's page that sees but cannot decide.

The server is the real one on the MuJoCo stand-in; the pages speak to it over rosbridge, and what the pages call is
read from the server's side (the outcomes topic, the level in its state).
"""

from __future__ import annotations

import base64
import json
import subprocess
import threading
from pathlib import Path

import pytest

from support import RawClient, RunningServer, wait_for

from client_protocol import names
from test_operator_page import INSTALL_HEADSET, IWER, READY, SLOW, choose_in_menu, enter_vr, frames, press
from vr_teleop_server.features.autonomy.learner import Situation
from vr_teleop_server.settings import ServerSettings

ROOT = Path(__file__).resolve().parent.parent
WEB = ROOT / "vr_teleop_server" / "web"
TOKENS = {"operator": "op-autonomy-1", "supervisor": "sup-autonomy-2", "spectator": "spec-autonomy-3"}
SCREENSHOTS = ROOT / ".pytest_cache" / "screenshots"
OUTCOMES = "/vr_teleop/autonomy/outcomes"


class Autonomy:
    """The server's autonomy feature as the tests reach it: proposals made in the server's process (as its rules
    make them, on the server's loop), its level, and every outcome it publishes, read from its bus."""

    OWNER = "test-autonomy-pages"

    def __init__(self, server: RunningServer) -> None:
        self.server = server
        self.feature = server.server.autonomy
        self.outcomes: list[dict] = []
        server.call(lambda: server.server.bus.subscribe(self.OWNER, OUTCOMES, "vr_teleop_msgs/ProposalOutcome",
                                                        self._outcome))

    def _outcome(self, published) -> None:
        self.outcomes.append(published.value.model_dump())

    def propose(self, action: str, reason: str, confidence: float = 0.8) -> str:
        a = self.feature
        return self.server.call(lambda: a.propose(action, reason, confidence, Situation("speech_ended"),
                                                  a.clock.monotonic()).id)

    def outcome(self, ident: str) -> dict | None:
        return next((o for o in self.outcomes if o["id"] == ident), None)

    def decided(self, ident: str, outcome: str) -> bool:
        """The proposal ended with `outcome`, decided by a person (not the time-out or the server)."""
        o = self.outcome(ident)
        return o is not None and o["outcome"] == outcome and o["decided_by"] not in ("timeout", "server", "autonomy")

    def label(self, action: str) -> str:
        return self.feature.menu_entry(action).label

    @property
    def level(self) -> str:
        return self.server.call(lambda: self.feature.level)

    def set_level(self, level: str) -> None:
        self.server.call(lambda: self.feature.set_level(level, "test"))


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """The stand-in with tokens per role, its autonomy supervised, proposing nothing by itself (no rules) and
    leaving a proposal a minute to be decided: the tests make the proposals."""
    tmp = tmp_path_factory.mktemp("autonomy_pages")
    rules = tmp / "rules.yaml"
    rules.write_text("timeout_s: 60\non_timeout: drop\nrules: []\n")
    running = RunningServer(ServerSettings(
        port=0, backend="sim", gesture_dir=tmp / "g", audio_dir=tmp / "a", operator_token=TOKENS["operator"],
        supervisor_token=TOKENS["supervisor"], spectator_token=TOKENS["spectator"], autonomy="supervised",
        autonomy_rules=rules))
    yield running
    running.stop()


@pytest.fixture(scope="module")
def autonomy(server):
    return Autonomy(server)


def operator_page(browser, server, *, headset: bool, role: str = "operator"):
    context = browser.new_context(viewport={"width": 960, "height": 600})
    page = context.new_page()
    page.errors = []  # type: ignore[attr-defined]
    page.on("pageerror", lambda exc: page.errors.append(str(exc)))
    if headset:
        page.add_init_script(path=str(IWER))
        page.add_init_script(script=INSTALL_HEADSET)
    page.goto(f"http://127.0.0.1:{server.port}/operator#token={TOKENS[role]}&camera=jpeg")
    page.wait_for_function(READY, timeout=SLOW)
    page.wait_for_function("window.operator.autonomy.model.level !== ''", timeout=SLOW)
    return page


def dashboard_page(browser, server, role: str):
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    page.errors = []  # type: ignore[attr-defined]
    page.on("pageerror", lambda exc: page.errors.append(str(exc)))
    page.goto(f"http://127.0.0.1:{server.port}/#token={TOKENS[role]}&camera=jpeg")
    page.wait_for_function("window.dashboard?.autonomy.level", timeout=SLOW)  # not yet run: wait, do not fail
    return page


def stick(page, x: float, y: float = 0.0) -> None:
    page.evaluate(f"xrDevice.controllers.right.updateAxes('thumbstick', {x}, {y})")
    frames(page)


def shown(page) -> dict | None:
    return page.evaluate("window.operator.autonomy.model.current()")


def screenshot(page, name: str) -> None:
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SCREENSHOTS / name))


def test_the_headset_shows_the_proposal_and_the_right_thumbstick_decides(browser, server, autonomy):
    page = operator_page(browser, server, headset=True)
    try:
        enter_vr(page)
        page.wait_for_function("document.getElementById('hud-autonomy')?.textContent.includes('supervised')",
                               timeout=SLOW)
        before = len(autonomy.outcomes)
        ident = autonomy.propose("emotion.happy", "Ana has stopped after speaking a while")
        page.wait_for_function(f"window.operator.autonomy.model.current()?.id === {ident!r}", timeout=SLOW)
        p = shown(page)
        assert p["reason"] == "Ana has stopped after speaking a while" and p["label"] == autonomy.label(p["action"])
        assert p["timeout"] == 60 and p["confidence"] == 0.8
        # the countdown runs down from the time-out
        page.wait_for_function(f"window.operator.autonomy.model.current().left < {p['left'] - 0.5}", timeout=SLOW)
        assert 0 < shown(page)["fraction"] < 1
        assert page.evaluate("window.operator.proposalMesh.visible")
        screenshot(page, "autonomy_hud.png")

        stick(page, 1.0)  # the right thumbstick pushed right: accept
        assert wait_for(lambda: autonomy.decided(ident, "accepted"), 30), autonomy.outcomes[before:]
        page.wait_for_function("window.operator.autonomy.model.current() === null", timeout=SLOW)
        page.wait_for_function("!window.operator.proposalMesh.visible", timeout=SLOW)
        stick(page, 0.0)

        second = autonomy.propose("emotion.sad", "Ana has just said something")
        page.wait_for_function(f"window.operator.autonomy.model.current()?.id === {second!r}", timeout=SLOW)
        stick(page, -1.0)  # pushed left: reject
        assert wait_for(lambda: autonomy.decided(second, "rejected"), 30), autonomy.outcomes[before:]
        page.wait_for_function("window.operator.autonomy.model.current() === null", timeout=SLOW)
        stick(page, 0.0)
        assert [o["outcome"] for o in autonomy.outcomes[before:]] == ["accepted", "rejected"]  # a push, a decision
        label = autonomy.label("emotion.sad")
        page.wait_for_function(f"document.getElementById('hud-message')?.textContent === '{label}: rejected'",
                               timeout=SLOW)
        assert page.errors == []
    finally:
        page.context.close()


def test_engage_talk_menus_and_estop_never_decide(browser, server, autonomy):
    page = operator_page(browser, server, headset=True)
    try:
        enter_vr(page)
        ident = autonomy.propose("emotion.surprise", "someone new is in view")
        page.wait_for_function(f"window.operator.autonomy.model.current()?.id === {ident!r}", timeout=SLOW)
        press(page, "right", "trigger")  # take control
        page.wait_for_function("document.getElementById('hud-control')?.textContent.startsWith('YOU HAVE CONTROL')",
                               timeout=SLOW)
        press(page, "right", "a-button")  # the commands menu, and the right stick pushed right in it
        page.wait_for_function("document.getElementById('menu-title').textContent === 'Commands'", timeout=SLOW)
        stick(page, 1.0)
        stick(page, 0.0)
        press(page, "right", "a-button")  # closed again
        page.wait_for_function("document.getElementById('menu-title').textContent === ''", timeout=SLOW)
        press(page, "left", "trigger")  # push-to-talk
        press(page, "right", "thumbstick")  # calibrate
        frames(page, 10)
        assert autonomy.outcome(ident) is None and shown(page)["id"] == ident  # still waiting
        stick(page, 1.0)  # and the right input still decides it
        assert wait_for(lambda: autonomy.decided(ident, "accepted"), 30), autonomy.outcome(ident)
        stick(page, 0.0)

        second = autonomy.propose("emotion.neutral", "a pupil looks away")
        page.wait_for_function(f"window.operator.autonomy.model.current()?.id === {second!r}", timeout=SLOW)
        page.evaluate("xrDevice.controllers.left.updateButtonValue('thumbstick', 1);"
                      "xrDevice.controllers.right.updateButtonValue('thumbstick', 1)")  # both sticks: e-stop
        page.wait_for_function("document.getElementById('hud-control')?.textContent.startsWith('E-STOPPED')",
                               timeout=SLOW)
        page.evaluate("xrDevice.controllers.left.updateButtonValue('thumbstick', 0);"
                      "xrDevice.controllers.right.updateButtonValue('thumbstick', 0)")
        frames(page)
        # the e-stop ends the proposal as the server's drop, never as the teacher's decision
        assert wait_for(lambda: autonomy.outcome(second) is not None, 30)
        assert {k: autonomy.outcome(second)[k] for k in ("outcome", "decided_by")} == \
            {"outcome": "dropped", "decided_by": "server"}
        page.wait_for_function("window.operator.autonomy.model.current() === null", timeout=SLOW)
        assert page.errors == []
    finally:
        page.context.close()
        autonomy.set_level("supervised")  # the teacher's word that the robot may move again after the e-stop


def test_the_attention_target_is_drawn_and_the_status_menu_switches_the_level(browser, server, autonomy):
    page = operator_page(browser, server, headset=True)
    try:
        enter_vr(page)
        page.wait_for_function("window.operator.camera.uploaded >= 3", timeout=SLOW)
        # the robot's own attention (the stand-in's pupils, or a glance round the room) drawn over the camera panel
        page.wait_for_function("window.operator.autonomy.place !== null", timeout=SLOW)
        # one snapshot: the place as drawn, with the target and the picture's size it was drawn from
        drawn = page.evaluate("({place: window.operator.autonomy.place, ...window.operator.autonomy.placed})")
        attention, place, size = drawn["attention"], drawn["place"], drawn["image"]
        if place["kind"] == "face":
            f = attention["face"]
            assert place["box"] == pytest.approx({"u": f["x"] / size["width"], "v": f["y"] / size["height"],
                                                  "w": f["width"] / size["width"], "h": f["height"] / size["height"]})
        page.wait_for_function(DRAWN, timeout=SLOW)
        # the HUD says so too (the target may have moved on since the snapshot: wait for the line, not a moment)
        page.wait_for_function("document.getElementById('hud-autonomy').textContent"
                               ".startsWith('autonomy: supervised · looking at')", timeout=SLOW)

        # the drawing itself: a ring where a direction falls, an arrow at the edge for one outside the picture
        rings = page.evaluate("""async () => {
            const {drawAttention} = await import('/operator/autonomy.js');
            const c = document.createElement('canvas');
            c.width = 640; c.height = 480;
            const alpha = (x, y) => c.getContext('2d').getImageData(x, y, 1, 1).data[3];
            drawAttention(c, {kind: 'direction', u: 0.25, v: 0.5, inside: true}, 'Ana (voice)');
            const ring = alpha(160 + 26, 240), centre = alpha(160, 240), corner = alpha(600, 440);
            drawAttention(c, {kind: 'direction', u: 1.4, v: 0.5, inside: false}, 'Ben (voice)');
            return {ring, centre, corner, edge: alpha(640 - 24, 240), middle: alpha(320, 240)};
        }""")
        assert rings == {"ring": 255, "centre": 0, "corner": 0, "edge": 255, "middle": 0}, rings

        # Status (X) › Autonomy (the list item, on the top-left diagonal) › Teleoperated (left), by the left stick
        page.wait_for_function("window.operator.nav.tree !== null", timeout=SLOW)
        choose_in_menu(page, "left", "x-button", "Status", (-0.7, -0.7), "status.autonomy")
        page.wait_for_function("document.getElementById('menu-title').textContent === 'Status › Autonomy'",
                               timeout=SLOW)
        page.evaluate("xrDevice.controllers.left.updateAxes('thumbstick', -1, 0)")
        page.wait_for_function("window.operator.nav.level.entries[window.operator.nav.highlight]?.item.id"
                               " === 'status.autonomy.teleoperated'", timeout=SLOW)
        page.evaluate("xrDevice.controllers.left.updateAxes('thumbstick', 0, 0)")
        screenshot(page, "autonomy_level_menu.png")
        press(page, "left", "trigger")
        assert wait_for(lambda: autonomy.level == "teleoperated", 30)
        page.wait_for_function("document.getElementById('hud-autonomy')?.textContent === 'autonomy: teleoperated'",
                               timeout=SLOW)
        page.wait_for_function("window.operator.autonomy.place === null", timeout=SLOW)  # nobody attended now
        assert page.evaluate("window.operator.autonomy.model.level") == "teleoperated"
        assert page.errors == []
    finally:
        page.context.close()
        autonomy.set_level("supervised")


DRAWN = """() => {  // the target drawn last is on the overlay: the face box's left edge, or the ring, is opaque
    const c = window.operator.attentionCanvas, ctx = c.getContext('2d'), place = window.operator.autonomy.place;
    if (!place) return false;
    const at = (x, y) => ctx.getImageData(Math.round(x), Math.round(y), 1, 1).data[3];
    if (place.kind === 'face') return at(place.box.u * c.width, (place.box.v + place.box.h / 2) * c.height) > 0;
    const x = Math.min(c.width - 24, Math.max(24, place.u * c.width));
    const y = Math.min(c.height - 24, Math.max(24, place.v * c.height));
    return (place.inside ? at(x + 26, y) : at(x, y)) > 0;
}"""


class Frames:
    """The camera frames and the face detector's boxes as the server publishes them (its bus), by frame seq."""

    OWNER = "test-autonomy-pages-frames"
    KEEP = 600

    def __init__(self, server: RunningServer) -> None:
        self.server, self.lock = server, threading.Lock()
        self.jpegs: dict[int, bytes] = {}
        self.faces: dict[int, list[dict]] = {}
        bus = server.server.bus
        self.tokens = server.call(lambda: [
            (names.CAMERA_TOPIC, bus.subscribe(self.OWNER, names.CAMERA_TOPIC, None, self._frame)),
            (names.FACES_TOPIC, bus.subscribe(self.OWNER, names.FACES_TOPIC, None, self._faces))])

    def _frame(self, published) -> None:
        with self.lock:
            self.jpegs[published.data["header"]["seq"]] = published.data["data"]
            while len(self.jpegs) > self.KEEP:
                del self.jpegs[next(iter(self.jpegs))]

    def _faces(self, published) -> None:
        with self.lock:
            self.faces[published.data["frame_seq"]] = published.data["faces"]

    def close(self) -> None:
        self.server.call(lambda: [self.server.server.bus.unsubscribe(t, k) for t, k in self.tokens])


MARKED = """() => {  // one moment of the dashboard: the box drawn, the frame shown under it, the target it came from
    const d = window.dashboard, img = document.getElementById('camera');
    const mark = document.getElementById('attention-mark');
    const r = img.getBoundingClientRect(), m = mark.getBoundingClientRect();
    const scale = Math.min(r.width / img.naturalWidth, r.height / img.naturalHeight);
    return {place: d.attentionPlace, painted: d.camera.painted, src: img.src, attention: d.autonomy.attention,
            hidden: mark.hidden, kind: mark.className, size: [img.naturalWidth, img.naturalHeight],
            mark: [(m.left - r.left - (r.width - img.naturalWidth * scale) / 2) / scale,
                   (m.top - r.top - (r.height - img.naturalHeight * scale) / 2) / scale,
                   m.width / scale, m.height / scale]};
}"""


def test_the_dashboard_draws_the_attended_faces_box_over_the_frame_it_was_found_in(browser, server):
    """Issue 42: the box and the picture under it come from the same capture, box after box as detection goes on
    (the stand-in's pupils face the robot: attention finds a face by itself)."""
    frames = Frames(server)
    page = dashboard_page(browser, server, "supervisor")
    seen: set[int] = set()
    try:
        for _ in range(3):  # three boxes, each from a later frame than the one before
            page.wait_for_function(f"window.dashboard.attentionPlace?.kind === 'face' && !document.getElementById("
                                   f"'attention-mark').hidden && window.dashboard.attentionPlace.frameSeq > "
                                   f"{max(seen, default=0)}", timeout=SLOW)
            m = page.evaluate(MARKED)
            seq = m["place"]["frameSeq"]
            assert not m["hidden"] and m["kind"] == "face", m["kind"]
            assert seq == m["painted"] == m["attention"]["frame_seq"], (seq, m["painted"], m["attention"])
            with frames.lock:  # the picture shown is that frame's JPEG, byte for byte
                jpeg, found = frames.jpegs.get(seq), frames.faces.get(seq, [])
            assert jpeg is not None and m["src"] == "data:image/jpeg;base64," + base64.b64encode(jpeg).decode()
            face = m["attention"]["face"]  # the box is one the detector found in that very frame
            assert any(all(f[k] == face[k] for k in ("x", "y", "width", "height")) for f in found), (face, found)
            assert m["mark"] == pytest.approx([face["x"], face["y"], face["width"], face["height"]], abs=2), m
            seen.add(seq)
        screenshot(page, "dashboard_attention_box.png")
        assert page.errors == []
    finally:
        page.close()
        frames.close()


def test_the_flat_view_decides_with_the_arrow_keys_and_the_cards_buttons(browser, server, autonomy):
    page = operator_page(browser, server, headset=False)
    try:
        ident = autonomy.propose("emotion.happy", "Ana smiled")
        page.wait_for_selector("#proposal:not([hidden])", timeout=SLOW)
        assert page.text_content("#proposal-reason") == "because Ana smiled"
        page.keyboard.press("ArrowRight")
        assert wait_for(lambda: autonomy.decided(ident, "accepted"), 30), autonomy.outcome(ident)
        page.wait_for_selector("#proposal", state="hidden", timeout=SLOW)
        second = autonomy.propose("emotion.sad", "Ana frowned")
        page.wait_for_selector("#proposal:not([hidden])", timeout=SLOW)
        page.click("#proposal-reject")
        assert wait_for(lambda: autonomy.decided(second, "rejected"), 30), autonomy.outcome(second)
        assert page.errors == []
    finally:
        page.context.close()


def test_the_dashboard_decides_with_buttons_and_keys_and_switches_the_level(browser, server, autonomy):
    page = dashboard_page(browser, server, "supervisor")
    try:
        page.wait_for_function("document.getElementById('autonomy-level').textContent === 'supervised'")
        for outcome, how in (("accepted", "button"), ("rejected", "r"), ("forbidden", "n"), ("accepted", "a")):
            ident = autonomy.propose("emotion.happy", "a pupil waved")
            page.wait_for_function(f"window.dashboard.autonomy.current()?.id === {ident!r}", timeout=SLOW)
            page.wait_for_selector("#proposal-card:not([hidden])", timeout=SLOW)
            assert page.text_content("#proposal-reason") == "because a pupil waved"
            if how == "button":
                page.click("#proposal-accept")
            else:
                page.keyboard.press(how)
            assert wait_for(lambda: autonomy.decided(ident, outcome), 30), autonomy.outcome(ident)
            page.wait_for_selector("#proposal-card", state="hidden", timeout=SLOW)
        page.wait_for_function("document.querySelectorAll('#outcomes li').length >= 4", timeout=SLOW)
        outcomes = page.locator("#outcomes li")
        assert "forbidden here" in outcomes.nth(1).text_content() and "rejected" in outcomes.nth(2).text_content()
        page.click("#autonomy [data-level='autonomous']")
        assert wait_for(lambda: autonomy.level == "autonomous", 30)
        page.wait_for_function("document.getElementById('autonomy-level').textContent === 'autonomous'")
        assert page.get_attribute("#autonomy [data-level='autonomous']", "aria-checked") == "true"
        page.click("#autonomy [data-level='supervised']")
        page.wait_for_function("document.getElementById('autonomy-level').textContent === 'supervised'")
        assert page.errors == []
    finally:
        page.close()
        autonomy.set_level("supervised")


def test_one_name_per_pupil_on_both_pages_and_a_rename_seen_in_both(browser, server, autonomy):
    """Issue 42: the pupil the robot looks at has one name, the same on the dashboard and in the headset (its HUD
    line and its camera panel's label): the stand-in pupil's own, never a face-N. The supervisor names her on the
    dashboard, and both pages say the new name. The two other pupils look away, so that hers is the face in view."""
    bystanders = server.server.bystanders
    pupils = {"child_left", "adult_centre", "child_right"}
    for who in ("adult_centre", "child_right"):
        assert server.call(lambda who=who: bystanders.look(who, "away"))["success"]
    dashboard = dashboard_page(browser, server, "supervisor")
    page = operator_page(browser, server, headset=True)
    hud = "(document.getElementById('hud-autonomy')?.textContent ?? '')"
    panel = "(document.getElementById('autonomy-attention').textContent)"
    label = "JSON.stringify(window.operator.autonomy.overlayKey ?? '')"  # the words drawn on the camera panel
    try:
        enter_vr(page)
        page.wait_for_function(f"{hud}.includes('looking at child_left (')", timeout=SLOW)
        page.wait_for_function(f"{label}.includes('child_left (')", timeout=SLOW)
        dashboard.wait_for_function(f"{panel}.startsWith('child_left (')", timeout=SLOW)
        dashboard.wait_for_function("window.dashboard.autonomy.attention?.id === 'child_left'", timeout=SLOW)

        dashboard.wait_for_function("document.getElementById('rename-id').textContent === 'child_left'",
                                    timeout=SLOW)
        dashboard.fill("#rename-name", "Mia")  # the form keeps whom it showed as she began typing
        renamed = dashboard.get_attribute("#rename", "data-id")
        assert renamed in pupils, renamed  # child_left, unless a pupil's voice took the attention meanwhile
        dashboard.press("#rename-name", "Enter")
        page.wait_for_function(f"{hud}.includes('looking at Mia (')", timeout=SLOW)
        page.wait_for_function(f"{label}.includes('Mia (')", timeout=SLOW)
        dashboard.wait_for_function(f"{panel}.startsWith('Mia (')", timeout=SLOW)
        dashboard.wait_for_function(f"document.getElementById('events').textContent.includes('{renamed} is Mia')",
                                    timeout=SLOW)
        assert server.call(lambda: autonomy.feature.name(renamed)) == "Mia"
        screenshot(page, "operator_attention_renamed.png")
        screenshot(dashboard, "dashboard_attention_renamed.png")

        # a name someone else has is refused, and the dashboard says why
        dashboard.fill("#rename-name", "Noah")
        named = dashboard.get_attribute("#rename", "data-id")
        other = next(p for p in sorted(pupils) if p != named)
        server.call(lambda: autonomy.feature.rename(other, "Noah"))
        dashboard.press("#rename-name", "Enter")
        dashboard.wait_for_selector("#autonomy-refusal:not([hidden])", timeout=SLOW)
        assert f"'Noah' is already the name of {other}" in dashboard.text_content("#autonomy-refusal")
        assert page.errors == [] and dashboard.errors == []
    finally:
        for who in pupils:
            server.call(lambda who=who: autonomy.feature.rename(who, ""))
        for who in ("adult_centre", "child_right"):
            server.call(lambda who=who: bystanders.look(who, "robot"))
        page.context.close()
        dashboard.close()


def test_a_spectator_sees_the_proposal_but_its_decision_is_refused(browser, server, autonomy):
    decider = RawClient(server.url)  # an operator watching the proposals: a supervised robot proposes only then
    decider.send({"op": "auth", "mac": TOKENS["operator"]})
    decider.send({"op": "subscribe", "topic": "/vr_teleop/autonomy/proposals", "type": "vr_teleop_msgs/Proposal"})
    assert wait_for(lambda: server.call(autonomy.feature.may_decide), 30)  # the spectator's page is no audience
    page = dashboard_page(browser, server, "spectator")
    try:
        ident = autonomy.propose("emotion.happy", "Ben has just said something")
        page.wait_for_function(f"window.dashboard.autonomy.current()?.id === {ident!r}", timeout=SLOW)
        page.click("#proposal-accept")
        page.wait_for_selector("#autonomy-refusal:not([hidden])", timeout=SLOW)
        assert "spectators only watch" in page.text_content("#autonomy-refusal")
        page.keyboard.press("r")
        page.click("#autonomy [data-level='teleoperated']")
        page.wait_for_function("document.getElementById('autonomy-refusal').textContent.startsWith('level')")
        assert autonomy.outcome(ident) is None and autonomy.level == "supervised"  # refused before the feature
        assert page.evaluate("window.dashboard.autonomy.current()?.id") == ident  # it still waits
        assert page.errors == []
    finally:
        page.close()
        decider.close()


def test_the_geometry_under_node(tmp_path):
    """Where a direction falls in the camera's picture, run by Node on the page's own module."""
    script = tmp_path / "check.mjs"
    script.write_text(f"""
import {{directionInImage, attentionInImage}} from {json.dumps(str(WEB / 'autonomy.js'))};
const out = {{
  ahead: directionInImage(10, 5, 10, 5, 80, 4 / 3),
  left: directionInImage(30, 5, 10, 5, 80, 4 / 3),
  below: directionInImage(10, 15, 10, 5, 80, 4 / 3),
  behind: directionInImage(190, 0, 0, 0, 80, 4 / 3),
  face: attentionInImage({{source: "face", has_face: true, face: {{x: 64, y: 48, width: 32, height: 24}}}},
                         {{yaw: 0, pitch: 0}}, 80, {{width: 640, height: 480}}),
  nobody: attentionInImage({{source: ""}}, {{yaw: 0, pitch: 0}}, 80, null),
}};
console.log(JSON.stringify(out));
""")
    result = subprocess.run(["node", str(script)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)
    assert out["ahead"] == {"u": 0.5, "v": 0.5}
    tan40 = 0.8390996311772799
    # 20 degrees to the left of the head: left of the centre by tan(20) over the half width's tan(40)
    assert out["left"]["u"] == pytest.approx(0.5 - 0.36397023426620234 / (2 * tan40), abs=1e-3)
    assert out["below"]["u"] == pytest.approx(0.5) and out["below"]["v"] > 0.5  # pitch positive down: lower
    assert out["behind"] is None
    assert out["face"] == {"kind": "face", "box": {"u": 0.1, "v": 0.1, "w": 0.05, "h": 0.05}}
    assert out["nobody"] is None
