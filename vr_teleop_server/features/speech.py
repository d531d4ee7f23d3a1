"""Speech both ways: the robot's text-to-speech (espeak-ng) streamed to the headset, and the operator's
voice written to the session's audio log.

Robot speech. The text is rendered to a WAV by an espeak-ng process, waited for off the event loop. The robot
then "says" it for exactly the WAV's duration (the stand-in animates its talking face; a real QTrobot gets
/qt_robot/speech/say), while the same audio goes to the headset as raw PCM chunks of audio_common_msgs/AudioData
on /vr_teleop/audio/robot, paced in real time with a small lead, whose format is on the latched
/vr_teleop/audio/robot/info (audio_common_msgs/AudioInfo).

Every WAV the robot says is also kept in the audio log directory (robot-<time>-<text>.wav).

Languages. The robot speaks one of LANGUAGES at a time (/vr_teleop/speech/set_language): espeak-ng's voice for
that language renders what the headset hears (and the stand-in's speech), the real robot's own voice gets the
language through its own interface (configure_speech: /qt_robot/speech/config on ROS 1, the TTS config on v3), and
the menus follow (the sentence list of that language). The one in force is on the latched /vr_teleop/speech/language.

Clips. A recorded clip (features/clips.py) plays like a sentence: it stops what is being said, the robot shows its
talking face and gets the audio through `Robot.play_voice` at real-time pace (the stand-in's mouth follows its
level, the ROS 1 robot's speaker topic and the v3's media stream carry it), the headset hears it, and "stop talking"
stops it.

Operator voice. Chunks on /vr_teleop/audio/operator (PCM S16LE; the format a client declares on
/vr_teleop/audio/operator/info, else mono 16 kHz) are appended to one WAV per client in the audio log directory.
The WAV header is rewritten with every chunk, so a crash loses nothing already received.
"""

from __future__ import annotations

import asyncio
import io
import logging
import re
import subprocess
import tempfile
import time
import wave
from concurrent.futures import ThreadPoolExecutor
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from client_protocol import names
from client_protocol.vocabulary import Part

from ..core.bus import SERVER_NODE, Bus, BusError, Published
from ..core.ownership import Ownership
from ..robot.interface import Robot, SpeechResult, stopped_within

log = logging.getLogger(__name__)

CHUNK_S = 0.1  # audio per chunk sent to the headset
LEAD_S = 0.3  # how far ahead of real time chunks are sent, so the headset's player never starves
NORMAL_SPEED = 100  # LuxAI's speech speed is a percentage of normal
ESPEAK = "espeak-ng"
ESPEAK_RATE = 200  # words a minute at LuxAI's speed 100 (what the server used with pyttsx3; espeak-ng's own is 175)
ESPEAK_PITCH = 50  # espeak-ng's normal pitch (0..99)
# espeak-ng's default voice (British English), named by its file: a voice named by language costs a search of every
# voice file, about 50 ms a render
ESPEAK_VOICE = "gmw/en"
ESPEAK_TIMEOUT_S = 30.0  # espeak-ng renders far faster than real time: a render this long is a hung process
CLIP_CHUNK_S = 0.04  # a clip goes to the robot in pieces this long, at real-time pace


@dataclass(frozen=True)
class Language:
    code: str  # what clients send and the sentence lists are named by (sentences.<code>.txt)
    name: str  # in the language itself, as a menu shows it
    espeak: str  # espeak-ng's voice file (`espeak-ng --voices`): a file, not a language, costs no voice search
    robot: str  # the locale a QTrobot's own TTS takes (/qt_robot/speech/config, tts set_config's lang)


LANGUAGES: dict[str, Language] = {lang.code: lang for lang in (
    Language("en", "English", "gmw/en", "en-US"),
    Language("de", "Deutsch", "gmw/de", "de-DE"),
    Language("fr", "Français", "roa/fr", "fr-FR"),
    Language("lb", "Lëtzebuergesch", "gmw/lb", "lb-LU"),
)}
DEFAULT_LANGUAGE = "en"

