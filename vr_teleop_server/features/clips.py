"""Voices from home: recorded clips (a parent's "well done", a friend's greeting) that the robot plays.

The library is a directory (`serve --clips DIR`) of WAV, Ogg and MP3 files, listed on the latched /vr_teleop/clips
and in the speech menu. A supervisor adds one from the dashboard (/vr_teleop/clips/add: the file's bytes) or removes
one (/vr_teleop/clips/remove: the file is deleted, as a family's withdrawal asks); the teacher records one from the
headset's microphone (/vr_teleop/clips/record, twice: the operator voice road's chunks from that client are kept,
and not played on the robot, until the second call, which checks and keeps them as any added clip); anyone who may
run menu commands plays one (/vr_teleop/clips/play), through the Speaker (features/speech.py), which hands it to `Robot.play_voice` on
every backend with the robot's talking face, and which "stop talking" stops.

Every clip is decoded with PyAV (FFmpeg's decoders) and checked before it is kept: a clip that is not WAV, Ogg or
MP3, that cannot be decoded, that is longer than MAX_CLIP_S, louder than MAX_RMS_DBFS or clipped, or silent, is
refused with that reason. Files put in the directory by hand are checked the same way when the list is read; a bad
one is left out and logged.
"""

from __future__ import annotations

import asyncio
import io
import logging
import math
import re
import time
import wave
from dataclasses import dataclass
from pathlib import Path
from collections.abc import Awaitable
from typing import Any

import av
import numpy as np

from client_protocol import names
from client_protocol.vocabulary import Part

from ..core.bus import Bus, BusError
from ..core.ownership import Ownership
from .speech import OperatorVoiceIn, Speaker

log = logging.getLogger(__name__)

RATE = 16000  # clips are decoded to mono S16LE at this rate: what the robots' speakers take (robot/link.py)
MAX_CLIP_S = 60.0
MAX_CLIP_BYTES = 8 * 1024 * 1024
MAX_RMS_DBFS = -10.0  # a voice recorded at a sensible level sits around -20 dBFS; louder blares from the robot
MAX_CLIPPED = 0.005  # the share of samples at full scale above which a clip is distorted
SILENT_RMS_DBFS = -60.0
FORMATS = {"wav": ".wav", "ogg": ".ogg", "mp3": ".mp3"}  # FFmpeg's demuxer name -> the file's extension
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$")


class ClipRefused(ValueError):
    """A clip that cannot be kept or played; the message is the reason, for the person who sent it."""


@dataclass(frozen=True)
class Decoded:
    pcm: bytes  # mono S16LE at RATE
    duration_s: float
    extension: str


def decode(data: bytes, max_s: float = MAX_CLIP_S) -> Decoded:
    """The clip as mono 16 kHz PCM, or ClipRefused saying what is wrong with it."""
    if not data:
        raise ClipRefused("the clip is empty")
    if len(data) > MAX_CLIP_BYTES:
        raise ClipRefused(f"the file is {len(data) / 1e6:.1f} MB; at most {MAX_CLIP_BYTES / 1e6:.0f} MB")
    pcm = bytearray()
    try:
        with av.open(io.BytesIO(data), mode="r") as container:
            kinds = set(container.format.name.split(","))
            extension = next((FORMATS[k] for k in FORMATS if k in kinds), None)
            if extension is None:
                raise ClipRefused(f"the file is {container.format.long_name or container.format.name}, not WAV, "
                                  "Ogg or MP3")
            if not container.streams.audio:
                raise ClipRefused("the file holds no audio")
            resampler = av.AudioResampler(format="s16", layout="mono", rate=RATE)
            for frame in container.decode(container.streams.audio[0]):
                for out in resampler.resample(frame):
                    pcm += out.to_ndarray().tobytes()
                if len(pcm) > 2 * RATE * max_s:  # stop decoding what would be refused anyway
                    raise ClipRefused(f"the clip is longer than {max_s:g} s; at most {max_s:g} s")
            for out in resampler.resample(None):
                pcm += out.to_ndarray().tobytes()
    except ClipRefused:
        raise
    except (av.FFmpegError, ValueError, OSError) as exc:
        raise ClipRefused(f"the file cannot be decoded as WAV, Ogg or MP3 ({exc})") from None
    samples = np.frombuffer(bytes(pcm), "<i2").astype(np.float32) / 32768.0
    duration = samples.size / RATE
    if duration > max_s:
        raise ClipRefused(f"the clip is {duration:.1f} s long; at most {max_s:g} s")
    if samples.size == 0:
        raise ClipRefused("the file holds no audio")
    rms_db = 20 * math.log10(max(float(np.sqrt(np.mean(np.square(samples)))), 1e-9))
    clipped = float(np.mean(np.abs(samples) >= 0.99))
    if rms_db > MAX_RMS_DBFS or clipped > MAX_CLIPPED:
        raise ClipRefused(f"the clip is too loud ({rms_db:.1f} dBFS RMS, {100 * clipped:.1f}% of samples at full "
                          f"scale; at most {MAX_RMS_DBFS:g} dBFS and {100 * MAX_CLIPPED:g}%): lower its volume")
    if rms_db < SILENT_RMS_DBFS:
        raise ClipRefused(f"the clip is silent ({rms_db:.1f} dBFS RMS)")
    return Decoded(bytes(pcm), duration, extension)


