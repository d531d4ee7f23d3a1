"""The supervisor's dashboard in a real browser (Debian's Chromium driven by Playwright), against a live server
with the stand-in; and roles over real sockets."""

from __future__ import annotations

import json
import urllib.request
from pathlib import Path

import pytest

import roslibpy

from support import Headset, RawClient, RunningServer, call, engage, physics_ran, wait_for
from vr_teleop_server.recording.format import read_recording

TOKENS = {"operator": "op-secret-1", "supervisor": "sup-secret-2", "spectator": "spec-secret-3"}
SCREENSHOTS = Path(__file__).resolve().parent.parent / ".pytest_cache" / "screenshots"


@pytest.fixture(scope="module")
def dashboard_server(module_servers, tmp_path_factory):
    return module_servers(backend="sim", record=tmp_path_factory.mktemp("dashboard") / "session.mcap",
                          operator_token=TOKENS["operator"], supervisor_token=TOKENS["supervisor"],
                          spectator_token=TOKENS["spectator"])


def open_page(browser, server: RunningServer, role: str, camera: str = "jpeg"):
    """The dashboard; its camera on the JPEG topic unless camera="webrtc" (test_media.py tests that path)."""
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.goto(f"http://127.0.0.1:{server.port}/#token={TOKENS[role]}&camera={camera}")
    page.errors = errors  # type: ignore[attr-defined]
    return page


def test_static_files_are_served_on_the_websocket_port(dashboard_server):
    base = f"http://127.0.0.1:{dashboard_server.port}"
    with urllib.request.urlopen(base + "/") as r:
        assert r.status == 200 and r.headers["Content-Type"].startswith("text/html")
        assert b"dashboard.js" in r.read()
    with urllib.request.urlopen(base + "/dashboard.js") as r:
        assert "javascript" in r.headers["Content-Type"]
    with pytest.raises(urllib.error.HTTPError) as info:
        urllib.request.urlopen(base + "/../app.py")
    assert info.value.code == 404


def test_the_page_shows_live_camera_frames_joints_and_menus(browser, dashboard_server):
    page = open_page(browser, dashboard_server, "supervisor")
    try:
        page.wait_for_function("window.dashboard?.frames >= 3", timeout=20_000)
        first = page.get_attribute("#camera", "src")
        mover = RawClient(dashboard_server.url)  # turn the head: the view changes
        mover.send({"op": "auth", "mac": TOKENS["operator"]})
        mover.send({"op": "publish", "topic": "/qt_robot/head_position/command", "msg": {"data": [-25.0, 5.0]}})
        page.wait_for_function(f"document.getElementById('camera').src !== {first!r}", timeout=10_000)
        mover.close()
        assert page.text_content("#camera-age").startswith("frame age")
        page.wait_for_selector(".gauge[data-name='HeadYaw'] .value:not(:empty)")
        page.wait_for_function("document.querySelectorAll('#gauges .gauge').length === 8")
        page.wait_for_function("document.querySelector(\".gauge[data-name='HeadYaw'] .value\").textContent !== '–'")
        page.wait_for_selector("button[data-item='emotion.happy']")
        page.wait_for_selector("button[data-item='motion.play.list.wave']")
        SCREENSHOTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(SCREENSHOTS / "dashboard.png"), full_page=True)
        assert page.errors == []
    finally:
        page.close()


def test_each_emotion_has_one_button_quick_ones_first(browser, dashboard_server):
    """The menus name the four quick emotions twice (their own items, then the generated list of all of them);
    the dashboard shows each emotion once, the quick ones first in their file's order, then the rest in the
    robot's order."""
    listener = RawClient(dashboard_server.url)
    listener.send({"op": "auth", "mac": TOKENS["spectator"]})
    listener.send({"op": "subscribe", "topic": "/vr_teleop/menus", "type": "vr_teleop_msgs/Menus"})
    items = listener.expect("publish", topic="/vr_teleop/menus")["msg"]["items"]
    listener.close()
    emotion_of = {i["id"]: json.loads(i["args"])["name"] for i in items if i["command"] == "show_emotion"}
    published = list(emotion_of.values())
    quick = [i["id"] for i in items if i["command"] == "show_emotion" and i["parent"] == "emotion"]
    assert len(quick) == 4 and len(published) > len(set(published))  # the repeats the dashboard must fold
    every = list(dashboard_server.server.robot.model.emotions)
    page = open_page(browser, dashboard_server, "supervisor")
    try:
        page.wait_for_selector(f"button[data-item='{next(i for i in emotion_of if emotion_of[i] == every[-1])}']")
        shown = page.eval_on_selector_all(
            "#menus .menu button", "bs => bs.map(b => b.dataset.item)")
        names = [emotion_of[i] for i in shown if i in emotion_of]
        expected = [emotion_of[i] for i in quick]
        expected += [e for e in every if e not in expected]
        assert names == expected
        assert page.errors == []
    finally:
        page.close()