# a row of `espeak-ng --voices`: Pty, Language, Age/Gender, VoiceName, File, Other Languages
VOICE_ROW = re.compile(r"\s*\d+\s+(?P<language>\S+)\s+\S+\s+\S+\s+(?P<file>\S+)")


@dataclass(frozen=True)
class Wav:
    pcm: bytes
    sample_rate: int
    channels: int
    sample_width: int

    @property
    def duration_s(self) -> float:
        return len(self.pcm) / (self.sample_rate * self.channels * self.sample_width)

    @classmethod
    def parse(cls, data: bytes) -> Wav:
        with wave.open(io.BytesIO(data)) as w:
            return cls(w.readframes(w.getnframes()), w.getframerate(), w.getnchannels(), w.getsampwidth())


class TextToSpeech:
    """espeak-ng, one process per render, its voice, pitch and rate on that process's command line.

    Nothing is shared between instances: espeak-ng's library keeps one set of parameters per process, and pyttsx3
    (used here before) handed a process one engine whose espeak driver returned from runAndWait 10 ms after
    starting a file, written or not (pyttsx3 issue #219): on a busy machine renders came back empty or with
    another server's audio. Voice, pitch and speed follow LuxAI's /qt_robot/speech/config."""

    def __init__(self) -> None:
        self._executor = ThreadPoolExecutor(1, thread_name_prefix="tts")
        self._voices: list[tuple[str, str]] | None = None  # (voice file, language), as espeak-ng lists them
        self._voice = ESPEAK_VOICE  # a voice file, as _voice_for finds them
        self._pitch = ESPEAK_PITCH
        self._rate = ESPEAK_RATE

    def _espeak(self, *args: str, text: str = "") -> bytes:
        try:
            done = subprocess.run([ESPEAK, *args], input=text.encode(), capture_output=True,
                                  timeout=ESPEAK_TIMEOUT_S, check=False)
        except FileNotFoundError:
            raise RuntimeError("espeak-ng is not installed (scripts/install-system-packages.sh)") from None
        except subprocess.TimeoutExpired:
            raise RuntimeError(f"espeak-ng took over {ESPEAK_TIMEOUT_S:g} s") from None
        if done.returncode != 0:
            raise RuntimeError(f"espeak-ng failed ({done.returncode}): {done.stderr.decode(errors='replace').strip()}")
        return done.stdout

    def _voice_list(self) -> list[tuple[str, str]]:
        if self._voices is None:
            rows = (VOICE_ROW.match(line) for line in self._espeak("--voices").decode().splitlines()[1:])
            self._voices = [(m["file"].lower(), m["language"].lower()) for m in rows if m]
        return self._voices

    def _voice_for(self, language: str) -> str:
        wanted = language.strip().lower().replace("_", "-")
        voices = self._voice_list()
        for file, lang in voices:
            if wanted in (file, lang) or file.endswith("/" + wanted):
                return file
        for file, lang in voices:  # "en" also matches "en-gb"
            if lang.startswith(wanted + "-"):
                return file
        raise ValueError(f"no voice for language {language!r}; espeak-ng offers e.g. en, en-gb, en-us, fr, de, nl")

    def _configure(self, language: str, pitch: int, speed: int) -> None:
        if language:
            self._voice = self._voice_for(language)
        if pitch:
            self._pitch = pitch
        if speed:
            self._rate = max(40, round(ESPEAK_RATE * speed / NORMAL_SPEED))

    def _render(self, text: str) -> Wav:
        out = self._espeak("--stdin", "--stdout", "-v", self._voice, "-p", str(self._pitch), "-s", str(self._rate),
                           text=text)
        try:
            return Wav.parse(out)  # a streamed WAV: its header gives no length, and wave reads the frames there are
        except (wave.Error, EOFError) as exc:
            raise RuntimeError(f"espeak-ng's output is not a WAV ({exc or 'empty'})") from None

    async def configure(self, language: str = "", pitch: int = 0, speed: int = 0) -> None:
        await asyncio.get_running_loop().run_in_executor(self._executor, self._configure, language, pitch, speed)

    async def render(self, text: str) -> Wav:
        """The text as a WAV; RuntimeError if espeak-ng fails."""
        return await asyncio.get_running_loop().run_in_executor(self._executor, self._render, text)

    def close(self) -> None:
        self._executor.shutdown(wait=False, cancel_futures=True)