def check_name(name: str) -> str:
    if not NAME.match(name):
        raise ClipRefused(f"clip name {name!r}: use 1 to 64 letters, digits, - and _ (starting with a letter or "
                          "digit)")
    return name


class ClipLibrary:
    """The clips in `directory` (None: no library, and adding is refused saying how to have one)."""

    def __init__(self, bus: Bus, speaker: Speaker, directory: Path | None,
                 voice: OperatorVoiceIn | None = None, owners: Ownership | None = None) -> None:
        self.bus = bus
        self.owners = owners  # a clip owns the voice and the face while it plays, for whoever played it
        self.speaker = speaker
        self.directory = directory
        self.voice = voice  # the operator voice road, recorded from
        self._recording: dict[str, tuple[int, int, bytearray]] = {}  # client -> (rate, channels, PCM so far)
        self.playing = ""  # the clip being played
        self._player: asyncio.Task[None] | None = None
        self.clips: dict[str, tuple[Path, float]] = {}  # name -> (file, seconds)
        self.changed: list[Any] = []  # called after the list changes (the menus list the clips)

    def start(self) -> None:
        self.bus.declare_topic(names.CLIPS_TOPIC, "vr_teleop_msgs/Clips", state=True, persistent=True)
        self.bus.provide(names.CLIP_ADD_SERVICE, "vr_teleop_msgs/AddClip", self._add)
        self.bus.provide(names.CLIP_REMOVE_SERVICE, "vr_teleop_msgs/ClipName", self._remove)
        self.bus.provide(names.CLIP_PLAY_SERVICE, "vr_teleop_msgs/ClipName", self._play)
        self.bus.provide(names.CLIP_RECORD_SERVICE, "std_srvs/Trigger", self._record)
        if self.voice is not None:
            self.voice.taps.append(self._tap)
        if self.directory is not None:
            self.directory.mkdir(parents=True, exist_ok=True)
            self.clips = self._scan()
        self._publish()

    async def stop(self) -> None:
        if self._player is not None:
            self._player.cancel()
        if self.voice is not None and self._tap in self.voice.taps:
            self.voice.taps.remove(self._tap)
        self._recording.clear()

    def _tap(self, sender: str, pcm: bytes, rate: int, channels: int) -> bool:
        entry = self._recording.get(sender)
        if entry is None:
            return False
        if (rate, channels) != entry[:2]:
            if entry[2]:  # a new format mid-clip: keep what came in the first one
                return True
            entry = self._recording[sender] = (rate, channels, entry[2])
        if len(entry[2]) < 2 * rate * channels * (MAX_CLIP_S + 1):  # beyond, the clip is refused as too long
            entry[2].extend(pcm)
        return True

    async def _record(self, _request: Any) -> dict[str, Any]:
        caller = Bus.caller()
        self._need_library()
        entry = self._recording.pop(caller, None)
        if entry is None:
            self._recording[caller] = (16000, 1, bytearray())
            return {"success": True, "message": "recording your voice (the robot does not play it): select again "
                                                "to stop and keep the clip"}
        rate, channels, pcm = entry
        buf = io.BytesIO()
        with wave.open(buf, "wb") as w:
            w.setnchannels(channels)
            w.setsampwidth(2)
            w.setframerate(rate)
            w.writeframes(bytes(pcm))
        name = f"recorded-{time.strftime('%Y%m%d-%H%M%S')}"
        if not pcm:
            raise BusError("no voice came while recording: hold to talk (or the left trigger) while it records")
        duration = await self.add(name, buf.getvalue())
        return {"success": True, "message": f"kept your {duration:.1f} s as clip {name!r}"}

    def names(self) -> list[str]:
        return sorted(self.clips)

    def _scan(self) -> dict[str, tuple[Path, float]]:
        assert self.directory is not None
        found = {}
        for path in sorted(self.directory.iterdir()):
            if path.suffix.lower() not in FORMATS.values() or not NAME.match(path.stem):
                continue
            try:
                found[path.stem] = (path, decode(path.read_bytes()).duration_s)
            except (ClipRefused, OSError) as exc:
                log.warning("clip %s left out: %s", path, exc)
        return found

    def _publish(self, listed: bool = True) -> None:
        """The library on its topic; `listed`: the list itself changed (the menus follow it; a clip starting or
        ending does not republish the menus, which would disturb a teacher navigating them)."""
        self.bus.publish(names.CLIPS_TOPIC, {
            "clips": [{"name": n, "duration": round(self.clips[n][1], 3)} for n in self.names()],
            "enabled": self.directory is not None, "playing": self.playing}, latch=True)
        if listed:
            for changed in tuple(self.changed):
                changed()

    def _need_library(self) -> Path:
        if self.directory is None:
            raise BusError("this server keeps no clips: start it with `serve --clips DIR`")
        return self.directory

    async def add(self, name: str, data: bytes) -> float:
        """Keep a clip; its duration. BusError with the reason when it is refused."""
        directory = self._need_library()
        try:
            check_name(name)
            if name in self.clips:
                raise ClipRefused(f"a clip named {name!r} exists: remove it first or choose another name")
            decoded = await asyncio.to_thread(decode, data)
        except ClipRefused as exc:
            raise BusError(f"clip {name!r} refused: {exc}") from None
        path = directory / f"{name}{decoded.extension}"
        await asyncio.to_thread(path.write_bytes, data)
        self.clips[name] = (path, decoded.duration_s)
        self._publish()
        return decoded.duration_s

    def _clip(self, name: str) -> Path:
        self._need_library()
        entry = self.clips.get(name)
        if entry is None:
            raise BusError(f"no clip named {name!r}; the clips are: {', '.join(self.names()) or 'none yet'}")
        return entry[0]

    async def play(self, name: str) -> float:
        """Starts playing a clip through the robot (a sentence or a clip playing stops); its duration. It plays on
        until its end or stop talking; `playing` (and /vr_teleop/clips) names it meanwhile."""
        path = self._clip(name)
        try:
            decoded = await asyncio.to_thread(lambda: decode(path.read_bytes()))
        except (ClipRefused, OSError) as exc:
            raise BusError(f"clip {name!r} cannot be played: {exc}") from None
        self.speaker.stop_speaking()
        player = self._player = asyncio.ensure_future(self._owned(Bus.caller(), self.speaker.play_clip(decoded.pcm,
                                                                                                    RATE)))
        self.playing = name
        self._publish(listed=False)
        player.add_done_callback(self._played)
        return decoded.duration_s

    async def _owned(self, by: str, playing: Awaitable[bool]) -> bool:
        if self.owners is None:
            return await playing
        with self.owners.commanding(by, (Part.VOICE, Part.FACE)):
            return await playing

    def _played(self, player: asyncio.Task[Any]) -> None:
        if not player.cancelled() and player.exception() is not None:
            log.error("a clip failed while playing: %s", player.exception())
        if player is self._player:
            self._player = None
            self.playing = ""
            self._publish(listed=False)

    async def _add(self, request: Any) -> dict[str, Any]:
        duration = await self.add(request.name, bytes(request.data))
        return {"success": True, "message": f"clip {request.name!r} added ({duration:.1f} s)", "duration": duration}

    async def _remove(self, request: Any) -> dict[str, Any]:
        path = self._clip(request.name)
        path.unlink(missing_ok=True)
        del self.clips[request.name]
        self._publish()
        return {"success": True, "message": f"clip {request.name!r} deleted"}

    async def _play(self, request: Any) -> dict[str, Any]:
        duration = await self.play(request.name)
        return {"success": True, "message": f"playing {request.name!r} ({duration:.1f} s)"}