def test_a_button_shows_an_emotion_and_escape_stops_the_robot(browser, dashboard_server):
    standin = dashboard_server.server.robot.standin
    page = open_page(browser, dashboard_server, "supervisor")
    try:
        page.wait_for_selector("button[data-item='emotion.sad']")
        page.click("button[data-item='emotion.sad']")
        assert wait_for(lambda: standin.emotion == "sad", 30)
        page.wait_for_function("document.getElementById('events').textContent.includes('showing sad')")
        # A head command is on its way when the supervisor hits Esc: the robot holds where it is.
        client = RawClient(dashboard_server.url)
        client.send({"op": "auth", "mac": TOKENS["operator"]})
        client.send({"op": "publish", "topic": "/qt_robot/head_position/command", "msg": {"data": [50.0, 0.0]}})
        assert wait_for(lambda: standin.joint_positions()["HeadYaw"] > 10, 30)
        page.keyboard.press("Escape")
        page.wait_for_function("document.getElementById('teleop-state').textContent.startsWith('estopped')",
                               timeout=5_000)
        assert physics_ran(standin, 0.3)  # the head comes to rest where the stop found it
        held = standin.joint_positions()["HeadYaw"]
        assert physics_ran(standin, 0.8)  # what it would have moved in, at its cap, had the command gone on
        assert abs(standin.joint_positions()["HeadYaw"] - held) < 1.0 and held < 49
        page.screenshot(path=str(SCREENSHOTS / "estop.png"), full_page=True)
        client.close()
    finally:
        page.close()


def test_the_holders_link_quality_is_shown(browser, dashboard_server):
    """The Teleoperation panel names the holding operator's link from the telemetry, and turns red while the
    robot holds on the operator's silent stream."""
    page = open_page(browser, dashboard_server, "supervisor")
    operator = roslibpy.Ros(host="127.0.0.1", port=dashboard_server.port, headers={
        "Authorization": f"Bearer {TOKENS['operator']}"})
    operator.run(timeout=10)
    headset = Headset(operator).start()
    try:
        engage(operator)
        page.wait_for_function("/^(good|degraded|poor)/.test(document.getElementById('teleop-link').textContent)",
                               timeout=30_000)
        headset.stop()
        page.wait_for_function("document.getElementById('teleop-link').textContent.startsWith('poor: head poses are "
                               "not arriving')", timeout=30_000)
        assert page.get_attribute("#teleop-link", "class") == "danger"
        call(operator, "/vr_teleop/control/engage", "std_srvs/SetBool", {"data": False})
        page.wait_for_function("document.getElementById('teleop-link').textContent === '–'", timeout=30_000)
        assert page.errors == []
    finally:
        headset.stop()
        operator.close()
        page.close()


def test_labels_appear_in_the_recording(browser, dashboard_server):
    page = open_page(browser, dashboard_server, "supervisor")
    try:
        page.wait_for_selector("#label-action")
        page.fill("#label-action", "hand_over_cup")
        page.click("header h1")  # focus off the input, so the keys are shortcuts
        page.keyboard.press("h")
        page.wait_for_function("document.querySelectorAll('#labels li').length >= 1")  # the start taken first
        page.keyboard.press("j")
        page.wait_for_function("document.querySelectorAll('#labels li').length >= 2")
    finally:
        page.close()
    server = dashboard_server.server

    def labels() -> list:
        if server.recorder:  # on the server's loop, where the recorder writes: never beside a write
            dashboard_server.call(server.recorder.flush)
        return [m for m in read_recording(Path(dashboard_server.settings.record)) if m.topic == "/study/labels"]
    assert wait_for(lambda: len(labels()) >= 2, 30)  # a failure bound on a loaded machine, never a measure
    kinds = [m.data["kind"] for m in labels()]
    assert kinds[-2:] == ["human_action_start", "human_action_stop"]
    assert '"hand_over_cup"' in labels()[-1].data["detail"] and labels()[-1].data["source"] == "experimenter"


