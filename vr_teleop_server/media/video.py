"""The head camera as WebRTC video, encoded once per frame for every peer that negotiated the same codec.

aiortc encodes per sender: five viewers would cost five encoders. Here one `VideoHub` per server runs one encoder
per codec (VP8, H.264) in an encoder process (encoder_process.py: no GIL shared with the event loop, a lower CPU
priority), fed by one thread that hands it each camera frame and waits for the bitstreams. A frame crosses as
its number in the stand-in's frame ring (shared memory the renderer draws into), so it is compressed once, and
the camera makes no JPEG for WebRTC viewers (`live_frames(jpeg=False)`); a camera that delivers JPEG anyway (a
real robot's) sends that; each peer's
`CameraTrack` hands the sender already-encoded packets, which aiortc only packetizes (`Encoder.pack`), so the
per-peer cost is the RTP packetization alone. If the encoder process dies, the next frame starts another. The hub
lives on the server's loop (it reads the robot); the tracks live with their peer connections on the media loop
(media_loop.py): the hub hands each encoded frame to each track's loop, and the tracks' calls back (attach, detach,
keyframe requests) come to the hub's.

Frames come from `Robot.live_frames()` only while some track is attached, newest first: while one frame is being
encoded, the camera's mailbox keeps only the newest one, so the encoder never works through a backlog. An
encoded frame waits for its sender in a queue of at most QUEUE_BOUND; a sender that falls further behind loses
its queue and waits for a keyframe (asked of the shared encoder), never delaying the other peers.

The shared encoder's bitrate is the lowest of its peers' bandwidth estimates (REMB, read from each sender's
RTCP), clamped to [MIN_BITRATE, MAX_BITRATE]: a congested peer lowers the quality for the peers that share its
codec rather than building a backlog (simulcast would separate them; not done).

RTP timestamps are send times: the server's clock (simclock) when the frame goes to its sender, in 90 kHz ticks
(plus aiortc's random origin per sender, which a track learns from its sender after the first frame: `RTCRtpSender`'s private
last RTP timestamp, so aiortc's version is bounded in pyproject). Stamping the render time instead made Chromium's
jitter buffer absorb the server's variable render-to-send delay (173 ms a frame against 45 on a loaded machine,
measured with getStats' jitterBufferDelay). Each frame's render time goes out with the telemetry, keyed by its
RTP timestamp.

Each frame's capture pose (the head's pose when it was taken) goes out on the peer's "capture_poses" data channel
when the client opened one, as the frame goes to its sender, keyed by the frame's RTP timestamp: a small JSON text
message per frame, ahead of the frame's packets. A data channel, not an RTP header extension: the browser hands a
page no header extension of its own (requestVideoFrameCallback reports the RTP timestamp, nothing else), and
aiortc's sender writes only the extensions it knows. The channel is unordered without retransmissions (a lost
pose is not worth a stall; the page keeps the previous one), and a pose is skipped while the channel's buffer
holds more than CAPTURE_POSE_BUFFER bytes (a congested association gets no backlog of stale poses).
"""

from __future__ import annotations

import asyncio
import contextlib
import fractions
import json
import logging
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import av
from aiortc import MediaStreamTrack, RTCRtpSender
from aiortc.mediastreams import MediaStreamError
from aiortc.rtp import RTCP_PSFB_APP, RTCP_PSFB_FIR, RTCP_PSFB_PLI, RtcpPsfbPacket, unpack_remb_fci

from robot_models.types import CameraFrame, CapturePose
from simclock import WALL, Clock
from worker_process.face_blur import Regions

from ..robot.interface import Robot
from .encoder_process import VIDEO_CLOCK_RATE, EncoderProcess, EncoderProcessError
from .media_loop import call_on

if TYPE_CHECKING:
    from ..features.face_blur import FaceBlur

log = logging.getLogger(__name__)

VIDEO_TIME_BASE = fractions.Fraction(1, VIDEO_CLOCK_RATE)
CODECS = ("VP8", "H264")
MIN_BITRATE = 150_000
MAX_BITRATE = 4_000_000
START_BITRATE = 800_000  # before the first estimate: what a 1 Mbit/s link carries
RESTART_DELAY_S = 1.0  # after the encoder process failed, the pump waits this long before it starts another
QUEUE_BOUND = 3  # encoded frames waiting for one sender (100 ms at 30 fps)
KEYFRAME_INTERVAL_S = 0.5  # keyframes asked for (PLI, joins) are granted at most this often: a PLI storm on a
# congested link would otherwise make every frame a large keyframe and keep the link congested
CAPTURE_POSE_BUFFER = 4096  # bytes waiting on the capture-poses channel past which a frame's pose is skipped


