"""The pages' words in English, German and French (web/i18n.js, web/i18n/<code>.json): every catalogue has every
key with the same {placeholders}, the pages use only keys that exist and every key is used; in Chromium the
dashboard shows its words in the language of #lang= or of the browser, switches the robot's language, and a
supervisor adds a clip from it and plays it."""

from __future__ import annotations

import io
import json
import re
import wave
from pathlib import Path

import numpy as np
import pytest
from support import wait_for
from testbed.pages import READY

from menus import load_menus, walk
from robot_models import load_qtrobot

WEB = Path(__file__).resolve().parent.parent / "vr_teleop_server" / "web"
CATALOGUES = {code: json.loads((WEB / "i18n" / f"{code}.json").read_text(encoding="utf-8")) for code in
              ("en", "de", "fr")}
TOKENS = {"operator": "op-words-1", "supervisor": "sup-words-2"}


def used_keys() -> dict[str, set[str]]:
    """key -> the files that use it: data-i18n* attributes in the HTML, t("key") in the scripts."""
    used: dict[str, set[str]] = {}
    for path in [*WEB.glob("*.html"), *WEB.glob("*.js"), *(WEB / "operator").glob("*.js")]:
        text = path.read_text(encoding="utf-8")
        keys = re.findall(r'data-i18n(?:-title|-placeholder)?="([^"]+)"', text)
        keys += re.findall(r'\bt\(\s*"([^"]+)"', text)
        for key in keys:
            used.setdefault(key, set()).add(path.name)
    return used


def test_every_catalogue_has_every_key_with_the_same_placeholders():
    english = CATALOGUES["en"]
    for code, catalogue in CATALOGUES.items():
        assert set(catalogue) == set(english), (code, set(english) ^ set(catalogue))
        for key, text in catalogue.items():
            assert isinstance(text, str) and text.strip(), (code, key)
            assert set(re.findall(r"\{(\w+)\}", text)) == set(re.findall(r"\{(\w+)\}", english[key])), (code, key)


def test_the_pages_use_only_keys_that_exist_and_every_key_is_used():
    used = used_keys()
    missing = {key: files for key, files in used.items() if key not in CATALOGUES["en"]}
    assert not missing, f"keys used by the pages but in no catalogue: {missing}"
    static = {k for k in CATALOGUES["en"] if not k.startswith(("menu.", "emotion."))}
    assert static - set(used) == set(), "keys no page uses"


def test_the_menu_words_name_every_packaged_item_and_emotion():
    """i18n.js's translateMenus looks words up by menu item id (menu.<id>) and emotion (emotion.<name>): each key
    names one that exists, and every packaged item and emotion has its word (the language items keep their own
    names, the generated items theirs)."""
    ids = set()
    for menu in load_menus():
        ids.add(menu.info.id)
        ids.update(item.id for _p, _i, item in walk(menu.items, menu.info.id)
                   if item.command != "show_emotion" and not item.id.startswith("speech.language."))
    words = {k.removeprefix("menu.") for k in CATALOGUES["en"] if k.startswith("menu.")}
    assert words == ids, (words ^ ids)
    emotions = {k.removeprefix("emotion.") for k in CATALOGUES["en"] if k.startswith("emotion.")}
    assert emotions == set(load_qtrobot().emotions)


def open_dashboard(browser, server, fragment: str, locale: str = "en-GB"):
    context = browser.new_context(locale=locale, viewport={"width": 1400, "height": 1000})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.goto(f"http://127.0.0.1:{server.port}/#token={TOKENS['supervisor']}&camera=jpeg&{fragment}")
    page.wait_for_function("document.querySelector('#connection').classList.contains('on')", timeout=30_000)
    page.errors = errors  # type: ignore[attr-defined]
    return page


@pytest.fixture
def words_server(servers, tmp_path):
    return servers(backend="sim", bystander_interval=0, clips=tmp_path / "clips",
                   operator_token=TOKENS["operator"], supervisor_token=TOKENS["supervisor"])