def test_a_spectator_watches_but_cannot_command(browser, dashboard_server):
    standin = dashboard_server.server.robot.standin
    before = standin.emotion
    page = open_page(browser, dashboard_server, "spectator")
    try:
        page.wait_for_function("window.dashboard?.frames >= 1", timeout=20_000)  # watching works
        page.wait_for_selector("button[data-item='emotion.surprise']")
        page.click("button[data-item='emotion.surprise']")
        page.wait_for_function("document.getElementById('events').textContent.includes('spectator')", timeout=5_000)
        assert standin.emotion == before != "surprise"
        page.screenshot(path=str(SCREENSHOTS / "spectator.png"), full_page=True)
    finally:
        page.close()


def test_roles_over_the_protocol(dashboard_server):
    anonymous = RawClient(dashboard_server.url)
    spectator = RawClient(dashboard_server.url)
    operator = RawClient(dashboard_server.url)
    try:
        anonymous.send({"op": "subscribe", "topic": "/qt_robot/joints/state"})
        assert "authenticate first" in anonymous.expect("status", level="error")["msg"]
        anonymous.send({"op": "auth", "mac": "wrong"})
        assert "not known" in anonymous.expect("status", level="error")["msg"]
        spectator.send({"op": "auth", "mac": TOKENS["spectator"]})
        spectator.send({"op": "publish", "topic": "/vr/head/pose", "msg": {}})
        status = spectator.expect("status", level="error")
        assert "refused" in status["msg"] and "spectator" in status["msg"]
        spectator.send({"op": "call_service", "id": "t", "service": "/rosapi/get_time"})
        assert spectator.expect("service_response", id="t")["result"] is True  # reading is allowed
        spectator.send({"op": "call_service", "id": "e", "service": "/vr_teleop/control/estop"})
        assert "spectator" in spectator.expect("status", level="error")["msg"]
        assert spectator.expect("service_response", id="e")["values"]["success"] is False
        operator.send({"op": "auth", "mac": TOKENS["operator"]})
        operator.send({"op": "call_service", "id": "m", "service": "/vr_teleop/motivation/reset", "args": {}})
        assert "only a supervisor" in operator.expect("status", level="error")["msg"]
        refused = operator.expect("service_response", id="m")  # answered inside the response too (ROS#)
        assert refused["result"] is True and refused["values"]["success"] is False
        assert "only a supervisor" in refused["values"]["message"]
        operator.send({"op": "call_service", "id": "t", "service": "/rosapi/get_time"})
        assert operator.expect("service_response", id="t")["result"] is True
    finally:
        for c in (anonymous, spectator, operator):
            c.close()


def test_open_access_only_on_loopback(tmp_path):
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "vr_teleop_server.cli", "serve", "--backend", "none", "--host",
                           "0.0.0.0", "--port", "0"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "without tokens" in proc.stderr and "--insecure" in proc.stderr


def test_tls_serves_https_and_wss(tmp_path, servers):
    import ssl
    import subprocess

    from websockets.sync.client import connect

    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key), "-out",
                    str(cert), "-days", "1", "-subj", "/CN=127.0.0.1"], check=True, capture_output=True)
    server = servers(certfile=cert, keyfile=key)
    assert server.url.startswith("wss://")
    context = ssl.create_default_context(cafile=str(cert))
    context.check_hostname = False
    with urllib.request.urlopen(f"https://127.0.0.1:{server.port}/", context=context) as r:
        assert r.status == 200 and b"dashboard.js" in r.read()
    with connect(server.url, ssl=context) as ws:
        ws.send('{"op": "call_service", "id": "t", "service": "/rosapi/get_time"}')
        assert '"service_response"' in ws.recv(timeout=5)
