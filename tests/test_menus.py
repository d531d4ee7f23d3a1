"""Menu files: the packaged trees, and bad files refused with the file, the item and the problem named."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from menus import COMMANDS, Command, MenuError, language_words, load_menus, walk
from robot_models import load_qtrobot
from vr_teleop_server.features.menu_service import MENU_HANDLERS, MenuService

ROOT = Path(__file__).resolve().parent.parent


def ids(menu) -> dict[str, object]:
    return {item.id: item for _parent, _pos, item in walk(menu.items, menu.info.id)}


def test_packaged_trees_reproduce_and_complete_the_papers_menus():
    menus = {m.info.id: m for m in load_menus()}
    status, motion = menus["status"], menus["motion"]
    assert status.info.controller == "left" and motion.info.controller == "right"
    shown = {item.args["which"] for item in ids(status).values() if item.command == "show_status"}
    assert shown == {"hardware", "motors", "dialog", "motivation"}
    commands = {item.command for item in ids(motion).values()}
    assert {"record_toggle", "set_arms_control", "set_head_control", "stop_gesture"} <= commands
    assert any(item.generate == "gestures" for item in ids(motion).values())
    assert any(item.generate == "emotions" for item in ids(menus["emotion"]).values())
    assert any(item.generate == "sentences" for item in ids(menus["speech"]).values())
    # The prototype's slots: status left/top/right/bottom = hardware/dialog/motivation/motors.
    slots = {item.slot: item.args.get("which") for item in status.items if item.slot != "list"}
    assert slots == {"left": "hardware", "top": "dialog", "right": "motivation", "bottom": "motors"}
    # and, in its list, the autonomy level (issue #34)
    levels = {item.args["level"] for item in ids(status).values() if item.command == "set_autonomy"}
    assert levels == {"teleoperated", "supervised", "autonomous"}


def test_every_command_has_its_arguments_and_one_handler():
    """The vocabulary, its arguments' models and the server's handlers name the same commands; each handler is the
    service's own."""
    assert list(COMMANDS) == list(MENU_HANDLERS) == list(Command)
    assert all(getattr(MenuService, f"_do_{c.value}") is MENU_HANDLERS[c] for c in Command)


def test_emotion_items_name_real_emotions():
    emotions = set(load_qtrobot().emotions)
    for menu in load_menus():
        for item in ids(menu).values():
            if item.command == "show_emotion":
                assert item.args["name"] in emotions


GOOD_HEADER = "menu: {id: m, label: M}\nitems:\n"
BAD_FILES = [
    ("- {id: a, label: A, command: dance}\n", "item 'a'", "unknown command 'dance'"),
    ("- {id: a, label: A, command: show_status, args: {which: mood}}\n", "item 'a'", "args of show_status: which"),
    ("- {id: a, label: A, slot: top, command: stop_gesture}\n- {id: b, label: B, slot: top, command: estop}\n",
     "", "items 'a' and 'b' both take slot top"),
    ("- {id: a, label: A, command: estop, submenu: []}\n", "item 'a'", "exactly one of command, submenu or generate"),
    ("- {id: a, label: A}\n", "item 'a'", "exactly one of command, submenu or generate"),
    ("- {id: a, label: A, command: estop, colour: red}\n", "item 'a'", "colour"),
    ("- {id: a, label: A, submenu: [{id: b, label: B, command: say, args: {}}]}\n", "item 'b'", "text"),
    ("- {id: a, label: A, generate: sentences, source: missing.txt}\n", "item 'a'", "missing.en.txt is missing"),
    ("- {id: a, label: A, command: estop}\n- {id: a, label: B, command: estop}\n", "item 'a'", "duplicate id"),
    ("- {id: a, label: A, command: estop\n", "", "not valid YAML"),  # as every data file (client_protocol/files)
    ("- {label: A, command: estop}\n", "item #1", "id: Field required"),
]


@pytest.mark.parametrize("body, where, problem", BAD_FILES)
def test_bad_menu_file_names_file_item_and_problem(tmp_path, body, where, problem):
    (tmp_path / "bad.yaml").write_text(GOOD_HEADER + body)
    with pytest.raises(MenuError) as info:
        load_menus(tmp_path)
    message = str(info.value)
    assert str(tmp_path / "bad.yaml") in message and where in message and problem in message, message


