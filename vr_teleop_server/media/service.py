"""WebRTC beside the rosbridge stream: the offer service, one peer connection per client, the clock service and
the link telemetry.

Signalling rides the rosbridge connection the client already has: it calls /vr_teleop/media/offer with its
offer and gets the server's answer (aiortc gathers its candidates before answering: no trickle). The peer
connection belongs to the calling session and is closed when that WebSocket closes (the bus's owner_dropped), or
when ICE or DTLS fail (a peer that vanished: aioice's consent checks notice within about 30 s). Every refusal is
answered inside the response (success false, message naming the problem and the fix).

A "poses" data channel in the offer carries the operator's poses and Joy into the client's own session (poses.py);
an offer with one is not refused for a media section without a common codec: that section alone is rejected.

/vr_teleop/media/ice_servers hands a client the ICE servers (STUN, TURN with fresh time-limited credentials,
turn.py) to build its peer connection with; the server's own peer uses the same. Its responses are confidential
(the session keeps them out of recordings).

The peer connections run on a media loop of their own, in a thread (media_loop.py): aiortc's per-packet work
never waits in the queue of the loop that carries the poses. This service lives on the server's loop (the bus's,
the sessions'): it answers the offer there and hands the negotiation to the media loop; what the peers receive
comes back (call_soon_threadsafe, in order): data-channel messages into the client's session, the operator's voice
to the robot and the bus, a failed connection to be closed.

Access is the camera topic's, for the offer and the ICE servers: a client that may not subscribe to the head camera
gets no media. An operator's or
supervisor's microphone is played on the robot and logged; a spectator's is ignored.
"""

from __future__ import annotations

import asyncio
import logging
import re
import time
from collections import deque
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from aiortc import RTCConfiguration, RTCPeerConnection, RTCSessionDescription
from aiortc import sdp as aiortc_sdp
from aiortc.rtcrtpsender import RTCRtpSender
from aiortc.exceptions import InvalidStateError, OperationError

from client_protocol import names

from ..core.access import AccessDenied, AccessPolicy, Role
from ..core.bus import SERVER_NODE, Bus, Published
from ..robot.interface import Robot
from . import link_quality, playout_delay
from .audio import RATE as AUDIO_RATE
from .audio import AudioMixer, OperatorVoice, RobotAudioTrack
from .media_loop import MediaLoop, call_on
from .poses import PoseChannel
from .turn import IceConfig
from .video import CODECS, VIDEO_CLOCK_RATE, CameraTrack, VideoHub

log = logging.getLogger(__name__)

TELEMETRY_PERIOD_S = 0.5
MAX_FRAME_TIMES = 64  # render times per client per report (30 fps x 0.5 s is 15; a late report catches up)
MEDIA_OWNER = "/vr_teleop_server/media"


@dataclass
class Peer:
    """One client's peer connection. Its pc, tracks and voice live on the media loop (made and touched there);
    the rest, poses included, on the server's loop."""

    owner: str
    pc: RTCPeerConnection | None = None  # made on the media loop, during the negotiation
    created: float = field(default_factory=time.monotonic)
    video: CameraTrack | None = None
    audio: RobotAudioTrack | None = None
    voice: OperatorVoice | None = None
    poses: PoseChannel | None = None
    closing: bool = False
    # from the newest stats
    bytes_sent: int = 0
    stats_at: float = 0.0
    bitrate: float = -1.0
    rtt: float = -1.0
    jitter: float = -1.0
    packets_lost: int = 0
    fraction_lost: float = 0.0


@dataclass
class ClientLink:
    """What telemetry keeps of one client between reports."""

    ws_rtt: float = -1.0
    ping: asyncio.Task[None] | None = None
    poses: deque[float] = field(default_factory=lambda: deque(maxlen=256))
    camera_base: int | None = None  # camera messages published before this client subscribed
    json_age_sum: float = 0.0
    json_age_n: int = 0
    webrtc_sent_reported: int = 0
    frames_reported: int = 0  # video frames whose render times went out already
    webrtc_age_reported: float = 0.0


