"""A media client for tests and the benches: the package's rosbridge client seen frame by frame, and an aiortc peer
that negotiates through /vr_teleop/media/offer, as a headset app would."""

from __future__ import annotations

import asyncio
import fractions
import itertools
import json
import time
from typing import Any

import av
import numpy as np
from aiortc import MediaStreamTrack, RTCConfiguration, RTCIceServer, RTCPeerConnection, RTCSessionDescription
from aiortc.mediastreams import MediaStreamError

from client_protocol import pose_frame
from testbed.waiting import Pace, until
from vr_teleop_server.client import Client, connect


class Rosbridge:
    """The package's rosbridge client (vr_teleop_server.client) with the frame-level view the media tests assert on:
    `call` answers with the `service_response` frame itself (or the `status` error that answered the call instead),
    not with its checked values; `subscribe` gives a queue of the topic's messages; `publish` advertises first."""

    def __init__(self, client: Client) -> None:
        self.client = client
        self.topics: dict[str, asyncio.Queue[dict[str, Any]]] = {}
        self._ids = itertools.count(1)
        self._waiting: dict[str, asyncio.Future[dict[str, Any]] | dict[str, Any] | None] = {}  # call id -> its answer
        client.on_status = self._on_status

    @classmethod
    async def open(cls, url: str, token: str | None = None) -> Rosbridge:
        bridge = cls(await connect(url))
        if token:
            await bridge.send({"op": "auth", "mac": token})
        return bridge

    @property
    def ws(self) -> Any:
        """The WebSocket underneath (to drop it without a closing handshake)."""
        return self.client.connection

    @property
    def statuses(self) -> list[dict[str, Any]]:
        return self.client.statuses

    async def send(self, frame: dict[str, Any]) -> None:
        await self.client.send(frame)

    def _on_status(self, msg: dict[str, Any]) -> None:
        """A status error with a waiting call's id answers that call, if it comes before the service_response."""
        call_id = str(msg.get("id"))
        if msg.get("level") != "error" or call_id not in self._waiting:
            return
        answer = self._waiting[call_id]
        if answer is None:  # the call is still being sent
            self._waiting[call_id] = {"op": "status", **msg}
        elif isinstance(answer, asyncio.Future) and not answer.done():
            answer.set_result({"op": "status", **msg})

    async def call(self, service: str, args: dict[str, Any], timeout: float = 30.0) -> dict[str, Any]:
        """The first answer to the call: its service_response frame, or the status error that came instead."""
        call_id = f"call:{next(self._ids)}"
        self._waiting[call_id] = None
        response = None
        try:
            response = await self.client.request(service, args, call_id=call_id)
            early = self._waiting[call_id]
            if isinstance(early, dict):
                return early
            self._waiting[call_id] = response
            async with asyncio.timeout(timeout):
                return await response
        finally:
            del self._waiting[call_id]
            if response is not None:
                response.cancel()

    async def subscribe(self, topic: str, type_name: str, **options: Any) -> asyncio.Queue[dict[str, Any]]:
        queue = self.topics[topic] = asyncio.Queue()
        await self.client.subscribe(topic, type_name, queue.put_nowait, **options)
        return queue

    async def publish(self, topic: str, type_name: str, msg: dict[str, Any]) -> None:
        await self.client.advertise(topic, type_name)
        await self.client.publish(topic, msg)

    async def close(self) -> None:
        await self.client.close()


class Tone(MediaStreamTrack):
    """A sine tone (or silence) at 48 kHz in 20 ms frames, paced in real time: the operator's microphone."""

    kind = "audio"

    def __init__(self, frequency: float = 440.0, amplitude: float = 0.5) -> None:
        super().__init__()
        self.frequency = frequency
        self.amplitude = amplitude
        self._pts = 0
        self._pace: Pace | None = None

    @property
    def frames_sent(self) -> int:
        """The 20 ms frames handed to the peer so far."""
        return self._pts // 960

    async def recv(self) -> av.AudioFrame:
        if self.readyState != "live":
            raise MediaStreamError
        if self._pace is None:
            self._pace = Pace(48000 / 960)  # 20 ms frames, the first at once
        else:
            await self._pace.tick()
        t = (self._pts + np.arange(960)) / 48000
        samples = (self.amplitude * 32767 * np.sin(2 * np.pi * self.frequency * t)).astype(np.int16)
        frame = av.AudioFrame.from_ndarray(samples.reshape(1, -1), format="s16", layout="mono")
        frame.sample_rate = 48000
        frame.pts = self._pts
        frame.time_base = fractions.Fraction(1, 48000)
        self._pts += 960
        return frame


