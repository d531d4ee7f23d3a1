"""Audio both ways over WebRTC: the robot's audio out as an Opus track, the operator's voice in.

Out: `AudioMixer` (one per server) makes 20 ms frames of 48 kHz mono in real time while some peer listens, and
hands each to every `RobotAudioTrack` (aiortc's sender encodes it as Opus). What it mixes:
- the robot's speech: the PCM chunks on /vr_teleop/audio/robot (the same audio the JSON path carries), which
  the speaker sends 300 ms ahead of real time; they wait in a FIFO and play at real time;
- the classroom microphone: what the robot hears besides itself (`Robot.listen`, heard only while some peer
  listens). On the stand-in that is its simulated pupils (features/bystanders.py: their voices, synthesised with
  the server's TTS, reach the stand-in's microphone as voices a few metres away). The robot's
  own speech reaches its microphone too; on the stand-in it is the same signal at the same time as the speech
  feed, so it is not added a second time (it would only make the speech louder). A real robot's microphone is
  mixed as it comes: it arrives in bursts over the robot's rosbridge, so it starts once HEARD_START_S is buffered
  and is cut back to that when more than HEARD_MAX_S waits (latency stays bounded however the robot's clock and
  ours drift).

In: `OperatorVoice` reads one peer's incoming Opus track (aiortc decodes it), and for an operator or supervisor
(a spectator only listens) publishes each decoded frame on /vr_teleop/audio/operator as that client: the voice's one
road, where features/speech.py's OperatorVoiceIn plays it on the robot (`Robot.play_voice`) and logs it, exactly
as PCM a client sends over rosbridge.
"""

from __future__ import annotations

import asyncio
import fractions
import logging
import math
import time
from collections import deque
from collections.abc import Callable

import av
import numpy as np
from aiortc import MediaStreamTrack
from aiortc.mediastreams import MediaStreamError

from client_protocol import names

from ..core.bus import Bus, BusError, Published
from ..robot.interface import Robot, held_level
from .media_loop import call_on

log = logging.getLogger(__name__)

RATE = 48000
FRAME_S = 0.02
FRAME_SAMPLES = int(RATE * FRAME_S)
TIME_BASE = fractions.Fraction(1, RATE)
TRACK_QUEUE = 10  # 200 ms of frames waiting for one sender at most; older ones are dropped
HEARD_START_S = 0.06  # a real robot's microphone starts playing once this much is buffered...
HEARD_MAX_S = 0.5     # ...and is cut back to HEARD_START_S when more than this waits (bounded latency)
OPERATOR_CHUNK_S = FRAME_S  # operator audio published on the bus a decoded frame at a time: no wait added

# (pcm s16 bytes, sample rate, channels) of a rendered line


def to_mono48k(pcm: bytes, rate: int, channels: int) -> np.ndarray:
    """S16 PCM at any rate and channel count as float32 mono at 48 kHz (linear interpolation: speech only)."""
    samples = np.frombuffer(pcm[:len(pcm) - len(pcm) % (2 * channels)], "<i2").astype(np.float32)
    if channels > 1:
        samples = samples.reshape(-1, channels).mean(axis=1)
    if rate != RATE and samples.size:
        n = int(round(samples.size * RATE / rate))
        samples = np.interp(np.arange(n) * (rate / RATE), np.arange(samples.size), samples).astype(np.float32)
    return samples


class _Fifo:
    """Float samples waiting to be played."""

    def __init__(self) -> None:
        self._chunks: deque[np.ndarray] = deque()
        self.size = 0

    def push(self, samples: np.ndarray) -> None:
        if samples.size:
            self._chunks.append(samples)
            self.size += samples.size

    def pull(self, n: int) -> np.ndarray:
        out = np.zeros(n, np.float32)
        filled = 0
        while filled < n and self._chunks:
            chunk = self._chunks[0]
            take = min(n - filled, chunk.size)
            out[filled:filled + take] = chunk[:take]
            filled += take
            if take == chunk.size:
                self._chunks.popleft()
            else:
                self._chunks[0] = chunk[take:]
        self.size -= filled
        return out

    def drop(self, n: int) -> None:
        """Forget the oldest n samples."""
        self.pull(n)

    def clear(self) -> None:
        self._chunks.clear()
        self.size = 0


