"""The operator's voice as a client sends it over rosbridge (AudioInfo, then AudioData), and what to check on the
other side: the pitch of what a robot's speaker got, and the WAV the server logged."""

from __future__ import annotations

import base64
import threading
import wave
from pathlib import Path

import numpy as np
import roslibpy

from client_protocol import names
from testbed.waiting import Pace


def tone(seconds: float, rate: int, channels: int, freq: float = 440.0, amplitude: float = 0.5) -> bytes:
    """S16LE, every channel the same sine."""
    t = np.arange(int(seconds * rate)) / rate
    mono = (np.sin(2 * np.pi * freq * t) * amplitude * 32767).astype("<i2")
    return np.repeat(mono, channels).tobytes()


class VoiceSender:
    """Sends PCM as a Unity client does: its AudioInfo once, then 100 ms AudioData chunks at real time (a thread;
    `done` is set after the last)."""

    def __init__(self, ros: roslibpy.Ros, pcm: bytes, rate: int, channels: int) -> None:
        self.info = roslibpy.Topic(ros, names.OPERATOR_AUDIO_INFO_TOPIC, "audio_common_msgs/AudioInfo")
        self.data = roslibpy.Topic(ros, names.OPERATOR_AUDIO_TOPIC, "audio_common_msgs/AudioData")
        self.pcm, self.rate, self.channels = pcm, rate, channels
        self.done = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> VoiceSender:
        self._thread.start()
        return self

    def _run(self) -> None:
        self.info.publish(roslibpy.Message({"channels": self.channels, "sample_rate": self.rate,
                                            "sample_format": "S16LE", "bitrate": self.rate * self.channels * 16,
                                            "coding_format": "pcm"}))
        step = int(0.1 * self.rate) * 2 * self.channels
        pace = Pace(10)  # a live microphone's pace: 100 ms chunks, the first at once
        for i, offset in enumerate(range(0, len(self.pcm), step)):
            if i:
                pace.wait()
            self.data.publish(roslibpy.Message({"data": base64.b64encode(self.pcm[offset:offset + step]).decode()}))
        self.done.set()


def pitch(samples: np.ndarray, rate: int) -> float:
    """The strongest frequency."""
    x = samples.astype(np.float32)
    spectrum = np.abs(np.fft.rfft(x * np.hanning(x.size)))
    return float(np.fft.rfftfreq(x.size, 1 / rate)[np.argmax(spectrum)])


def logged(audio_dir: Path) -> tuple[int, int, bytes]:
    """(rate, channels, frames) of the newest operator WAV, or (0, 0, b"") while there is none whole."""
    files = sorted(Path(audio_dir).glob("operator-*.wav"))
    if not files:
        return 0, 0, b""
    try:
        with wave.open(str(files[-1])) as w:  # readable while the server still writes it
            return w.getframerate(), w.getnchannels(), w.readframes(w.getnframes())
    except (EOFError, wave.Error):  # caught between the file's creation and its first header
        return 0, 0, b""