def _rounded(value: Any) -> Any:
    """Floats to PoseSender.DECIMALS places: fewer bytes for the channel's congestion window."""
    if isinstance(value, float):
        return round(value, PoseSender.DECIMALS)
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    return value


class PoseSender:
    """The sending end of the poses data channel: never queues poses behind the channel. Each topic keeps only its
    newest frame until the channel can take it (`bufferedAmount` at most the low threshold), so a congested
    channel sends fewer, fresher poses instead of a growing backlog of stale ones. The threshold is 0 here: aiortc
    lowers bufferedAmount, and says so, on this loop as soon as SCTP takes a message, and anything buffered waits for
    the congestion window (measured on continent: a budget of one frame's poses raised the latency p50 by a third).
    The page's is about two binary pose frames (pose_channel.js): a browser's events come from its network thread,
    a task later each. The head pose (what the watchdog times and the camera follows) may take every other send;
    the other topics share the rest, the one that has waited longest first. A stalled channel (no head pose taken
    for STALL_S while more is buffered than it takes: its congestion window full, waiting out a retransmission
    timer) hands head poses back to the caller for the WebSocket until it takes one again, as the operator page's
    sender (web/operator/pose_channel.js) does; the page sends one binary pose frame per XR frame, as this sender
    with `compact`: it flushes once the caller's current run of sends is over (call_soon: the replay sends one XR
    frame's messages without yielding) or when a topic comes again (the next frame began), so a frame's head, controllers and Joy go as one message, half the packets
    of a head-first frame and a second for the rest (measured on continent: SCTP's window at 2% loss carries fewer
    than two packets per XR frame). JSON frames go compact, their floats to DECIMALS places (10 micrometres; a thousandth of a
    degree in a quaternion): about 80% of the bytes, and the channel's congestion window counts bytes."""

    HEAD = "/vr/head/pose"
    STALL_S = 0.1
    DECIMALS = 5

    def __init__(self, channel: Any, compact: bool = False) -> None:
        """`compact`: send what is pending as ONE binary pose frame (client_protocol/pose_frame.py) per XR frame."""
        self.channel = channel
        self.compact = compact
        self._pending_msgs: dict[str, dict[str, Any]] = {}  # compact: topic -> newest message
        self.head_taken_at: float | None = None  # when the channel last took a head pose
        self.failovers = 0  # head poses handed back for the WebSocket: the channel was stalled
        channel.bufferedAmountLowThreshold = 0
        self._pending: dict[str, str] = {}
        self.sent = 0
        self.head_sent = 0  # sends that carried a head pose
        self.replaced = 0  # frames overtaken by a newer one of their topic before the channel could take them
        self.sent_at: dict[str, list[tuple[float, str]]] = {}  # with `keep_sent`: topic -> (send time, frame)
        self.keep_sent = False
        self._head_last = False  # the last frame sent was a head pose
        self._flush_soon: asyncio.Handle | None = None  # compact: the end of the current XR frame's sends
        channel.on("bufferedamountlow", self._pump)

    @property
    def open(self) -> bool:
        return self.channel.readyState == "open"

    def send(self, topic: str, msg: dict[str, Any]) -> bool:
        """Takes the message (True), or hands a head pose back for the WebSocket (False: the channel is stalled)."""
        if topic == self.HEAD and self.stalled():
            self._pending.pop(self.HEAD, None)
            self.failovers += 1
            return False
        if self.compact and topic in self._pending:
            self._pump()  # a topic again: the next XR frame began (a late caller sends frames back to back)
        if topic in self._pending:
            self.replaced += 1
        if self.compact:
            self._pending_msgs[topic] = msg
        self._pending[topic] = json.dumps({"op": "publish", "topic": topic, "msg": _rounded(msg)},
                                          separators=(",", ":"))
        if not self.compact:
            self._pump()
        elif self._flush_soon is None:
            self._flush_soon = asyncio.get_running_loop().call_soon(self._end_of_frame)
        return True

    def _end_of_frame(self) -> None:
        self._flush_soon = None
        self._pump()

    def stalled(self) -> bool:
        now = time.monotonic()
        if self.head_taken_at is None:
            self.head_taken_at = now
        return (now - self.head_taken_at > self.STALL_S
                and self.channel.bufferedAmount > self.channel.bufferedAmountLowThreshold)

    def send_raw(self, data: str | bytes) -> None:
        """Anything at all, at once (bad-input tests)."""
        self.channel.send(data)

    def _pump(self) -> None:
        if self.compact:
            while self._pending and self.open and self.channel.bufferedAmount <= self.channel.bufferedAmountLowThreshold:
                data = _pose_frame(self._pending_msgs)
                if self.HEAD in self._pending:
                    self.head_taken_at = time.monotonic()
                    self.head_sent += 1
                self._pending.clear()
                self._pending_msgs.clear()
                self.channel.send(data)
                self.sent += 1
            return
        while self._pending and self.open and self.channel.bufferedAmount <= self.channel.bufferedAmountLowThreshold:
            others = (t for t in self._pending if t != self.HEAD)
            topic = self.HEAD if self.HEAD in self._pending and not self._head_last else next(others, self.HEAD)
            self._head_last = topic == self.HEAD
            frame = self._pending.pop(topic)
            self.channel.send(frame)
            self.sent += 1
            if topic == self.HEAD:
                self.head_taken_at = time.monotonic()
                self.head_sent += 1
            if self.keep_sent:
                self.sent_at.setdefault(topic, []).append((time.monotonic(), frame))

    async def wait_open(self, timeout: float = 30.0) -> None:
        if not await until(lambda: self.open, timeout):
            raise TimeoutError(f"the poses channel did not open (state {self.channel.readyState})")