@dataclass(frozen=True)
class EncodedFrame:
    data: bytes
    pts: int  # render time in 90 kHz ticks since the hub's epoch (the encoder's clock)
    keyframe: bool
    render_wall: float  # the camera frame's wall-clock stamp (its render time)
    seq: int
    bitrate: int  # the encoder's target when it encoded this frame
    pose: CapturePose | None = None  # the head's pose when the frame was taken


class VideoHub:
    """One per server, and a second one for spectators under `serve --blur-faces` (`blur`: each frame's faces
    blurred by the encoder process): the camera pump and one shared encoder per codec, for every attached
    CameraTrack."""

    def __init__(self, robot: Robot, fps: float = 30.0, clock: Clock = WALL, blur: FaceBlur | None = None) -> None:
        self.robot = robot
        self.blur = blur
        self.fps = fps
        self.clock = clock  # the server's: frames are stamped on it, so pts and ages are too
        self._tracks: dict[str, set[CameraTrack]] = {codec: set() for codec in CODECS}
        self._keyframe: set[str] = set()
        self._keyframe_at: dict[str, float] = {}
        self._encoder: EncoderProcess | None = None  # used only in the executor's thread
        self._executor: ThreadPoolExecutor | None = None
        self._task: asyncio.Task[None] | None = None
        self.home: asyncio.AbstractEventLoop | None = None  # the server's loop, where the hub lives (start)
        self.epoch = clock.time()
        self.encoded = {codec: 0 for codec in CODECS}  # frames each codec's encoder produced
        self.encoder_bitrate = {codec: 0 for codec in CODECS}  # each encoder's target at its latest frame

    @property
    def encoder_pid(self) -> int | None:
        """The encoder process's pid while one runs (it starts with the first frame a peer watches)."""
        encoder = self._encoder
        return None if encoder is None else encoder.pid

    @property
    def watching(self) -> int:
        return sum(len(tracks) for tracks in self._tracks.values())

    def start(self) -> None:
        """On the server's loop: the hub's home, where tracks on the media loop send their calls."""
        self.home = asyncio.get_running_loop()

    def _at_home(self, fn: Any, *args: Any) -> None:
        if self.home is None:
            fn(*args)
        else:
            call_on(self.home, fn, *args)

    def attach(self, track: CameraTrack, codec: str) -> None:
        """From any loop: `track` receives the frames of `codec` from now on."""
        if codec not in self._tracks:
            raise ValueError(f"no encoder for {codec}; this server encodes {', '.join(CODECS)}")
        self._at_home(self._attach, track, codec)

    def _attach(self, track: CameraTrack, codec: str) -> None:
        if track.readyState != "live":
            return  # stopped before this call arrived
        self._tracks[codec].add(track)
        self._keyframe.add(codec)
        if self._task is None or self._task.done():
            if self._executor is None:
                self._executor = ThreadPoolExecutor(1, thread_name_prefix="media-video")
            self._task = asyncio.ensure_future(self._pump())

    def detach(self, track: CameraTrack) -> None:
        """From any loop."""
        self._at_home(self._detach, track)

    def _detach(self, track: CameraTrack) -> None:
        for tracks in self._tracks.values():
            tracks.discard(track)
        if self.watching == 0 and self._task is not None:
            self._task.cancel()  # its live_frames() gives the camera back
            self._task = None

    def request_keyframe(self, codec: str) -> None:
        """From any loop."""
        self._at_home(self._keyframe.add, codec)

    def _take_keyframe(self, codec: str) -> bool:
        if codec not in self._keyframe:
            return False
        now = self.clock.monotonic()
        if now - self._keyframe_at.get(codec, -1e9) < KEYFRAME_INTERVAL_S:
            return False  # kept asked: granted when the interval has passed
        self._keyframe.discard(codec)
        self._keyframe_at[codec] = now
        return True

    def _regrant_lost_keyframes(self, jobs: dict[str, tuple[bool, int]], out: dict[str, EncodedFrame]) -> None:
        """A keyframe granted for a frame that never came out (its ring slot already held a newer frame, or the
        codec failed) is not spent: the next frame is one. A peer waiting for its first keyframe would otherwise
        wait for another peer's request (CI saw one get no frame in 30 s)."""
        for codec, (keyframe, _) in jobs.items():
            if keyframe and not (codec in out and out[codec].keyframe):
                self._keyframe.add(codec)
                self._keyframe_at.pop(codec, None)

    def bitrate(self, codec: str) -> int:
        """The shared encoder's target: the lowest estimate of the peers that share it."""
        estimates = [t.estimate for t in self._tracks[codec] if t.estimate]
        target = min(estimates) if estimates else START_BITRATE
        return int(min(MAX_BITRATE, max(MIN_BITRATE, target)))

    async def _pump(self) -> None:
        loop = asyncio.get_running_loop()
        try:
            async with contextlib.aclosing(self.robot.live_frames(jpeg=False)) as frames:
                async for frame in frames:
                    jobs = {}
                    for codec, tracks in self._tracks.items():
                        if tracks:
                            jobs[codec] = (self._take_keyframe(codec), self.bitrate(codec))
                    if not jobs:
                        return
                    targets = {codec: tuple(self._tracks[codec]) for codec in jobs}
                    regions = None if self.blur is None else self.blur.plan(frame.seq).regions
                    try:
                        out = await loop.run_in_executor(self._executor, self._encode, frame, jobs, targets, regions)
                    except EncoderProcessError as exc:
                        log.warning("%s; another starts in %g s", exc, RESTART_DELAY_S)
                        self._keyframe.update(jobs)  # a new encoder starts with one anyway; the peers need it
                        await asyncio.sleep(RESTART_DELAY_S)
                        continue
                    self._regrant_lost_keyframes(jobs, out)
        except asyncio.CancelledError:
            raise
        except Exception:
            log.exception("the WebRTC camera pump failed; peers get no more video")

    def _encode(self, frame: CameraFrame, jobs: dict[str, tuple[bool, int]],
                targets: dict[str, tuple[CameraTrack, ...]] | None = None,
                regions: Regions | None = None) -> dict[str, EncodedFrame]:
        """Executor thread: the frame through the encoder process (started on first use, or again after it
        failed); blocks in a socket read, without the GIL, while the process encodes. Each encoded frame goes
        from here straight to its `targets`' loops (the tracks of its codec when the frame was taken), not by
        way of the server's loop: on a busy loop (JSON camera frames, poses) that hop was a wait of its own."""
        if self._encoder is not None and self._encoder.ring is not frame.ring:
            self._close_encoder()  # another camera (a new stand-in): another ring to map
        if self._encoder is None:
            self._encoder = EncoderProcess(self.fps, ring=frame.ring)
        pts = round((frame.stamp_wall - self.epoch) * VIDEO_CLOCK_RATE)
        try:
            results = self._encoder.encode(frame.seq if frame.ring is not None else frame.jpeg, pts, jobs, regions)
        except EncoderProcessError:
            self._close_encoder()
            raise
        out = {}
        for codec, result in results.items():
            if isinstance(result, str):
                log.error("%s", result)
                continue
            data, key, bitrate = result
            self.encoded[codec] += 1
            self.encoder_bitrate[codec] = bitrate
            out[codec] = item = EncodedFrame(data, pts, key, frame.stamp_wall, frame.seq, bitrate, frame.pose)
            for track in (targets or {}).get(codec, ()):
                track.deliver(item)  # to its own loop: the packets are made and sent there
        return out

    def _close_encoder(self) -> None:
        if self._encoder is not None:
            self._encoder.close()
            self._encoder = None

    async def close(self) -> None:
        for tracks in self._tracks.values():
            for track in list(tracks):
                call_on(track.loop, track.stop)
            tracks.clear()
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None
        if self._executor is not None:
            # In the executor's thread, after the frame it may still be encoding: the process is used only there.
            await asyncio.get_running_loop().run_in_executor(self._executor, self._close_encoder)
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None