class SessionView:
    """What the media service reads of a session (duck-typed: name, role, operator, subscriptions, ping)."""

    name: str
    role: Role | None
    operator: str
    subscriptions: Mapping[str, Any]
    ping: Callable[[], Awaitable[float]] | None


class MediaService:
    """Provides /vr_teleop/media/offer, /vr_teleop/media/ice_servers and /vr_teleop/clock, publishes
    /vr_teleop/telemetry."""

    def __init__(self, bus: Bus, robot: Robot | None, access: AccessPolicy,
                 sessions: Callable[[], Mapping[str, SessionView]], *, camera_fps: float = 30.0,
                 ice: IceConfig | None = None,
                 holds_control: Callable[[str], bool] = lambda _name: False,
                 control: Callable[[str], link_quality.ControlLink | None] = lambda connection: None) -> None:
        self.bus = bus
        self.holds_control = holds_control  # a session's name -> whether its operator holds control (poses channel)
        self.robot = robot
        self.access = access
        self.sessions = sessions
        self.control = control  # the watchdog as a connection's operator meets it (for the link quality)
        self.ice = ice or IceConfig()
        self.video = VideoHub(robot, camera_fps) if robot is not None else None
        self.audio = AudioMixer(bus, robot=robot)
        self.peers: dict[str, Peer] = {}
        self.links: dict[str, ClientLink] = {}
        self._tasks: set[asyncio.Task[Any]] = set()
        self.media_loop = MediaLoop()
        self.home: asyncio.AbstractEventLoop | None = None  # the server's loop (start)
        self._telemetry: asyncio.Task[None] | None = None
        self._camera_published = 0
        self._pose_token = 0
        self.peers_created = 0
        self.peers_closed = 0

    # ---- lifecycle ----------------------------------------------------------------------------------------------
    def start(self) -> None:
        self.home = asyncio.get_running_loop()
        self.media_loop.setup()
        if self.video is not None:
            self.video.start()
        self.bus.provide(names.MEDIA_OFFER_SERVICE, "vr_teleop_msgs/MediaOffer", self._offer)
        self.bus.provide(names.MEDIA_ICE_SERVERS_SERVICE, "vr_teleop_msgs/IceServers", self._ice_servers,
                         confidential=True)
        self.bus.provide(names.CLOCK_SERVICE, "vr_teleop_msgs/Clock", self._clock)
        self.bus.declare_topic(names.TELEMETRY_TOPIC, "vr_teleop_msgs/Telemetry", persistent=True)
        self._pose_token = self.bus.subscribe(MEDIA_OWNER, names.HEAD_POSE_TOPIC, "geometry_msgs/PoseStamped",
                                              self._on_pose)
        self.bus.taps.append(self._tap)
        self.bus.owner_dropped.append(self._owner_dropped)
        self.audio.start()
        self._telemetry = asyncio.ensure_future(self._report_loop())

    async def stop(self) -> None:
        if self._telemetry is not None:
            self._telemetry.cancel()
            self._telemetry = None
        # Closes under way finish (cancelling one would cancel aiortc's shared close future), then the rest.
        if self._tasks:
            await asyncio.gather(*self._tasks, return_exceptions=True)
        for owner in list(self.peers):
            await self._close_peer(owner)
        for link in self.links.values():
            if link.ping is not None:
                link.ping.cancel()
        self.links.clear()
        if self._tap in self.bus.taps:
            self.bus.taps.remove(self._tap)
        if self._owner_dropped in self.bus.owner_dropped:
            self.bus.owner_dropped.remove(self._owner_dropped)
        self.bus.unsubscribe(names.HEAD_POSE_TOPIC, self._pose_token)
        for name in (names.MEDIA_OFFER_SERVICE, names.MEDIA_ICE_SERVERS_SERVICE, names.CLOCK_SERVICE):
            if name in self.bus.services:
                self.bus.unadvertise_service(SERVER_NODE, name)
        await self.audio.close()
        if self.video is not None:
            await self.video.close()
        await self.media_loop.shutdown()  # last: the hubs above stop their tracks on it

    def _spawn(self, coro: Awaitable[Any]) -> asyncio.Task[Any]:
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return task

    # ---- signalling ---------------------------------------------------------------------------------------------
    @staticmethod
    def _refuse(message: str) -> dict[str, Any]:
        return {"success": False, "message": message, "sdp": "", "type": ""}

    async def _offer(self, request: Any) -> dict[str, Any]:
        caller = Bus.caller()
        session = self.sessions().get(caller)
        if session is None:
            return self._refuse(f"{names.MEDIA_OFFER_SERVICE} must be called by a client over its rosbridge connection: the "
                                "peer connection lives as long as that connection")
        try:
            self.access.check(session.role, "subscribe", names.CAMERA_TOPIC)
        except AccessDenied as exc:
            return self._refuse(f"no media without camera access: {exc}")
        if caller in self.peers:
            return self._refuse("this connection already has a peer connection (one per connection; renegotiation "
                                "is not supported): keep using it, or open a new rosbridge connection for another")
        if request.type != "offer":
            return self._refuse(f"type must be 'offer' (the client offers, the server answers), got {request.type!r}")
        if "m=" not in request.sdp:
            return self._refuse("malformed SDP: no media section (m=...); send the offer your WebRTC stack made "
                                "(RTCPeerConnection.createOffer) with a video and/or audio transceiver")
        try:
            offer = aiortc_sdp.SessionDescription.parse(request.sdp)
        except Exception as exc:
            return self._refuse(f"malformed SDP: {type(exc).__name__}: {exc}")
        kinds = [m.kind for m in offer.media if m.kind in ("audio", "video", "application")]
        if not kinds:
            return self._refuse("the offer has no audio, video or data channel section; add a transceiver (video "
                                "recvonly for the camera, audio sendrecv for the voice) or a data channel "
                                f"({names.POSES_CHANNEL!r}) before createOffer")
        sdp, rejected = request.sdp, []
        if "application" in kinds:  # a media section without a common codec must not cost the poses channel
            sdp, rejected = _without_unusable_media(request.sdp, offer)
        config = RTCConfiguration(iceServers=self.ice.rtc())
        peer = self.peers[caller] = Peer(caller)  # reserved before any await: a concurrent offer is refused
        self.peers_created += 1
        try:
            answer = await self.media_loop.run(self._negotiate(peer, session, self._may_speak(session.role), config,
                                                               sdp, offer))
        except _Refusal as exc:
            await self._close_peer(caller)
            return self._refuse(str(exc))
        except Exception as exc:
            log.exception("%s: WebRTC negotiation failed", caller)
            await self._close_peer(caller)
            return self._refuse(f"negotiation failed: {type(exc).__name__}: {exc}")
        if caller not in self.peers or peer.closing:  # the client left while we negotiated
            return self._refuse("the connection closed during negotiation")
        log.info("%s: peer connection negotiated (video %s)", caller, peer.video.codec if peer.video else "none")
        message = ""
        answer_sdp = answer.sdp
        if rejected:
            answer_sdp = _with_rejected_media(answer_sdp, rejected)
            message = (f"{_no_common_codec(offer, [r.kind for r in rejected])}: "
                       f"{' and '.join(r.kind for r in rejected)} rejected (answered with port 0; take the camera "
                       f"from its JPEG topic); the {names.POSES_CHANNEL!r} data channel and the rest are up")
        return {"success": True, "message": message, "sdp": answer_sdp, "type": answer.type}

    async def _ice_servers(self, _request: Any) -> dict[str, Any]:
        caller = Bus.caller()
        session = self.sessions().get(caller)

        def refuse(message: str) -> dict[str, Any]:
            return {"success": False, "message": message, "ice_servers": [], "expires": 0.0}

        if session is None:
            return refuse(f"{names.MEDIA_ICE_SERVERS_SERVICE} must be called by a client over its rosbridge "
                          "connection: the credentials are made for its operator")
        try:
            self.access.check(session.role, "subscribe", names.CAMERA_TOPIC)
        except AccessDenied as exc:
            return refuse(f"no media without camera access: {exc}")
        servers, expires = self.ice.servers(session.operator or caller)
        return {"success": True, "message": "" if servers else "no ICE servers configured (host candidates only: "
                                                                "enough on a LAN)",
                "ice_servers": servers, "expires": expires}

    async def _negotiate(self, peer: Peer, session: SessionView, may_speak: bool, config: RTCConfiguration,
                         sdp: str, offer: aiortc_sdp.SessionDescription) -> RTCSessionDescription:
        """On the media loop: the peer connection, its callbacks and its answer. What must reach the bus, the
        sessions or the robot goes home (to the server's loop) by call_on."""
        home = self.home
        assert home is not None
        pc = peer.pc = RTCPeerConnection(config)

        @pc.on("track")
        def on_track(track: Any) -> None:
            if track.kind == "audio" and peer.voice is None:
                peer.voice = OperatorVoice(self.bus, self.robot, peer.owner, track, may_speak, home=home)

        @pc.on("datachannel")
        def on_datachannel(channel: Any) -> None:
            label = channel.label
            channel.on("message", lambda message: call_on(home, self._channel_message, peer, session, message, label))

        @pc.on("connectionstatechange")
        def on_state() -> None:
            if pc.connectionState in ("failed", "closed"):
                call_on(home, self._connection_ended, peer, pc.connectionState)

        try:
            await pc.setRemoteDescription(RTCSessionDescription(sdp, "offer"))
        except OperationError:
            raise _Refusal(_no_common_codec(offer)) from None
        except (ValueError, KeyError, IndexError, TypeError) as exc:
            raise _Refusal(f"malformed SDP: {exc}") from None
        directions = {m.rtp.muxId: m.direction for m in offer.media}
        for transceiver in pc.getTransceivers():
            if directions.get(transceiver.mid) not in ("sendrecv", "recvonly"):  # the client does not receive
                continue
            if transceiver.kind == "video" and self.video is not None and peer.video is None:
                peer.video = CameraTrack(self.video)
                pc.addTrack(peer.video)
                sending = next(t for t in pc.getTransceivers() if t.sender.track is peer.video)
                peer.video.playout_delay = playout_delay.enable(sending, offer)
            elif transceiver.kind == "audio" and peer.audio is None:
                peer.audio = RobotAudioTrack(self.audio)
                pc.addTrack(peer.audio)
        await pc.setLocalDescription(await pc.createAnswer())
        if peer.video is not None:
            codec, sender = self._video_codec(pc)
            if codec not in CODECS:
                raise _Refusal(f"no common video codec: the answer would send {codec or 'nothing'}; this server "
                               f"sends {' or '.join(CODECS)}")
            peer.video.bind(codec, sender)
        return pc.localDescription

    @staticmethod
    def _video_codec(pc: RTCPeerConnection) -> tuple[str, Any]:
        """The codec the video sender will use: the first of the answer's video section (aiortc's rule)."""
        answer = aiortc_sdp.SessionDescription.parse(pc.localDescription.sdp)
        for transceiver in pc.getTransceivers():
            if transceiver.kind != "video" or transceiver.sender.track is None:
                continue
            for media in answer.media:
                if media.kind == "video" and media.rtp.muxId == transceiver.mid and media.rtp.codecs:
                    return media.rtp.codecs[0].name.upper(), transceiver.sender
        return "", None

    def _may_speak(self, role: Role | None) -> bool:
        try:
            self.access.check(role, "publish", names.OPERATOR_AUDIO_TOPIC)
        except AccessDenied:
            return False
        return True

    def _channel_message(self, peer: Peer, session: SessionView, message: str | bytes, label: str) -> None:
        """Home: one data-channel message into the client's session, in arrival order (tasks start in the order
        they are made, as aiortc's own emitter would start them)."""
        if peer.closing:
            return
        if peer.poses is None:
            peer.poses = PoseChannel(session, self.holds_control)
        self._spawn(peer.poses.on_message(message, label))

    def _connection_ended(self, peer: Peer, state: str) -> None:
        if not peer.closing:
            log.info("%s: peer connection %s", peer.owner, state)
            self._spawn(self._close_peer(peer.owner, peer))

    def _owner_dropped(self, owner: str) -> None:
        self.links.pop(owner, None)
        if owner in self.peers:
            self._spawn(self._close_peer(owner))

    async def _close_peer(self, owner: str, only: Peer | None = None) -> None:
        peer = self.peers.get(owner)
        if peer is None or (only is not None and peer is not only):
            return
        if peer.closing:
            return
        peer.closing = True
        try:
            await self.media_loop.run(self._close_media(peer))
        finally:
            if self.peers.get(owner) is peer:
                del self.peers[owner]
            self.peers_closed += 1
            log.info("%s: peer connection closed", owner)

    @staticmethod
    async def _close_media(peer: Peer) -> None:
        """On the media loop: the peer's voice, tracks and connection."""
        if peer.voice is not None:
            await peer.voice.close()
        for track in (peer.video, peer.audio):
            if track is not None:
                track.stop()
        if peer.pc is None:
            return
        try:  # not under wait_for: cancelling aiortc's close leaves its shared future cancelled
            await peer.pc.close()
        except InvalidStateError:
            log.warning("%s: the peer connection did not close cleanly", peer.owner)

    # ---- clock --------------------------------------------------------------------------------------------------
    async def _clock(self, request: Any) -> dict[str, Any]:
        received = time.time()
        return {"success": True, "message": "", "client_send": request.client_send, "server_receive": received,
                "server_send": time.time()}

    # ---- telemetry ----------------------------------------------------------------------------------------------
    def _on_pose(self, published: Published) -> None:
        link = self.links.get(published.sender)
        if link is None and published.sender in self.sessions():
            link = self.links[published.sender] = ClientLink()
        if link is not None:
            link.poses.append(time.monotonic())

    def _tap(self, published: Published) -> None:
        if published.topic != names.CAMERA_TOPIC:
            return
        self._camera_published += 1
        stamp = (published.plain or {}).get("header", {}).get("stamp") if published.plain is not None else None
        if stamp is None:
            return
        render = (stamp.get("secs", stamp.get("sec", 0)) or 0) + (stamp.get("nsecs", stamp.get("nanosec", 0)) or 0) / 1e9
        age = max(0.0, time.time() - render)
        for name, session in self.sessions().items():
            if names.CAMERA_TOPIC in session.subscriptions:
                link = self.links.setdefault(name, ClientLink())
                link.json_age_sum += age
                link.json_age_n += 1

    async def _report_loop(self) -> None:
        while True:
            try:
                await self._report()
            except asyncio.CancelledError:
                raise
            except Exception:
                log.exception("telemetry failed")
            await asyncio.sleep(TELEMETRY_PERIOD_S)

    def _ping(self, name: str, session: SessionView, link: ClientLink) -> None:
        if session.ping is None or (link.ping is not None and not link.ping.done()):
            return

        async def ping() -> None:
            try:
                link.ws_rtt = await asyncio.wait_for(session.ping(), 5.0)
            except Exception:  # closed, or no pong in time: keep the last figure
                pass

        link.ping = asyncio.ensure_future(ping())

    async def _report(self) -> None:
        sessions = self.sessions()
        clients = []
        for name, session in list(sessions.items()):
            link = self.links.setdefault(name, ClientLink())
            self._ping(name, session, link)
            peer = self.peers.get(name)
            if peer is not None and not peer.closing and peer.pc is not None:
                await self.media_loop.run(self._peer_stats(peer))
            # Read after the stats: poses keep arriving while the media loop answers, and an age is never negative.
            clients.append(self._client_entry(name, session, link, peer, time.monotonic()))
        self.bus.publish(names.TELEMETRY_TOPIC, {"header": {"stamp": _stamp(time.time())}, "clients": clients})

    @staticmethod
    async def _peer_stats(peer: Peer) -> None:
        """On the media loop. The video sender's figures; without video (audio only), the audio sender's."""
        assert peer.pc is not None
        senders = [x for x in peer.pc.getSenders() if x.track is not None]
        sender = next((x for x in senders if x.kind == "video"), None) or next(iter(senders), None)
        if sender is None:
            return
        clock_rate = VIDEO_CLOCK_RATE if sender.kind == "video" else AUDIO_RATE
        try:
            report = await sender.getStats()
        except Exception:
            return
        now = time.monotonic()
        for stats in report.values():
            if stats.type == "outbound-rtp":
                if peer.stats_at:
                    peer.bitrate = 8 * (stats.bytesSent - peer.bytes_sent) / max(1e-3, now - peer.stats_at)
                peer.bytes_sent, peer.stats_at = stats.bytesSent, now
            elif stats.type == "remote-inbound-rtp":
                peer.rtt = stats.roundTripTime if stats.roundTripTime is not None else -1.0
                peer.jitter = (stats.jitter or 0) / clock_rate
                peer.packets_lost = max(0, stats.packetsLost or 0)
                peer.fraction_lost = (stats.fractionLost or 0) / 256.0

    def _client_entry(self, name: str, session: SessionView, link: ClientLink, peer: Peer | None,
                      now: float) -> dict[str, Any]:
        recent = [t for t in link.poses if now - t <= 1.0]
        sub = session.subscriptions.get(names.CAMERA_TOPIC)
        sent = dropped = 0
        age_sum, age_n = link.json_age_sum, link.json_age_n
        link.json_age_sum, link.json_age_n = 0.0, 0
        if sub is not None:
            if link.camera_base is None:
                link.camera_base = self._camera_published - len(sub.queue) - sub.dropped
            dropped = sub.dropped
            sent = max(0, self._camera_published - link.camera_base - dropped - len(sub.queue))
        else:
            link.camera_base = None
        entry: dict[str, Any] = {
            "client": name, "role": session.role or ("supervisor" if self.access.open else ""),
            "ws_rtt": link.ws_rtt, "pose_rate": float(len(recent)),
            "pose_age": now - link.poses[-1] if link.poses else -1.0,
            "webrtc": peer is not None, "video_codec": "", "rtc_state": "", "rtc_rtt": -1.0, "rtc_jitter": -1.0,
            "rtc_packets_lost": 0, "rtc_fraction_lost": 0.0, "rtc_bitrate": -1.0, "rtc_target_bitrate": -1.0,
            "rtc_frames_sent": 0, "rtp_timestamp": 0, "rtp_render_time": 0.0, "rtp_clock_rate": 0,
            "frame_rtp_timestamps": [], "frame_render_times": [], "operator_voice_level": 0.0,
            "dc_received": 0, "dc_refused": 0, "dc_stale_dropped": 0, "dc_last_refusal": ""}
        if peer is not None:
            entry.update(rtc_state=peer.pc.connectionState if peer.pc is not None else "new", rtc_rtt=peer.rtt,
                         rtc_jitter=peer.jitter, rtc_packets_lost=peer.packets_lost,
                         rtc_fraction_lost=peer.fraction_lost, rtc_bitrate=peer.bitrate)
            video = peer.video
            if video is not None:
                sent += video.frames_sent
                dropped += video.frames_dropped
                age_sum += video.age_sum - link.webrtc_age_reported
                age_n += video.frames_sent - link.webrtc_sent_reported
                link.webrtc_age_reported, link.webrtc_sent_reported = video.age_sum, video.frames_sent
                entry.update(video_codec=video.codec, rtc_frames_sent=video.frames_sent,
                             rtc_target_bitrate=float(self.video.bitrate(video.codec)) if video.codec else -1.0)
                recent = video.recent(min(MAX_FRAME_TIMES, video.frames_sent - link.frames_reported))
                link.frames_reported = video.frames_sent
                newest = video.recent(1)
                if newest:
                    entry.update(rtp_timestamp=newest[0][0], rtp_render_time=newest[0][1],
                                 rtp_clock_rate=VIDEO_CLOCK_RATE, frame_rtp_timestamps=[r for r, _ in recent],
                                 frame_render_times=[t for _, t in recent])
            if peer.poses is not None:
                counts = peer.poses.counts
                entry.update(dc_received=counts.received % 2**32, dc_refused=counts.refused % 2**32,
                             dc_stale_dropped=counts.stale_dropped % 2**32, dc_last_refusal=counts.last_refusal)
            if peer.voice is not None and peer.voice.task is not None and not peer.voice.task.done():
                entry["operator_voice_level"] = (self.robot.voice_level if peer.voice.may_speak
                                                 and self.robot is not None else peer.voice.level)
        entry.update(camera_frames_sent=sent % 2**32, camera_frames_dropped=dropped % 2**32,
                     camera_frame_age=age_sum / age_n if age_n else -1.0)
        control = self.control(name)
        jitter = link_quality.pose_jitter(link.poses, now)
        quality, warning = link_quality.assess(ws_rtt=link.ws_rtt, rtc_rtt=entry["rtc_rtt"],
                                               fraction_lost=entry["rtc_fraction_lost"], pose_jitter_s=jitter,
                                               control=control)
        entry.update(pose_jitter=jitter, watchdog_threshold=control.threshold_s if control else -1.0,
                     watchdog_holds=control.holds_last_minute if control else 0, link_quality=quality,
                     link_warning=warning)
        return entry