def _pose_frame(msgs: dict[str, dict[str, Any]]) -> bytes:
    """The pending messages as one binary pose frame, stamped with the head pose's stamp (else the newest)."""
    def stamp(msg: dict[str, Any]) -> float:
        s = msg.get("header", {}).get("stamp", {})
        return s.get("secs", s.get("sec", 0)) + s.get("nsecs", s.get("nanosec", 0)) / 1e9

    head = msgs.get(PoseSender.HEAD)
    when = stamp(head) if head is not None else max(stamp(m) for m in msgs.values())
    poses, joys, unity = {}, {}, True
    for topic, msg in msgs.items():
        if topic in pose_frame.POSE_TOPICS:
            p, q = msg["pose"]["position"], msg["pose"]["orientation"]
            poses[topic] = (p["x"], p["y"], p["z"], q["x"], q["y"], q["z"], q["w"])
            unity = msg.get("header", {}).get("frame_id") == pose_frame.UNITY_FRAME
        elif topic in pose_frame.JOY_TOPICS:
            joys[topic] = ((list(msg["axes"]) + [0.0] * 4)[:4], (list(msg["buttons"]) + [0] * 4)[:4])
    return pose_frame.encode(when, poses, joys, unity=unity)


class MediaPeer:
    """An aiortc peer that receives the robot's video and audio, may send a microphone track, and with `poses`
    opens the poses data channel (unordered, no retransmissions) before the offer, as the operator page does."""

    def __init__(self, video: bool = True, audio: bool = True, mic: MediaStreamTrack | None = None,
                 video_codec: str | tuple[str, ...] | None = None, poses: bool = False,
                 ice_servers: list[RTCIceServer] | None = None, compact: bool = False) -> None:
        self.pc = RTCPeerConnection(RTCConfiguration(iceServers=ice_servers or []))
        self.poses: PoseSender | None = None
        if poses:
            self.poses = PoseSender(self.pc.createDataChannel("poses", ordered=False, maxRetransmits=0), compact)
        self.frames: list[tuple[float, Any]] = []  # (monotonic receive time, av.VideoFrame)
        self.audio_frames: list[tuple[float, np.ndarray]] = []
        self.keep_frames = 5
        self.video_count = 0
        self.first_rtp: int | None = None
        self.video_bytes = 0  # RTP received on the video transceiver
        self.video_payload_types: set[int] = set()  # of the RTP packets received on it (rtx too)
        self.light = False  # True: count video frames without decoding them (a viewer on another machine)
        self.video_arrivals: list[tuple[float, int]] = []  # light: (wall time, RTP timestamp) of each frame's end
        self._tasks: list[asyncio.Task[None]] = []
        if video:
            transceiver = self.pc.addTransceiver("video", direction="recvonly")
            if video_codec:  # one codec, or several in the order asked (the server sends the first it shares)
                from aiortc.rtcrtpsender import RTCRtpSender
                order = [video_codec] if isinstance(video_codec, str) else list(video_codec)
                codecs = RTCRtpSender.getCapabilities("video").codecs
                caps = [c for name in [*order, "rtx"] for c in codecs if c.mimeType.lower() == f"video/{name.lower()}"]
                transceiver.setCodecPreferences(caps)
        if audio:
            if mic is not None:
                self.pc.addTrack(mic)
            else:
                self.pc.addTransceiver("audio", direction="recvonly")

        @self.pc.on("track")
        def on_track(track: MediaStreamTrack) -> None:
            self._tasks.append(asyncio.ensure_future(self._consume(track)))

    async def _consume(self, track: MediaStreamTrack) -> None:
        try:
            while True:
                frame = await track.recv()
                now = time.monotonic()
                if track.kind == "video":
                    self.video_count += 1
                    self.frames.append((now, frame))
                    del self.frames[:-self.keep_frames]
                else:
                    self.audio_frames.append((now, frame.to_ndarray().reshape(-1)))
        except (MediaStreamError, asyncio.CancelledError):
            pass

    async def negotiate(self, ros: Rosbridge) -> dict[str, Any]:
        await self.pc.setLocalDescription(await self.pc.createOffer())
        reply = await ros.call("/vr_teleop/media/offer", {"sdp": self.pc.localDescription.sdp,
                                                          "type": self.pc.localDescription.type})
        values = reply.get("values")
        if reply.get("op") == "service_response" and reply.get("result") and values["success"]:
            await self.accept(values)
        return reply

    async def accept(self, values: dict[str, Any]) -> None:
        """Takes the server's answer (a successful /vr_teleop/media/offer response's values)."""
        await self.pc.setRemoteDescription(RTCSessionDescription(values["sdp"], values["type"]))
        self._watch_rtp()

    def _watch_rtp(self) -> None:
        """aiortc's decoded frames count pts from the first frame's RTP timestamp: keep that timestamp, so that
        a frame's RTP timestamp is first_rtp + pts (a browser sees it directly: rVFC's rtpTimestamp)."""
        for transceiver in self.pc.getTransceivers():
            if transceiver.kind != "video":
                continue
            receiver = transceiver.receiver
            original = receiver._handle_rtp_packet

            async def handle(packet, arrival_time_ms, original=original):
                if self.first_rtp is None:
                    self.first_rtp = packet.timestamp
                self.video_bytes += len(packet.payload) + 12  # with the RTP header
                self.video_payload_types.add(packet.payload_type)
                if self.light:  # count frames by their last packet; no jitter buffer, no decoding
                    self.video_count += packet.marker
                    if packet.marker:
                        self.video_arrivals.append((time.time(), packet.timestamp))
                    return
                await original(packet, arrival_time_ms)

            receiver._handle_rtp_packet = handle

    def rtp_timestamp(self, frame) -> int:
        return (self.first_rtp + frame.pts) & 0xFFFFFFFF

    async def wait_video(self, count: int, timeout: float = 30.0) -> None:
        target = self.video_count + count
        if not await until(lambda: self.video_count >= target, timeout):
            raise TimeoutError(f"{self.video_count} video frames, waited for {target}; connection "
                               f"{self.pc.connectionState}, ICE {self.pc.iceConnectionState}, "
                               f"{self.video_bytes} bytes of video RTP (payload types "
                               f"{sorted(self.video_payload_types)})")

    async def close(self) -> None:
        await self.pc.close()
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)


