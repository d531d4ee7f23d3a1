"""The robot's languages over the real protocol: a switch from the speech menu (or /vr_teleop/speech/set_language)
is heard (what the headset hears is espeak-ng's voice for that language, not the English one, and the stand-in's
mouth moves), the speech menu's sentences become that language's list under the same ids, a missing list refuses
the switch naming the file, and the real robots get the language through their own interfaces (ROS 1's
/qt_robot/speech/config, the v3's TTS config)."""

from __future__ import annotations

import base64
import io
import json
import shutil
import subprocess
import threading
import wave

import numpy as np
import pytest
import roslibpy
from testbed.luxai_hub import FakeQtrobotV3
from testbed.ros1_rosbridge import Ros1QTrobot
from support import Watch, call, refused, wait_for

from client_protocol import names
from menus import PACKAGED_DIR, read_sentences

TEXT = "Gut gemacht!"


def espeak(voice: str, text: str) -> np.ndarray:
    """What espeak-ng itself renders with a voice, at the server's normal pitch and rate."""
    out = subprocess.run(["espeak-ng", "--stdout", "-v", voice, "-p", "50", "-s", "200", text],
                         capture_output=True, check=True).stdout
    with wave.open(io.BytesIO(out)) as w:
        return np.frombuffer(w.readframes(w.getnframes()), "<i2")


def select(ros: roslibpy.Ros, item: str, args: str = "") -> dict:
    return roslibpy.Service(ros, names.MENU_SELECT_SERVICE, "vr_teleop_msgs/MenuSelect").call(
        roslibpy.ServiceRequest({"id": item, "args": args}), timeout=30)


def speech_items(ros: roslibpy.Ros) -> dict[str, dict]:
    watch = Watch(ros, names.MENUS_TOPIC, "vr_teleop_msgs/Menus")
    try:
        assert wait_for(lambda: watch.latest, 30)
        return {i["id"]: i for i in watch.latest["items"] if i["menu"] == "speech"}
    finally:
        watch.close()


def connect(port: int) -> roslibpy.Ros:
    ros = roslibpy.Ros(host="127.0.0.1", port=port)
    ros.run(timeout=10)
    return ros


@pytest.fixture
def sim(servers):
    server = servers(backend="sim", bystander_interval=0)
    ros = connect(server.port)
    yield server, ros
    ros.close()


def heard_saying(server, ros: roslibpy.Ros, text: str) -> np.ndarray:
    """Says `text` through the speech service; what the headset's audio topic carried, and checks that the
    stand-in's mouth moved while it was said."""
    robot = server.server.robot
    audio = Watch(ros, names.ROBOT_AUDIO_TOPIC, "audio_common_msgs/AudioData")
    answers: list[dict] = []
    threading.Thread(target=lambda: answers.append(call(ros, names.SPEECH_SAY_SERVICE,
                                                        "qt_robot_interface/speech_say", {"message": text})),
                     daemon=True).start()
    try:
        assert wait_for(lambda: server.call(robot.standin.is_talking) or answers, 30)
        assert not answers, "the sentence ended before the mouth was seen moving"
        assert wait_for(lambda: answers, 30) and answers[0]["status"] is True, answers
        with audio.lock:
            return np.concatenate([np.frombuffer(base64.b64decode(m["data"]), "<i2") for m in audio.messages])
    finally:
        audio.close()


def test_a_switch_to_german_is_heard_and_the_sentences_follow(sim):
    server, ros = sim
    language = Watch(ros, names.SPEECH_LANGUAGE_TOPIC, "std_msgs/String")
    assert wait_for(lambda: language.latest.get("data") == "en", 30)
    english = heard_saying(server, ros, TEXT)
    assert np.array_equal(english, espeak("gmw/en", TEXT))

    reply = select(ros, "speech.language.de")
    assert reply == {"success": True, "message": "speaking Deutsch"}, reply
    assert wait_for(lambda: language.latest.get("data") == "de", 30)
    german = heard_saying(server, ros, TEXT)
    assert np.array_equal(german, espeak("gmw/de", TEXT))  # espeak-ng's German voice, not its English one
    assert german.size != english.size or not np.array_equal(german, english)

    items = speech_items(ros)
    well_done = items["speech.sentences.well_done"]  # the same id in every language (autonomy's rules use it)
    assert well_done["label"] == "Gut gemacht!" and json.loads(well_done["args"]) == {"text": "Gut gemacht!"}
    assert items["speech.sentences.hello_everyone_i_am_qt"]["label"] == "Hallo zusammen, ich bin QT."

    assert select(ros, "speech.language.lb")["message"] == "speaking Lëtzebuergesch"
    assert speech_items(ros)["speech.sentences.well_done"]["label"] == "Gutt gemaach!"
    assert np.array_equal(heard_saying(server, ros, "Gutt gemaach!"), espeak("gmw/lb", "Gutt gemaach!"))
    assert select(ros, "speech.language.fr")["message"] == "speaking Français"
    assert speech_items(ros)["speech.sentences.well_done"]["label"] == "Bravo !"

    refused(call(ros, names.SPEECH_LANGUAGE_SERVICE, "vr_teleop_msgs/SetLanguage", {"language": "tlh"}),
            r"unknown language 'tlh'; the robot speaks en, de, fr, lb")
    assert language.latest["data"] == "fr"