class _Refusal(Exception):
    """A negotiation refused for a reason the client can fix; the text goes into the response."""


def _no_common_codec(offer: aiortc_sdp.SessionDescription, kinds: list[str] | None = None) -> str:
    parts = []
    for media in offer.media:
        if media.kind not in (kinds or ("audio", "video")):
            continue
        codecs = sorted({c.name for c in media.rtp.codecs if c.name.lower() not in ("rtx", "red", "ulpfec")})
        parts.append(f"{media.kind}: {', '.join(codecs) or 'none'}")
    return (f"no common codec: the offer has {'; '.join(parts)}; this server sends video as VP8 or H264 and audio "
            "as Opus (or PCMU/PCMA), and takes Opus from the client")


@dataclass(frozen=True)
class _Rejected:
    """An offered media section answered with port 0 (RFC 3264): where it was, and its answer line."""

    index: int
    kind: str
    section: str


def _media_sections(sdp: str) -> list[str]:
    """The session part, then each media section, as text (each m= line starts one)."""
    return re.split(r"(?=^m=)", sdp, flags=re.M)


def _without_unusable_media(sdp: str, offer: aiortc_sdp.SessionDescription) -> tuple[str, list[_Rejected]]:
    """The offer without its audio/video sections that share no codec with this server (aiortc refuses a whole
    offer for one), out of the BUNDLE group too; and what to answer for each."""
    sections = _media_sections(sdp)
    if len(sections) != len(offer.media) + 1:
        return sdp, []
    rejected = []
    for index, media in enumerate(offer.media):
        if media.kind not in ("audio", "video"):
            continue
        ours = {(c.mimeType.split("/")[1].lower(), c.clockRate)
                for c in RTCRtpSender.getCapabilities(media.kind).codecs}
        if any((c.name.lower(), c.clockRate) in ours for c in media.rtp.codecs
               if c.name.lower() not in ("rtx", "red", "ulpfec")):
            continue
        m_line = sections[index + 1].splitlines()[0].split()
        rejected.append(_Rejected(index, media.kind, " ".join([m_line[0], "0", *m_line[2:]]) + "\r\n"
                                  "c=IN IP4 0.0.0.0\r\na=inactive\r\n" f"a=mid:{media.rtp.muxId}\r\n"))
    if not rejected:
        return sdp, []
    mids = {offer.media[r.index].rtp.muxId for r in rejected}
    gone = {r.index + 1 for r in rejected}
    head = re.sub(r"^(a=group:BUNDLE)(.*)$",
                  lambda m: m.group(1) + "".join(f" {x}" for x in m.group(2).split() if x not in mids),
                  sections[0], flags=re.M)
    return head + "".join(s for i, s in enumerate(sections) if i and i not in gone), rejected


def _with_rejected_media(answer: str, rejected: list[_Rejected]) -> str:
    """The answer with each rejected section put back where the offer had it (an answer keeps the offer's order)."""
    sections = _media_sections(answer)
    for r in sorted(rejected, key=lambda r: r.index):
        sections.insert(r.index + 1, r.section)
    return "".join(sections)


def _stamp(t: float) -> dict[str, int]:
    secs = int(t)
    return {"secs": secs, "nsecs": int((t - secs) * 1e9)}
