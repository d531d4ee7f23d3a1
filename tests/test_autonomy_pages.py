"""Supervised autonomy on both pages (issue 34), in Chromium through Playwright, IWER as the headset: the robot's
proposal on the HUD with its reason and countdown, decided by the right thumbstick (and never by the buttons that
take control, stop the robot or open menus), the attention target on the camera panel, the level; the dashboard's
buttons and keys, its level switch, the outcomes as they come; a spectator's page that sees but cannot decide.

The server is the real one on the MuJoCo stand-in; the pages speak to it over rosbridge, and what the pages call is
read from the server's side (the outcomes topic, the level in its state).
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from support import RunningServer, wait_for
from test_operator_page import INSTALL_HEADSET, IWER, READY, SLOW, enter_vr, frames, press
from vr_teleop_server.settings import ServerSettings

ROOT = Path(__file__).resolve().parent.parent
WEB = ROOT / "vr_teleop_server" / "web"
TOKENS = {"operator": "op-autonomy-1", "supervisor": "sup-autonomy-2", "spectator": "spec-autonomy-3"}
SCREENSHOTS = ROOT / ".pytest_cache" / "screenshots"
STATE = "/vr_teleop/autonomy/state"
PROPOSALS = "/vr_teleop/autonomy/proposals"
OUTCOMES = "/vr_teleop/autonomy/outcomes"
ATTENTION = "/vr_teleop/autonomy/attention"


class FakeAutonomy:
    """The server's side of the contract, in the server's process on its bus (until the feature lands): the level
    and decide services, the state, proposals, attention and outcomes topics. It records every call it gets."""

    OWNER = "test-autonomy"

    def __init__(self, server: RunningServer) -> None:
        self.server = server
        self.bus = server.server.bus
        self.level = "supervised"
        self.pending: dict[str, dict] = {}
        self.calls: list[tuple[str, dict]] = []
        self.ids = 0
        self.attention = {"header": {}, "source": "", "who": "", "yaw": 0.0, "pitch": 0.0, "has_face": False,
                          "face": {"x": 0, "y": 0, "width": 0, "height": 0, "confidence": 0.0}, "score": 0.0}
        server.call(self._advertise)

    def _advertise(self) -> None:
        for name, type_name in ((STATE, "vr_teleop_msgs/AutonomyState"), (PROPOSALS, "vr_teleop_msgs/Proposal"),
                                (OUTCOMES, "vr_teleop_msgs/ProposalOutcome"),
                                (ATTENTION, "vr_teleop_msgs/AttentionTarget")):
            self.bus.advertise(self.OWNER, name, type_name, latched=name == STATE)
        self.bus.advertise_service(self.OWNER, "/vr_teleop/autonomy/decide", "vr_teleop_msgs/DecideProposal",
                                   self._decide)
        self.bus.advertise_service(self.OWNER, "/vr_teleop/autonomy/level", "vr_teleop_msgs/SetAutonomy",
                                   self._set_level)
        self._publish_state()

    def _publish_state(self) -> None:
        self.bus.publish(STATE, {"header": {}, "level": self.level, "attention": self.attention,
                                 "pending": list(self.pending.values()), "running": ["attention"],
                                 "owners": [{"part": "head", "owner": "autonomy"}]}, latch=True)

    async def _decide(self, request, now):
        self.calls.append(("decide", {"id": request.id, "decision": request.decision}))
        p = self.pending.pop(request.id, None)
        if p is None:
            return {"success": False, "message": f"no pending proposal {request.id!r}"}
        outcome = {"accept": "accepted", "reject": "rejected", "forbid": "forbidden"}[request.decision]
        self._end(p, outcome)
        self._publish_state()
        return {"success": True, "message": f"{p['id']} {outcome}"}

    def _end(self, p: dict, outcome: str) -> None:
        self.pending.pop(p["id"], None)
        self.bus.publish(OUTCOMES, {"header": {}, "id": p["id"], "action": p["action"], "outcome": outcome,
                                    "initiator": "robot", "decided_by": "teacher", "seconds": 1.5,
                                    "situation": p["situation"]})

    async def _set_level(self, request, now):
        self.calls.append(("level", {"level": request.level}))
        self.level = request.level
        self._publish_state()
        return {"success": True, "message": f"autonomy level {request.level}"}

    def propose(self, label: str, reason: str, *, timeout: float = 60.0, confidence: float = 0.8) -> str:
        def publish() -> str:
            for old in list(self.pending.values()):  # as the feature does: a newer proposal supersedes
                self._end(old, "superseded")
            self.ids += 1
            p = {"header": {}, "id": f"p-{self.ids}", "action": f"menu.{label.lower().replace(' ', '_')}",
                 "label": label, "reason": reason, "confidence": confidence, "timeout": timeout,
                 "on_timeout": "execute", "situation": "speech_ended"}
            self.pending[p["id"]] = p
            self.bus.publish(PROPOSALS, p)
            self._publish_state()
            return p["id"]
        return self.server.call(publish)

    def look_at(self, yaw: float, pitch: float, who: str = "Ana", face: dict | None = None) -> None:
        def publish() -> None:
            self.attention = {**self.attention, "source": "both" if face else "voice", "who": who, "yaw": yaw,
                              "pitch": pitch, "has_face": face is not None, "score": 0.7,
                              "face": {**self.attention["face"], **(face or {})}}
            self.bus.publish(ATTENTION, self.attention)
        self.server.call(publish)

    def decisions(self) -> list[dict]:
        return [args for kind, args in self.calls if kind == "decide"]


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("autonomy_pages")
    running = RunningServer(ServerSettings(
        port=0, backend="sim", gesture_dir=tmp / "g", audio_dir=tmp / "a", operator_token=TOKENS["operator"],
        supervisor_token=TOKENS["supervisor"], spectator_token=TOKENS["spectator"]))
    yield running
    running.stop()


@pytest.fixture(scope="module")
def autonomy(server):
    return FakeAutonomy(server)


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
    page.wait_for_function("window.dashboard.autonomy.level !== ''", timeout=SLOW)
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
        ident = autonomy.propose("Well done", "Ana has stopped after speaking a while", timeout=60.0)
        page.wait_for_function(f"window.operator.autonomy.model.current()?.id === {ident!r}", timeout=SLOW)
        p = shown(page)
        assert p["reason"] == "Ana has stopped after speaking a while" and p["label"] == "Well done"
        # the countdown runs down from the time-out
        page.wait_for_function(f"window.operator.autonomy.model.current().left < {p['left'] - 0.5}", timeout=SLOW)
        assert 0 < shown(page)["fraction"] < 1
        assert page.evaluate("window.operator.proposalMesh.visible")
        screenshot(page, "autonomy_hud.png")

        stick(page, 1.0)  # the right thumbstick pushed right: accept
        assert wait_for(lambda: autonomy.decisions() == [{"id": ident, "decision": "accept"}], 10)
        page.wait_for_function("window.operator.autonomy.model.current() === null", timeout=SLOW)
        page.wait_for_function("!window.operator.proposalMesh.visible", timeout=SLOW)
        stick(page, 0.0)

        second = autonomy.propose("Nod", "Ana has just said something")
        page.wait_for_function(f"window.operator.autonomy.model.current()?.id === {second!r}", timeout=SLOW)
        stick(page, -1.0)  # pushed left: reject
        assert wait_for(lambda: autonomy.decisions()[-1] == {"id": second, "decision": "reject"}, 10)
        page.wait_for_function("window.operator.autonomy.model.current() === null", timeout=SLOW)
        stick(page, 0.0)
        assert len(autonomy.decisions()) == 2  # one push, one decision
        page.wait_for_function("document.getElementById('hud-message')?.textContent === 'Nod: rejected'",
                               timeout=SLOW)
        assert page.errors == []
    finally:
        page.context.close()


def test_engage_estop_and_menus_never_decide(browser, server, autonomy):
    page = operator_page(browser, server, headset=True)
    try:
        enter_vr(page)
        before = len(autonomy.decisions())
        ident = autonomy.propose("Hello", "someone new is in view")
        page.wait_for_function(f"window.operator.autonomy.model.current()?.id === {ident!r}", timeout=SLOW)
        press(page, "right", "trigger")  # take control
        page.wait_for_function("document.getElementById('hud-control')?.textContent.startsWith('YOU HAVE CONTROL')",
                               timeout=SLOW)
        page.evaluate("xrDevice.controllers.left.updateButtonValue('thumbstick', 1);"
                      "xrDevice.controllers.right.updateButtonValue('thumbstick', 1)")  # both sticks: e-stop
        page.wait_for_function("document.getElementById('hud-control')?.textContent.startsWith('E-STOPPED')",
                               timeout=SLOW)
        page.evaluate("xrDevice.controllers.left.updateButtonValue('thumbstick', 0);"
                      "xrDevice.controllers.right.updateButtonValue('thumbstick', 0)")
        frames(page)
        press(page, "right", "a-button")  # the commands menu, and the stick pushed right in it
        page.wait_for_function("document.getElementById('menu-title').textContent === 'Commands'", timeout=SLOW)
        stick(page, 1.0)
        stick(page, 0.0)
        press(page, "right", "a-button")  # closed again
        page.wait_for_function("document.getElementById('menu-title').textContent === ''", timeout=SLOW)
        press(page, "left", "trigger")  # push-to-talk
        frames(page, 10)
        assert len(autonomy.decisions()) == before
        assert shown(page)["id"] == ident  # still waiting
        stick(page, 1.0)  # and the right input still decides it
        assert wait_for(lambda: autonomy.decisions()[before:] == [{"id": ident, "decision": "accept"}], 10)
        stick(page, 0.0)
        assert page.errors == []
    finally:
        page.context.close()


def test_the_attention_target_is_drawn_on_the_camera_panel(browser, server, autonomy):
    page = operator_page(browser, server, headset=True)
    try:
        enter_vr(page)
        page.wait_for_function("window.operator.camera.uploaded >= 3", timeout=SLOW)
        head = page.evaluate("window.operator.state.robotHead")
        autonomy.look_at(head["yaw"] + 20.0, head["pitch"] - 10.0)  # 20 deg left of the head, 10 deg above it
        page.wait_for_function("window.operator.autonomy.place?.kind === 'direction'", timeout=SLOW)
        place = page.evaluate("window.operator.autonomy.place")
        assert place["inside"] and place["u"] < 0.5 and place["v"] < 0.5, place
        drawn = page.evaluate("""([u, v]) => {
            const c = window.operator.attentionCanvas, ctx = c.getContext('2d');
            const alpha = (x, y) => ctx.getImageData(Math.round(x), Math.round(y), 1, 1).data[3];
            const x = u * c.width, y = v * c.height;
            return {ring: Math.max(...[0, 90, 180, 270].map((a) => alpha(x + 26 * Math.cos(a * Math.PI / 180),
                                                                            y + 26 * Math.sin(a * Math.PI / 180)))),
                    far: alpha(c.width - 5, c.height - 5)};
        }""", [place["u"], place["v"]])
        assert drawn["ring"] > 0 and drawn["far"] == 0, drawn
        assert "looking at Ana (voice)" in page.text_content("#hud-autonomy")

        autonomy.look_at(0.0, 0.0, who="Ben", face={"x": 320, "y": 120, "width": 80, "height": 100})
        page.wait_for_function("window.operator.autonomy.place?.kind === 'face'", timeout=SLOW)
        size = page.evaluate("window.operator.camera.size")
        box = page.evaluate("window.operator.autonomy.place.box")
        assert box == pytest.approx({"u": 320 / size["width"], "v": 120 / size["height"],
                                     "w": 80 / size["width"], "h": 100 / size["height"]})
        edge = page.evaluate("""() => {
            const c = window.operator.attentionCanvas, b = window.operator.autonomy.place.box;
            return c.getContext('2d').getImageData(Math.round(b.u * c.width), Math.round((b.v + b.h / 2) * c.height),
                                                   1, 1).data[3];
        }""")
        assert edge > 0  # the box's left edge
        screenshot(page, "autonomy_attention.png")
        assert page.errors == []
    finally:
        page.context.close()


def test_the_flat_view_decides_with_the_arrow_keys(browser, server, autonomy):
    page = operator_page(browser, server, headset=False)
    try:
        ident = autonomy.propose("Happy face", "Ana smiled")
        page.wait_for_selector("#proposal:not([hidden])", timeout=SLOW)
        assert page.text_content("#proposal-reason") == "because Ana smiled"
        page.keyboard.press("ArrowRight")
        assert wait_for(lambda: autonomy.decisions()[-1] == {"id": ident, "decision": "accept"}, 10)
        page.wait_for_selector("#proposal", state="hidden", timeout=SLOW)
        second = autonomy.propose("Sad face", "Ana frowned")
        page.wait_for_selector("#proposal:not([hidden])", timeout=SLOW)
        page.click("#proposal-reject")
        assert wait_for(lambda: autonomy.decisions()[-1] == {"id": second, "decision": "reject"}, 10)
        assert page.errors == []
    finally:
        page.context.close()


def test_the_dashboard_decides_with_buttons_and_keys_and_switches_the_level(browser, server, autonomy):
    page = dashboard_page(browser, server, "supervisor")
    try:
        page.wait_for_function("document.getElementById('autonomy-level').textContent === 'supervised'")
        for decision, how in (("accept", "button"), ("reject", "r"), ("forbid", "n"), ("accept", "a")):
            ident = autonomy.propose("Wave", "a pupil waved")
            page.wait_for_selector("#proposal-card:not([hidden])", timeout=SLOW)
            page.wait_for_function(f"window.dashboard.autonomy.current()?.id === {ident!r}", timeout=SLOW)
            assert page.text_content("#proposal-reason") == "because a pupil waved"
            if how == "button":
                page.click("#proposal-accept")
            else:
                page.keyboard.press(how)
            assert wait_for(lambda: autonomy.decisions()[-1] == {"id": ident, "decision": decision}, 10)
            page.wait_for_selector("#proposal-card", state="hidden", timeout=SLOW)
        outcomes = page.locator("#outcomes li")
        page.wait_for_function("document.querySelectorAll('#outcomes li').length >= 4", timeout=SLOW)
        assert "forbidden here" in outcomes.nth(1).text_content() and "rejected" in outcomes.nth(2).text_content()
        page.click("#autonomy [data-level='autonomous']")
        assert wait_for(lambda: ("level", {"level": "autonomous"}) in autonomy.calls, 10)
        page.wait_for_function("document.getElementById('autonomy-level').textContent === 'autonomous'")
        assert page.get_attribute("#autonomy [data-level='autonomous']", "aria-checked") == "true"
        page.click("#autonomy [data-level='supervised']")
        page.wait_for_function("document.getElementById('autonomy-level').textContent === 'supervised'")
        assert page.errors == []
    finally:
        page.close()


def test_a_spectator_sees_the_proposal_but_its_decision_is_refused(browser, server, autonomy):
    page = dashboard_page(browser, server, "spectator")
    try:
        before = len(autonomy.calls)
        ident = autonomy.propose("Nod", "Ben has just said something")
        page.wait_for_function(f"window.dashboard.autonomy.current()?.id === {ident!r}", timeout=SLOW)
        page.click("#proposal-accept")
        page.wait_for_selector("#autonomy-refusal:not([hidden])", timeout=SLOW)
        assert "spectators only watch" in page.text_content("#autonomy-refusal")
        page.keyboard.press("r")
        page.click("#autonomy [data-level='teleoperated']")
        page.wait_for_function("document.getElementById('autonomy-refusal').textContent.includes('level')")
        assert len(autonomy.calls) == before  # the server refused all three before they reached the feature
        assert page.evaluate("window.dashboard.autonomy.current()?.id") == ident  # it still waits
        assert page.errors == []
    finally:
        page.close()


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