class AudioMixer:
    """The robot's audio for every peer: speech plus the classroom microphone, in real time, 20 ms frames."""

    def __init__(self, bus: Bus, *, robot: Robot | None = None) -> None:
        self.bus = bus
        self.robot = robot
        self._tracks: set[RobotAudioTrack] = set()
        self._speech = _Fifo()
        self._heard = _Fifo()  # the robot's own microphone
        self._heard_playing = False
        self._unlisten: Callable[[], None] | None = None
        self._speech_format = (22050, 1)
        self._task: asyncio.Task[None] | None = None
        self._tokens: list[tuple[str, int]] = []
        self.home: asyncio.AbstractEventLoop | None = None  # the server's loop, where the mixer lives (start)
        self.frames = 0

    def start(self) -> None:
        self.home = asyncio.get_running_loop()
        self.bus.declare_topic(names.ROBOT_AUDIO_TOPIC, "audio_common_msgs/AudioData", persistent=True)
        self.bus.declare_topic(names.ROBOT_AUDIO_INFO_TOPIC, "audio_common_msgs/AudioInfo", state=True, persistent=True)
        self._tokens = [
            (names.ROBOT_AUDIO_INFO_TOPIC, self.bus.subscribe("/vr_teleop_server/media", names.ROBOT_AUDIO_INFO_TOPIC, None,
                                                        self._on_info)),
            (names.ROBOT_AUDIO_TOPIC, self.bus.subscribe("/vr_teleop_server/media", names.ROBOT_AUDIO_TOPIC, None,
                                                   self._on_speech)),
        ]

    def _on_info(self, published: Published) -> None:
        info = published.data
        if info["sample_rate"] > 0 and info["channels"] in (1, 2):
            self._speech_format = (int(info["sample_rate"]), int(info["channels"]))

    def _on_speech(self, published: Published) -> None:
        if not self._tracks:
            return  # nobody listens: nothing accumulates
        rate, channels = self._speech_format
        self._speech.push(to_mono48k(bytes(published.data["data"]), rate, channels))

    def _on_heard(self, pcm: bytes, rate: int, channels: int) -> None:
        self._heard.push(to_mono48k(pcm, rate, channels))
        if self._heard.size > HEARD_MAX_S * RATE:
            self._heard.drop(self._heard.size - int(HEARD_START_S * RATE))

    def _pull_heard(self) -> np.ndarray:
        if not self._heard_playing and self._heard.size < HEARD_START_S * RATE:
            return np.zeros(FRAME_SAMPLES, np.float32)
        self._heard_playing = self._heard.size > FRAME_SAMPLES  # runs dry: buffer again before going on
        return self._heard.pull(FRAME_SAMPLES)

    def _at_home(self, fn: Callable[..., None], *args: object) -> None:
        if self.home is None:
            fn(*args)
        else:
            call_on(self.home, fn, *args)

    def attach(self, track: RobotAudioTrack) -> None:
        """From any loop (a track lives on the media loop)."""
        self._at_home(self._attach, track)

    def detach(self, track: RobotAudioTrack) -> None:
        """From any loop."""
        self._at_home(self._detach, track)

    def _attach(self, track: RobotAudioTrack) -> None:
        if track.readyState != "live":
            return
        self._tracks.add(track)
        if self._task is None or self._task.done():
            self._task = asyncio.ensure_future(self._run())
        if self.robot is not None and self._unlisten is None:
            self._unlisten = self.robot.listen(self._on_heard)

    def _detach(self, track: RobotAudioTrack) -> None:
        self._tracks.discard(track)
        if not self._tracks and self._unlisten is not None:
            self._unlisten()
            self._unlisten = None
        if not self._tracks and self._task is not None:
            self._task.cancel()
            self._task = None
            self._speech.clear()
            self._heard.clear()
            self._heard_playing = False

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        next_at = loop.time()
        pts = 0
        try:
            while True:
                now = loop.time()
                if now - next_at > 0.2:  # the loop stalled: real time goes on, no burst of frames
                    next_at = now
                mixed = self._speech.pull(FRAME_SAMPLES) + self._pull_heard()
                pcm = np.clip(mixed, -32768, 32767).astype(np.int16)
                frame = av.AudioFrame.from_ndarray(pcm.reshape(1, -1), format="s16", layout="mono")
                frame.sample_rate = RATE
                frame.pts = pts
                frame.time_base = TIME_BASE
                pts += FRAME_SAMPLES
                self.frames += 1
                for track in self._tracks:
                    track.deliver(frame)
                next_at += FRAME_S
                await asyncio.sleep(max(0.0, next_at - loop.time()))
        except asyncio.CancelledError:
            raise
        except Exception:
            log.exception("the robot audio mixer failed; peers get no more robot audio")

    async def close(self) -> None:
        for track in list(self._tracks):
            call_on(track.loop, track.stop)
            self._detach(track)  # the last one stops listening to the robot's microphone
        if self._task is not None:
            self._task.cancel()
        self._task = None
        for topic, token in self._tokens:
            self.bus.unsubscribe(topic, token)
        self._tokens = []