class Speaker:
    """What /qt_robot/speech/say does here: render, let the robot talk for the WAV's length, stream the audio."""

    def __init__(self, bus: Bus, robot: Robot, audio_dir: Path, tts: TextToSpeech | None = None) -> None:
        self.bus = bus
        self.robot = robot
        self.audio_dir = audio_dir
        self.tts = tts or TextToSpeech()
        self.last_wav_path: Path | None = None
        self._stream: asyncio.Task[None] | None = None
        self._info: tuple[int, int, int] | None = None
        self.language = DEFAULT_LANGUAGE
        # each is called with a language code before the switch: one raising ValueError refuses it (a menu whose
        # sentence list for that language is missing says which file)
        self.language_checks: list[Callable[[str], None]] = []
        self.language_changed: list[Callable[[], None]] = []  # after a switch (the menus publish their sentences)
        self._clip_stop: asyncio.Event | None = None

    def start(self) -> None:
        self.bus.declare_topic(names.ROBOT_AUDIO_TOPIC, "audio_common_msgs/AudioData", persistent=True)
        self.bus.declare_topic(names.ROBOT_AUDIO_INFO_TOPIC, "audio_common_msgs/AudioInfo", state=True,
                               persistent=True)
        self.bus.declare_topic(names.SPEECH_LANGUAGE_TOPIC, "std_msgs/String", state=True, persistent=True)
        self.bus.provide(names.SPEECH_LANGUAGE_SERVICE, "vr_teleop_msgs/SetLanguage", self._set_language_service)
        self.bus.publish(names.SPEECH_LANGUAGE_TOPIC, {"data": self.language}, latch=True)

    async def _set_language_service(self, request: Any) -> dict[str, Any]:
        return {"success": True, "message": await self.set_language(request.language)}

    async def set_language(self, code: str) -> str:
        """Switch the robot's language: its own voice first (a robot that refuses it leaves everything as it was),
        then the server's voice, then the menus. BusError says why not."""
        code = code.strip().lower()
        language = LANGUAGES.get(code)
        if language is None:
            raise BusError(f"unknown language {code!r}; the robot speaks {', '.join(LANGUAGES)} "
                           f"({', '.join(lang.name for lang in LANGUAGES.values())})")
        for check in self.language_checks:
            try:
                check(code)
            except ValueError as exc:
                raise BusError(f"cannot switch to {language.name}: {exc}") from None
        await self.robot.configure_speech(language.robot, 0, 0)
        try:
            await self.tts.configure(language.espeak)
        except ValueError as exc:
            raise BusError(str(exc)) from None
        self.language = code
        self.bus.publish(names.SPEECH_LANGUAGE_TOPIC, {"data": code}, latch=True)
        for changed in tuple(self.language_changed):
            changed()
        return f"speaking {language.name}"

    async def say(self, text: str) -> SpeechResult:
        if not text.strip():
            raise BusError("nothing to say: the message is empty")
        try:
            wav = await self.tts.render(text)
        except RuntimeError as exc:
            raise BusError(f"text-to-speech failed: {exc}") from None
        self.stop_speaking()
        self._log(text, wav)
        self._publish_info(wav)
        stream = self._stream = asyncio.ensure_future(self._stream_audio(wav))
        completed = False
        try:
            result = await self.robot.say(text, duration_s=wav.duration_s)
            completed = result.completed
        finally:
            if not completed:  # stopped or cancelled: the headset's audio stops too
                stream.cancel()
        return result

    def stop_speaking(self) -> None:
        self.robot.stop_speech()
        if self._clip_stop is not None:
            self._clip_stop.set()
            self._clip_stop = None
        if self._stream is not None:
            self._stream.cancel()
            self._stream = None

    async def play_clip(self, pcm: bytes, sample_rate: int) -> bool:
        """Play a clip (mono S16LE) through the robot with its talking face; True if it played to its end, False
        when stop_speaking() (or a new sentence or clip) cut it short."""
        self.stop_speaking()
        stop = self._clip_stop = asyncio.Event()
        wav = Wav(pcm, sample_rate, 1, 2)
        self._publish_info(wav)
        self._show("talking")
        stream = self._stream = asyncio.ensure_future(self._stream_audio(wav))
        step = int(CLIP_CHUNK_S * sample_rate) * 2
        loop = asyncio.get_running_loop()
        start = loop.time()
        try:
            for i, offset in enumerate(range(0, len(pcm), step)):
                delay = start + i * CLIP_CHUNK_S - loop.time()
                if delay > 0 and await stopped_within(stop, delay) or stop.is_set():
                    return False
                self.robot.play_voice(pcm[offset:offset + step], sample_rate, 1)
            end = start + len(pcm) / (2 * sample_rate) - loop.time()
            return not (end > 0 and await stopped_within(stop, end)) and not stop.is_set()
        finally:
            superseded = self._clip_stop is not None and self._clip_stop is not stop  # a newer clip's face stays
            if self._clip_stop is stop:
                self._clip_stop = None
            if stop.is_set():
                stream.cancel()
            if not superseded:
                self._show("neutral")

    def _show(self, emotion: str) -> None:
        """The face a clip plays with; a robot that cannot show it now (lost) still plays the clip."""
        try:
            self.robot.show_emotion(emotion)
        except Exception as exc:  # noqa: BLE001 -- the audio matters more than the face
            log.warning("the robot could not show %s while a clip played: %s", emotion, exc)

    async def configure(self, language: str, pitch: int, speed: int) -> None:
        """The server's voice (what the headset hears) and the robot's own, if it has one, change together."""
        try:
            await self.tts.configure(language, pitch, speed)
        except ValueError as exc:
            raise BusError(str(exc)) from None
        await self.robot.configure_speech(language, pitch, speed)

    def _log(self, text: str, wav: Wav) -> None:
        """Keeps what the robot said in the audio log, beside the operator's voice."""
        self.audio_dir.mkdir(parents=True, exist_ok=True)
        slug = re.sub(r"[^A-Za-z0-9]+", "_", text).strip("_")[:30]
        path = self.audio_dir / f"robot-{time.strftime('%Y%m%d-%H%M%S')}-{time.monotonic_ns() % 10**6:06d}-{slug}.wav"
        with wave.open(str(path), "wb") as w:
            w.setnchannels(wav.channels)
            w.setsampwidth(wav.sample_width)
            w.setframerate(wav.sample_rate)
            w.writeframes(wav.pcm)
        self.last_wav_path = path

    def _publish_info(self, wav: Wav) -> None:
        info = (wav.sample_rate, wav.channels, wav.sample_width)
        if info == self._info:
            return
        self._info = info
        self.bus.publish(names.ROBOT_AUDIO_INFO_TOPIC, {
            "channels": wav.channels, "sample_rate": wav.sample_rate, "sample_format": f"S{8 * wav.sample_width}LE",
            "bitrate": wav.sample_rate * wav.channels * wav.sample_width * 8, "coding_format": "pcm"})

    async def _stream_audio(self, wav: Wav) -> None:
        step = int(CHUNK_S * wav.sample_rate) * wav.channels * wav.sample_width
        loop = asyncio.get_running_loop()
        start = loop.time()
        for i, offset in enumerate(range(0, len(wav.pcm), step)):
            due = start + i * CHUNK_S - LEAD_S
            delay = due - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            self.bus.publish(names.ROBOT_AUDIO_TOPIC, {"data": wav.pcm[offset:offset + step]})

    async def stop(self) -> None:
        self.stop_speaking()
        self.tts.close()