class LinkShaper:
    """A bottleneck link on the server's side of one peer connection: packets leave at `rate` bits a second
    through a drop-tail queue of `queue_s` seconds, as through a router. Install it on the server's loop; it
    wraps the DTLS transport's send (aiortc internals: tests and bench only)."""

    def __init__(self, pc: RTCPeerConnection, rate: float, queue_s: float = 0.5) -> None:
        self.rate = rate
        self.limit = int(rate * queue_s / 8)
        self.queued = 0
        self.dropped = 0
        self.sent = 0
        self._queue: asyncio.Queue[tuple[Any, bytes]] = asyncio.Queue()
        transports = {t.sender.transport for t in pc.getTransceivers()}
        for transport in transports:
            original = transport._send_rtp

            async def send(data: bytes, original=original) -> None:
                if self.queued + len(data) > self.limit:
                    self.dropped += 1
                    return
                self.queued += len(data)
                self._queue.put_nowait((original, data))

            transport._send_rtp = send
        self.task = asyncio.ensure_future(self._drain())

    async def _drain(self) -> None:
        link = Pace(self.rate / (8 * 1528), catch_up=False)  # full-size packets' rate; each ticks its own length
        while True:
            original, data = await self._queue.get()
            self.queued -= len(data)
            # The link's rate: a packet leaves its size's time (IP/UDP headers too) after the one before it, or at
            # once on an idle link.
            await link.tick(8 * (len(data) + 28) / self.rate)
            try:
                await original(data)
            except ConnectionError:
                return
            self.sent += 1

    def close(self) -> None:
        self.task.cancel()