class RobotAudioTrack(MediaStreamTrack):
    """One peer's copy of the robot's audio (its sender encodes Opus), on the loop it was made on (the media
    loop's); the mixer reaches it through `deliver`."""

    kind = "audio"

    def __init__(self, mixer: AudioMixer) -> None:
        super().__init__()
        self.mixer = mixer
        self.loop = asyncio.get_running_loop()
        self._queue: deque[av.AudioFrame] = deque(maxlen=TRACK_QUEUE)
        self._ready = asyncio.Event()
        self.frames_sent = 0
        mixer.attach(self)

    def deliver(self, frame: av.AudioFrame) -> None:
        """From the mixer's loop."""
        call_on(self.loop, self.offer, frame)

    def offer(self, frame: av.AudioFrame) -> None:
        self._queue.append(frame)
        self._ready.set()

    async def recv(self) -> av.AudioFrame:
        while not self._queue:
            if self.readyState != "live":
                raise MediaStreamError
            self._ready.clear()
            await self._ready.wait()
        if self.readyState != "live":
            raise MediaStreamError
        self.frames_sent += 1
        return self._queue.popleft()

    def stop(self) -> None:
        super().stop()
        self.mixer.detach(self)
        self._ready.set()


def voice_level(samples: np.ndarray) -> float:
    """0..1 from RMS: -50 dBFS and below is 0, -10 dBFS and above is 1."""
    if not samples.size:
        return 0.0
    rms = float(np.sqrt(np.mean(np.square(samples.astype(np.float32) / 32768.0))))
    db = 20 * math.log10(max(rms, 1e-9))
    return min(1.0, max(0.0, (db + 50.0) / 40.0))


class OperatorVoice:
    """One peer's incoming microphone track, published as the client's operator audio (which the robot plays and
    the server logs). It reads (and aiortc decodes) the track on the track's loop, the media loop; each frame goes
    to `home`, the loop of the bus, to be published."""

    def __init__(self, bus: Bus, owner: str, track: MediaStreamTrack, may_speak: bool,
                 home: asyncio.AbstractEventLoop | None = None) -> None:
        self.bus = bus
        self.home = home
        self.owner = owner
        self.track = track
        self.may_speak = may_speak
        self._level = (0.0, 0.0)  # (level, monotonic time) of the newest frame
        self.frames = 0
        self._resampler = av.AudioResampler(format="s16", layout="mono", rate=RATE)
        self._pending: list[bytes] = []
        self._pending_samples = 0
        self._announced = False
        self.closed = False
        self.task = asyncio.ensure_future(self._run())

    async def _run(self) -> None:
        try:
            while True:
                frame = await self.track.recv()
                for out in self._resampler.resample(frame):
                    samples = out.to_ndarray().reshape(-1).astype(np.int16)
                    if self.home is None:
                        self._take(samples)
                    else:
                        call_on(self.home, self._take, samples)
        except (MediaStreamError, asyncio.CancelledError):
            pass
        except Exception:
            log.exception("%s: the operator's voice track failed", self.owner)
        finally:
            self._level = (0.0, 0.0)

    @property
    def level(self) -> float:
        """The voice's level now: 0 once no frame came for a while (a browser's push-to-talk released sends nothing
        at all): robot.interface.held_level."""
        return held_level(self._level, time.monotonic())

    def _take(self, samples: np.ndarray) -> None:
        if self.closed:
            return  # queued for home before the peer closed
        self.frames += 1
        self._level = (voice_level(samples), time.monotonic())
        if not self.may_speak:
            return  # a spectator's microphone is neither played nor logged
        self._pending.append(samples.tobytes())
        self._pending_samples += samples.size
        if self._pending_samples >= OPERATOR_CHUNK_S * RATE:
            self._publish()

    def _publish(self) -> None:
        data = b"".join(self._pending)
        self._pending, self._pending_samples = [], 0
        try:
            if not self._announced:
                self.bus.declare_topic(names.OPERATOR_AUDIO_INFO_TOPIC, "audio_common_msgs/AudioInfo", persistent=True)
                self.bus.declare_topic(names.OPERATOR_AUDIO_TOPIC, "audio_common_msgs/AudioData", persistent=True)
                self.bus.publish(names.OPERATOR_AUDIO_INFO_TOPIC, {
                    "channels": 1, "sample_rate": RATE, "sample_format": "S16LE", "bitrate": RATE * 16,
                    "coding_format": "pcm"}, sender=self.owner)
                self._announced = True
            self.bus.publish(names.OPERATOR_AUDIO_TOPIC, {"data": data}, sender=self.owner)
        except BusError:
            log.exception("the operator's voice could not be published")

    async def close(self) -> None:
        self.closed = True
        self.task.cancel()
        try:
            await self.task
        except asyncio.CancelledError:
            pass