def test_an_unknown_sentence_variable_names_the_file_and_the_line_at_load(tmp_path):
    """Every language's list is checked when the menus load, not when the robot switches to it."""
    (tmp_path / "s.yaml").write_text(GOOD_HEADER + "- {id: a, label: A, generate: sentences, source: lines.txt}\n")
    (tmp_path / "lines.en.txt").write_text("# a comment\nWell done, {pupil}!\nThank you, {teacher}.\n")
    (tmp_path / "lines.de.txt").write_text("# ein Kommentar\nGut gemacht, {pupil}!\nDanke, {lehrer}.\n")
    with pytest.raises(MenuError) as info:
        load_menus(tmp_path)
    message = str(info.value)
    assert f"{tmp_path / 'lines.de.txt'}:3: unknown variable {{lehrer}}" in message, message
    assert "{pupil}, {teacher}" in message and str(tmp_path / "s.yaml") in message, message
    (tmp_path / "lines.de.txt").write_text("Gut gemacht, {pupil}!\nDanke, {teacher}.\n")
    assert load_menus(tmp_path)[0].info.id == "m"


def test_duplicate_ids_across_files_name_both(tmp_path):
    (tmp_path / "a.yaml").write_text("menu: {id: one, label: One}\nitems:\n- {id: x, label: X, command: estop}\n")
    (tmp_path / "b.yaml").write_text("menu: {id: two, label: Two}\nitems:\n- {id: x, label: X, command: estop}\n")
    with pytest.raises(MenuError, match=r"b\.yaml: item 'x': duplicate id \(also in .*a\.yaml\)"):
        load_menus(tmp_path)


def test_serve_refuses_a_bad_menu_file(tmp_path):
    (tmp_path / "motion.yaml").write_text(GOOD_HEADER + "- {id: motion.fly, label: Fly, command: fly}\n")
    proc = subprocess.run([sys.executable, "-m", "vr_teleop_server.cli", "serve", "--port", "0", "--backend", "none",
                           "--menu-dir", str(tmp_path)], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert proc.returncode == 2
    assert "motion.yaml" in proc.stderr and "motion.fly" in proc.stderr and "unknown command 'fly'" in proc.stderr
    assert "listening" not in proc.stdout


def test_emotion_words_name_the_file_and_line_of_what_is_wrong(tmp_path):
    """A menu's words file (menu.words) stands for one file per language: the reference (English) one must be
    there and well formed at load; another language's must name the same emotions (checked at a switch)."""
    menu = tmp_path / "emotion.yaml"
    menu.write_text("menu: {id: e, label: E, words: words.txt}\n"
                    "items:\n- {id: e.sad, label: Sad, command: show_emotion, args: {name: sad}}\n")
    with pytest.raises(MenuError, match=r"emotion\.yaml: menu words: no emotion words for 'en': .*words\.en\.txt is "
                                        r"missing"):
        load_menus(tmp_path)
    (tmp_path / "words.en.txt").write_text("# what they say\nsad: Oh no.\nsurprise Wow!\n")
    with pytest.raises(MenuError, match=r"words\.en\.txt:3: write 'emotion: words' \(got 'surprise Wow!'\)"):
        load_menus(tmp_path)
    (tmp_path / "words.en.txt").write_text("sad: Oh no.\nsurprise: Wow!\n")
    assert language_words(tmp_path / "words.txt", "en") == {"sad": "Oh no.", "surprise": "Wow!"}
    load_menus(tmp_path)
    (tmp_path / "words.de.txt").write_text("sad: Oh nein.\nhappy: Juhu!\n")
    with pytest.raises(MenuError, match=r"words\.de\.txt has no words for surprise \(.*words\.en\.txt has\)"):
        language_words(tmp_path / "words.txt", "de")
    (tmp_path / "words.de.txt").write_text("sad: Oh nein.\nsurprise: Wow!\nhappy: Juhu!\n")
    with pytest.raises(MenuError, match=r"words\.de\.txt has words for happy, which .*words\.en\.txt does not"):
        language_words(tmp_path / "words.txt", "de")