def test_a_missing_sentence_list_refuses_the_switch_naming_the_file(servers, tmp_path):
    menus = tmp_path / "menus"
    shutil.copytree(PACKAGED_DIR, menus)
    (menus / "sentences.fr.txt").unlink()
    server = servers(backend="sim", bystander_interval=0, menu_dir=menus)
    ros = connect(server.port)
    try:
        reply = refused(select(ros, "speech.language.fr"),
                        r"cannot switch to Français: no sentence list for 'fr': .*sentences\.fr\.txt is missing")
        assert str(menus / "sentences.fr.txt") in reply["message"]
        language = Watch(ros, names.SPEECH_LANGUAGE_TOPIC, "std_msgs/String")
        assert wait_for(lambda: language.latest.get("data") == "en", 30)  # nothing changed
        assert speech_items(ros)["speech.sentences.well_done"]["label"] == "Well done!"
        (menus / "sentences.fr.txt").write_text("Bravo !\n")
        english = len(read_sentences(menus / "sentences.en.txt"))
        refused(select(ros, "speech.language.fr"),
                rf"sentences\.fr\.txt holds 1 sentences and .*sentences\.en\.txt {english}:")
    finally:
        ros.close()


def menu_items(ros: roslibpy.Ros, menu: str) -> dict[str, dict]:
    watch = Watch(ros, names.MENUS_TOPIC, "vr_teleop_msgs/Menus")
    try:
        assert wait_for(lambda: watch.latest, 30)
        return {i["id"]: i for i in watch.latest["items"] if i["menu"] == menu}
    finally:
        watch.close()


def test_an_emotions_words_are_said_in_the_robots_language(sim):
    """The emotion menu's surprise says its words (emotion_words.<language>.txt) as the face shows it: English
    first, German after a switch, heard on the headset's audio topic as espeak-ng's voice of that language says them."""
    server, ros = sim
    surprise = menu_items(ros, "emotion")["emotion.surprise"]
    assert json.loads(surprise["args"]) == {"name": "surprise", "say": "Wow, look at that!"}
    assert "say" not in json.loads(menu_items(ros, "emotion")["emotion.happy"]["args"])  # happy has no words

    assert select(ros, "speech.language.de")["message"] == "speaking Deutsch"
    assert wait_for(lambda: json.loads(menu_items(ros, "emotion")["emotion.surprise"]["args"]).get("say")
                    == "Wow, schau mal!", 10)
    assert json.loads(menu_items(ros, "emotion")["emotion.all.surprise"]["args"])["say"] == "Wow, schau mal!"
    audio = Watch(ros, names.ROBOT_AUDIO_TOPIC, "audio_common_msgs/AudioData")
    try:
        reply = select(ros, "emotion.surprise")
        assert reply == {"success": True, "message": "showing surprise, saying 'Wow, schau mal!'"}, reply
        assert server.call(lambda: server.server.robot.standin.emotion) == "surprise"
        expected = espeak("gmw/de", "Wow, schau mal!")
        assert wait_for(lambda: sum(len(base64.b64decode(m["data"])) for m in audio.messages) >= 2 * expected.size,
                        30)
        with audio.lock:
            heard = np.concatenate([np.frombuffer(base64.b64decode(m["data"]), "<i2") for m in audio.messages])
        assert np.array_equal(heard, expected)  # German words in espeak-ng's German voice
    finally:
        audio.close()


def test_a_missing_emotion_word_refuses_the_switch_naming_the_file(servers, tmp_path):
    menus = tmp_path / "menus"
    shutil.copytree(PACKAGED_DIR, menus)
    german = menus / "emotion_words.de.txt"
    german.write_text("".join(line for line in german.read_text().splitlines(keepends=True)
                              if not line.startswith("surprise:")))
    server = servers(backend="sim", bystander_interval=0, menu_dir=menus)
    ros = connect(server.port)
    try:
        reply = refused(select(ros, "speech.language.de"),
                        r"cannot switch to Deutsch: .*emotion_words\.de\.txt has no words for surprise "
                        r"\(.*emotion_words\.en\.txt has\)")
        assert str(german) in reply["message"]
        assert json.loads(menu_items(ros, "emotion")["emotion.surprise"]["args"])["say"] == "Wow, look at that!"
    finally:
        ros.close()


@pytest.mark.slow
def test_the_ros1_robot_gets_the_language_through_its_speech_config(servers):
    robot = Ros1QTrobot(seconds_per_word=0.05)
    try:
        server = servers(backend="ros", robot_url=robot.url)
        ros = connect(server.port)
        try:
            assert select(ros, "speech.language.de")["success"]
            assert robot.speech_config[-1] == {"language": "de-DE", "pitch": 0, "speed": 0}, robot.speech_config
            assert select(ros, "speech.sentences.well_done")["success"]
            assert robot.services_called(names.SPEECH_SAY_SERVICE)[-1] == {"message": "Gut gemacht!"}
        finally:
            ros.close()
    finally:
        robot.stop()


@pytest.mark.slow
def test_the_v3_robot_gets_the_language_in_its_tts_config(servers):
    hub = FakeQtrobotV3().start()
    try:
        server = servers(backend="luxai", bystander_interval=0, robot_url=f"tcp://127.0.0.1:{hub.hub_port}",
                         camera_url=f"tcp://127.0.0.1:{hub.camera_port}")
        ros = connect(server.port)
        try:
            assert select(ros, "speech.language.fr")["success"]
            assert hub.tts_config.get("lang") == "fr-FR", hub.tts_config
            assert select(ros, "speech.sentences.well_done")["success"]
            assert hub.said[-1]["text"] == "Bravo !" and hub.said[-1]["lang"] == "fr-FR", hub.said
        finally:
            ros.close()
    finally:
        hub.stop()