class CameraTrack(MediaStreamTrack):
    """One peer's video track: hands its sender the hub's encoded frames (aiortc packs av.Packet without
    encoding). Counts what it sent and dropped, and knows its RTP to render-time mapping. It lives on the loop it
    was made on (the media loop, with its peer connection); the hub reaches it through `deliver`."""

    kind = "video"

    def __init__(self, hub: VideoHub) -> None:
        super().__init__()
        self.hub = hub
        self.loop = asyncio.get_running_loop()
        self.codec = ""
        self.sender: RTCRtpSender | None = None
        self.playout_delay = False  # whether its packets carry the playout-delay extension (playout_delay.py)
        self.estimate: int | None = None  # the peer's REMB, bits per second
        self._queue: deque[EncodedFrame] = deque()
        self._ready = asyncio.Event()
        self._need_keyframe = True
        self.frames_sent = 0
        self.frames_dropped = 0
        self.age_sum = 0.0  # render to send, over frames_sent
        self.rtp_origin: int | None = None
        self.last_pts = -1  # send time of the newest frame, 90 kHz ticks since the hub's epoch
        self.sent: deque[tuple[int, float]] = deque(maxlen=64)  # (pts, render time) of the newest frames sent
        self.pose_channel: Any = None  # the peer's "capture_poses" data channel, once the client opened one
        self.poses_sent = 0

    def bind(self, codec: str, sender: RTCRtpSender) -> None:
        """Start receiving the hub's frames for `codec`, and listen to the sender's RTCP (PLI, FIR, REMB)."""
        self.codec = codec
        self.sender = sender
        original = sender._handle_rtcp_packet

        async def handle_rtcp(packet: Any) -> None:
            if isinstance(packet, RtcpPsfbPacket):
                if packet.fmt in (RTCP_PSFB_PLI, RTCP_PSFB_FIR):  # deltas go on meanwhile: the peer decides
                    self.hub.request_keyframe(self.codec)
                elif packet.fmt == RTCP_PSFB_APP:
                    try:
                        bitrate, ssrcs = unpack_remb_fci(packet.fci)
                    except ValueError:
                        pass
                    else:
                        if sender._ssrc in ssrcs:
                            self.estimate = bitrate
            await original(packet)

        sender._handle_rtcp_packet = handle_rtcp
        self.hub.attach(self, codec)

    def deliver(self, item: EncodedFrame) -> None:
        """From any thread (the hub's encoding thread): `offer` on this track's own loop, in delivery order."""
        call_on(self.loop, self.offer, item)

    def offer(self, item: EncodedFrame) -> None:
        """On the track's loop: queue a frame, or drop this peer's queue when it has fallen behind."""
        if len(self._queue) >= QUEUE_BOUND:
            self.frames_dropped += len(self._queue)
            self._queue.clear()
            self._need_keyframe = True
            self.hub.request_keyframe(self.codec)
        if self._need_keyframe and not item.keyframe:
            self.frames_dropped += 1
            return
        self._need_keyframe = False
        self._queue.append(item)
        self._ready.set()

    async def recv(self) -> av.Packet:
        self._learn_rtp_origin()
        while not self._queue:
            if self.readyState != "live":
                raise MediaStreamError
            self._ready.clear()
            await self._ready.wait()
        if self.readyState != "live":
            raise MediaStreamError
        item = self._queue.popleft()
        packet = av.Packet(item.data)
        now = self.hub.clock.time()
        self.last_pts = max(self.last_pts + 1, round((now - self.hub.epoch) * VIDEO_CLOCK_RATE))
        packet.pts = self.last_pts
        packet.time_base = VIDEO_TIME_BASE
        self.sent.append((self.last_pts, item.render_wall))
        self._send_pose(item)
        self.frames_sent += 1
        self.age_sum += max(0.0, now - item.render_wall)
        return packet

    def _learn_rtp_origin(self) -> None:
        """The sender has sent every packet of the previous frame by now: its last RTP timestamp minus that frame's
        pts is the random origin aiortc gave this sender."""
        if self.rtp_origin is not None or self.last_pts < 0 or self.sender is None:
            return
        stamp = getattr(self.sender, "_RTCRtpSender__rtp_timestamp", None)
        if isinstance(stamp, int) and stamp:
            self.rtp_origin = (stamp - self.last_pts) & 0xFFFFFFFF

    def _send_pose(self, item: EncodedFrame) -> None:
        """The frame's capture pose on the capture-poses channel, keyed by its RTP timestamp (known from the
        second frame on), unless the channel is not open or is backed up."""
        channel, pose, rtp = self.pose_channel, item.pose, self.rtp_timestamp(self.last_pts)
        if channel is None or pose is None or rtp is None or channel.readyState != "open" \
                or channel.bufferedAmount > CAPTURE_POSE_BUFFER:
            return
        channel.send(json.dumps({"rtp_timestamp": rtp, "seq": item.seq, "head_yaw": round(pose.yaw, 4),
                                 "head_pitch": round(pose.pitch, 4), "stamp_gap": round(pose.gap_s, 4),
                                 "source": pose.source, "render_time": item.render_wall}))
        self.poses_sent += 1

    def rtp_timestamp(self, pts: int) -> int | None:
        return None if self.rtp_origin is None else (self.rtp_origin + pts) & 0xFFFFFFFF

    def recent(self, count: int) -> list[tuple[int, float]]:
        """(RTP timestamp, render time) of the newest `count` frames sent (as many as are kept), once known."""
        if self.rtp_origin is None or count <= 0:
            return []
        frames = list(self.sent)[-count:]
        return [((self.rtp_origin + pts) & 0xFFFFFFFF, render) for pts, render in frames]

    def stop(self) -> None:
        super().stop()
        self.hub.detach(self)
        self._ready.set()