def test_the_dashboard_speaks_the_readers_language(browser, words_server):
    for fragment, locale, heading, language in (("lang=de", "en-GB", "Kopfkamera", "de"),
                                                ("", "fr-FR", "Caméra de la tête", "fr"),
                                                ("", "nl-NL", "Head camera", "en")):
        page = open_dashboard(browser, words_server, fragment, locale)
        try:
            assert page.text_content("[data-i18n='camera.heading']") == heading
            assert page.evaluate("document.documentElement.lang") == language
            assert page.input_value("#page-language") == language
            assert page.text_content("#connection") == json.loads(
                (WEB / "i18n" / f"{language}.json").read_text(encoding="utf-8"))["connection.connected"]
            assert page.errors == []
        finally:
            page.context.close()


def test_from_the_dashboard_the_robots_language_switches_and_a_clip_is_added_and_played(browser, words_server,
                                                                                      tmp_path):
    server = words_server
    page = open_dashboard(browser, server, "lang=de")
    try:
        page.wait_for_selector("#menus button:text-is('fröhlich')", timeout=20_000)  # the emotions' words
        page.wait_for_selector("#menus h3:text-is('Gefühle')", timeout=20_000)
        page.click("#robot-languages [data-language='lb']")
        page.wait_for_selector("#robot-languages [data-language='lb'][aria-pressed='true']", timeout=20_000)
        assert server.call(lambda: server.server.robot is not None)

        t = np.arange(16000) / 16000
        buf = io.BytesIO()
        with wave.open(buf, "wb") as w:
            w.setnchannels(1)
            w.setsampwidth(2)
            w.setframerate(16000)
            w.writeframes((np.sin(2 * np.pi * 300 * t) * 3000).astype("<i2").tobytes())
        clip = tmp_path / "Oma sagt Hallo.wav"
        clip.write_bytes(buf.getvalue())
        page.set_input_files("#clip-file", str(clip))
        page.click("#clip-form button[data-i18n='voices.add']")
        page.wait_for_selector("#clips button[data-clip='Oma_sagt_Hallo']", timeout=20_000)
        assert page.text_content("#clip-result") == "Aufnahme Oma_sagt_Hallo hinzugefügt (1.0 s)"
        assert (server.settings.clips / "Oma_sagt_Hallo.wav").read_bytes() == buf.getvalue()

        robot = server.server.robot
        page.click("#clips button[data-clip='Oma_sagt_Hallo']")
        assert wait_for(lambda: server.call(lambda: robot.voice_level) > 0.3, 30), "the mouth did not move"

        (tmp_path / "loud.wav").write_bytes(_loud_wav())
        page.set_input_files("#clip-file", str(tmp_path / "loud.wav"))
        page.click("#clip-form button[data-i18n='voices.add']")
        page.wait_for_function("document.querySelector('#clip-result').textContent.includes('abgelehnt')",
                               timeout=20_000)
        assert "too loud" in page.text_content("#clip-result")  # the server's reason, as it gave it
        assert page.errors == []
    finally:
        page.context.close()


def _loud_wav() -> bytes:
    buf = io.BytesIO()
    with wave.open(buf, "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(16000)
        w.writeframes((np.sign(np.sin(np.arange(16000) / 5)) * 32767).astype("<i2").tobytes())
    return buf.getvalue()


def test_the_operator_page_speaks_the_readers_language(browser, words_server):
    context = browser.new_context(locale="de-AT", viewport={"width": 1000, "height": 640})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    try:
        # lang= wins over the browser's de-AT
        page.goto(f"http://127.0.0.1:{words_server.port}/operator#token={TOKENS['operator']}&camera=jpeg&lang=fr")
        page.wait_for_function("document.querySelector('#vr-note').textContent !== ''", timeout=60_000)
        assert page.evaluate("document.documentElement.lang") == "fr"
        assert page.text_content("h1") == "Opérateur QTrobot"
        assert page.text_content("#enter-vr") == "Entrer en VR"
        assert page.text_content("#vr-note") == "pas de casque : vue à plat"  # no headset in this browser
        assert page.text_content("[data-i18n='operator.help.5']") == "arrêt d'urgence"
        page.wait_for_function(READY, timeout=60_000)
        page.wait_for_function("window.operator.nav.tree !== null", timeout=60_000)
        page.keyboard.press("y")  # Y: the speech menu, its title in French
        page.wait_for_function("document.getElementById('menu-title').textContent === 'Parole'", timeout=60_000)
        assert errors == []
    finally:
        context.close()