def default_audio_dir() -> Path:
    return Path(tempfile.gettempdir()) / "vr-teleop-audio"


class OperatorVoiceIn:
    """The one road of the operator's voice: every chunk on /vr_teleop/audio/operator, whatever carried it (a
    client's AudioData over rosbridge, at the rate and channel count its AudioInfo declares; WebRTC, which
    media/audio.py publishes there as the client; a replayed recording), is played on the robot
    (`Robot.play_voice`) and logged, one WAV per client in `directory`."""

    def __init__(self, bus: Bus, robot: Robot, directory: Path, default_rate: int = 16000,
                 owners: Ownership | None = None) -> None:
        self.bus = bus
        self.robot = robot
        self.owners = owners or Ownership(robot.model.parts)  # the operator's voice owns the robot's while it talks
        self.directory = directory
        self.default_rate = default_rate
        self._formats: dict[str, tuple[int, int]] = {}  # sender -> (sample rate, channels)
        self._files: dict[str, tuple[wave.Wave_write, Path]] = {}
        # each takes (sender, pcm, rate, channels) and returns True when it keeps the chunk from the robot (a clip
        # being recorded from that voice)
        self.taps: list[Callable[[str, bytes, int, int], bool]] = []

    def start(self) -> None:
        self.bus.declare_topic(names.OPERATOR_AUDIO_TOPIC, "audio_common_msgs/AudioData", persistent=True)
        self.bus.declare_topic(names.OPERATOR_AUDIO_INFO_TOPIC, "audio_common_msgs/AudioInfo", persistent=True)
        self.bus.subscribe(SERVER_NODE, names.OPERATOR_AUDIO_TOPIC, None, self._on_chunk)
        self.bus.subscribe(SERVER_NODE, names.OPERATOR_AUDIO_INFO_TOPIC, None, self._on_info)
        self.bus.owner_dropped.append(self._close_for)

    def _on_info(self, published: Published) -> None:
        info = published.data
        sample_format, channels, rate = info["sample_format"], info["channels"], info["sample_rate"]
        if sample_format.upper() not in ("S16LE", "") or channels not in (1, 2) or rate <= 0:
            self.bus.report(published.sender, "error", f"{published.topic}: only PCM S16LE, 1 or 2 channels, is "
                            f"logged (got {sample_format or '?'}, {channels} channel(s), {rate} Hz)")
            return
        if published.sender in self._files:
            self._close_for(published.sender)  # a new format starts a new file
        self._formats[published.sender] = (rate, channels)

    def _on_chunk(self, published: Published) -> None:
        data: bytes = bytes(published.data["data"])
        rate, channels = self._formats.get(published.sender, (self.default_rate, 1))
        if len(data) % (2 * channels):
            self.bus.report(published.sender, "error", f"{published.topic}: a chunk of {len(data)} bytes is not a "
                            f"whole number of {channels}-channel 16-bit samples")
            return
        entry = self._files.get(published.sender)
        if entry is None:
            self.directory.mkdir(parents=True, exist_ok=True)
            safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", published.sender).strip("_")
            path = self.directory / f"operator-{time.strftime('%Y%m%d-%H%M%S')}-{safe}.wav"
            w = wave.open(str(path), "wb")
            w.setnchannels(channels)
            w.setsampwidth(2)
            w.setframerate(rate)
            entry = self._files[published.sender] = (w, path)
            log.info("operator audio from %s goes to %s", published.sender, path)
        entry[0].writeframes(data)  # rewrites the header: the file is whole after every chunk
        if any([tap(published.sender, data, rate, channels) for tap in self.taps]):
            return
        try:
            with self.owners.commanding(published.sender, (Part.VOICE,)):
                self.robot.play_voice(data, rate, channels)
        except Exception:  # the log above is kept whatever the robot does with it
            log.exception("the robot could not play the operator's voice")

    def _close_for(self, owner: str) -> None:
        entry = self._files.pop(owner, None)
        self._formats.pop(owner, None)
        if entry is not None:
            entry[0].close()

    async def stop(self) -> None:
        for owner in list(self._files):
            self._close_for(owner)
        if self._close_for in self.bus.owner_dropped:
            self.bus.owner_dropped.remove(self._close_for)