class ChannelRoad:
    """The poses data channel as `vr-teleop replay`'s road (tools/replay.py PoseRoad): a peer connection offered
    over the replay's own rosbridge connection, with the channel and, with `video`, the camera (counted, not
    decoded: a viewer whose decoding is not this machine's business). With `carry` False the channel is opened but
    nothing is sent on it: the poses stay on the WebSocket beside the same media (a baseline with the same load)."""

    def __init__(self, video: bool = False, carry: bool = True, audio: bool = False, turn: str = "",
                 compact: bool = False) -> None:
        """`turn` ("udp", "tcp" or "tls"): ask the server for its ICE servers and reach the relay that way (aiortc
        uses one TURN URL, the first: the one of that transport goes first)."""
        self.video = video
        self.turn = turn
        self.compact = compact  # the poses as binary pose frames (client_protocol/pose_frame.py)
        self.carry = carry
        self.audio = audio  # also receive the robot's audio (decoded: the bench counts its gaps)
        self.peer: MediaPeer | None = None  # made in open(), on the replay's loop and in its thread's namespace
        self.video_frames: list[tuple[float, int]] = []  # (monotonic time, frames so far) at open and close

    async def open(self, call: Any) -> None:
        ice = None
        if self.turn:
            values = await call("/vr_teleop/media/ice_servers", {})
            scheme = {"udp": "turn:", "tcp": "turn:", "tls": "turns:"}[self.turn]
            transport = "transport=udp" if self.turn == "udp" else "transport=tcp"

            def rank(url: str) -> int:
                return 0 if url.startswith(scheme) and url.endswith(transport) else 1

            ice = [RTCIceServer(urls=sorted(e["urls"], key=rank), username=e["username"] or None,
                                credential=e["credential"] or None) for e in values.get("ice_servers", [])]
        self.peer = MediaPeer(video=self.video, audio=self.audio, poses=True, ice_servers=ice, compact=self.compact)
        self.peer.light = True
        pc = self.peer.pc
        await pc.setLocalDescription(await pc.createOffer())
        values = await call("/vr_teleop/media/offer", {"sdp": pc.localDescription.sdp, "type": "offer"})
        if not values.get("success"):
            raise RuntimeError(f"the server refused the offer: {values.get('message')}")
        await self.peer.accept(values)
        await self.peer.poses.wait_open()
        self.video_frames.append((time.monotonic(), self.peer.video_count))

    @property
    def sender(self) -> PoseSender:
        assert self.peer is not None and self.peer.poses is not None
        return self.peer.poses

    def send(self, topic: str, msg: dict[str, Any]) -> bool:
        if not self.carry or not self.sender.open:
            return False
        return self.sender.send(topic, msg)

    @property
    def video_fps(self) -> float | None:
        if len(self.video_frames) < 2:
            return None
        (t0, n0), (t1, n1) = self.video_frames[0], self.video_frames[-1]
        return (n1 - n0) / max(t1 - t0, 1e-9)

    async def close(self) -> None:
        if self.peer is not None:
            self.video_frames.append((time.monotonic(), self.peer.video_count))
            await self.peer.close()
