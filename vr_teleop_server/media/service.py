"""WebRTC beside the rosbridge stream: the offer service and one peer connection per client (peer.py). The offer's
SDP is read and mended in sdp.py; the link telemetry and the clock service are telemetry.py's.

Signalling rides the rosbridge connection the client already has: it calls /vr_teleop/media/offer with its
offer and gets the server's answer (aiortc gathers its candidates before answering: no trickle). The peer
connection belongs to the calling session and is closed when that WebSocket closes (the bus's owner_dropped), or
when ICE or DTLS fail (a peer that vanished: aioice's consent checks notice within about 30 s). Every refusal is
answered inside the response (success false, message naming the problem and the fix).

A "poses" data channel in the offer carries the operator's poses and Joy into the client's own session (poses.py);
on a "capture_poses" channel the server sends each video frame's capture pose (video.py);
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
gets no media. Under `serve --blur-faces` a client that may not see faces (a spectator: core/access.py) gets its
video from a second hub, whose frames have their faces blurred. An operator's or
supervisor's microphone is played on the robot and logged; a spectator's is ignored.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable, Mapping
from typing import TYPE_CHECKING, Any

from aiortc import RTCConfiguration, RTCPeerConnection, RTCSessionDescription
from aiortc.exceptions import InvalidStateError, OperationError

from client_protocol import names
from simclock import WALL, Clock

from ..core.access import AccessDenied, AccessPolicy, Role
from ..core.bus import SERVER_NODE, Bus
from ..robot.interface import Robot
from . import link_quality, playout_delay, sdp
from .audio import AudioMixer, OperatorVoice, RobotAudioTrack
from .media_loop import MediaLoop, call_on
from .peer import Peer
from .poses import PoseChannel
from .telemetry import SessionView, Telemetry
from .turn import IceConfig
from .video import CODECS, CameraTrack, VideoHub

if TYPE_CHECKING:
    from ..features.face_blur import FaceBlur

log = logging.getLogger(__name__)

class MediaService:
    """Provides /vr_teleop/media/offer, /vr_teleop/media/ice_servers and /vr_teleop/clock, publishes
    /vr_teleop/telemetry."""

    def __init__(self, bus: Bus, robot: Robot | None, access: AccessPolicy,
                 sessions: Callable[[], Mapping[str, SessionView]], *, camera_fps: float = 30.0,
                 ice: IceConfig | None = None,
                 holds_control: Callable[[str], bool] = lambda _name: False,
                 control: Callable[[str], link_quality.ControlLink | None] = lambda connection: None,
                 clock: Clock = WALL, blur: FaceBlur | None = None) -> None:
        self.bus = bus
        self.holds_control = holds_control  # a session's name -> whether its operator holds control (poses channel)
        self.robot = robot
        self.access = access
        self.sessions = sessions
        self.ice = ice or IceConfig()
        self.video = VideoHub(robot, camera_fps, clock=clock) if robot is not None else None
        # serve --blur-faces: what a client that may not see faces watches
        self.blurred_video = VideoHub(robot, camera_fps, clock=clock, blur=blur) \
            if robot is not None and blur is not None else None
        self.audio = AudioMixer(bus, robot=robot)
        self.peers: dict[str, Peer] = {}
        self._tasks: set[asyncio.Task[Any]] = set()
        self.media_loop = MediaLoop()
        self.telemetry = Telemetry(bus, access, sessions, self.peers, self.media_loop, robot=robot,
                                   control=control, clock=clock)
        self.home: asyncio.AbstractEventLoop | None = None  # the server's loop (start)
        self.peers_created = 0
        self.peers_closed = 0

    # ---- lifecycle ----------------------------------------------------------------------------------------------
    def start(self) -> None:
        self.home = asyncio.get_running_loop()
        self.media_loop.setup()
        for hub in (self.video, self.blurred_video):
            if hub is not None:
                hub.start()
        self.bus.provide(names.MEDIA_OFFER_SERVICE, "vr_teleop_msgs/MediaOffer", self._offer)
        self.bus.provide(names.MEDIA_ICE_SERVERS_SERVICE, "vr_teleop_msgs/IceServers", self._ice_servers,
                         confidential=True)
        self.bus.owner_dropped.append(self._owner_dropped)
        self.audio.start()
        self.telemetry.start()

    async def stop(self) -> None:
        self.telemetry.stop()
        # Closes under way finish (cancelling one would cancel aiortc's shared close future), then the rest.
        if self._tasks:
            await asyncio.gather(*self._tasks, return_exceptions=True)
        for owner in list(self.peers):
            await self._close_peer(owner)
        if self._owner_dropped in self.bus.owner_dropped:
            self.bus.owner_dropped.remove(self._owner_dropped)
        for name in (names.MEDIA_OFFER_SERVICE, names.MEDIA_ICE_SERVERS_SERVICE, names.CLOCK_SERVICE):
            if name in self.bus.services:
                self.bus.unadvertise_service(SERVER_NODE, name)
        await self.audio.close()
        for hub in (self.video, self.blurred_video):
            if hub is not None:
                await hub.close()
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
            offer = sdp.parse(request.sdp)
        except Exception as exc:
            return self._refuse(f"malformed SDP: {type(exc).__name__}: {exc}")
        kinds = [m.kind for m in offer.media if m.kind in ("audio", "video", "application")]
        if not kinds:
            return self._refuse("the offer has no audio, video or data channel section; add a transceiver (video "
                                "recvonly for the camera, audio sendrecv for the voice) or a data channel "
                                f"({names.POSES_CHANNEL!r}) before createOffer")
        offered, rejected = request.sdp, []
        if "application" in kinds:  # a media section without a common codec must not cost the poses channel
            offered, rejected = sdp.without_unusable_media(request.sdp, offer)
        config = RTCConfiguration(iceServers=self.ice.rtc())
        peer = self.peers[caller] = Peer(caller)  # reserved before any await: a concurrent offer is refused
        self.peers_created += 1
        try:
            answer = await self.media_loop.run(self._negotiate(peer, session, self._may_speak(session.role), config,
                                                               offered, offer))
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
            answer_sdp = sdp.with_rejected_media(answer_sdp, rejected)
            message = (f"{sdp.no_common_codec(offer, [r.kind for r in rejected])}: "
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
                         offered: str, offer: sdp.SessionDescription) -> RTCSessionDescription:
        """On the media loop: the peer connection, its callbacks and its answer. What must reach the bus, the
        sessions or the robot goes home (to the server's loop) by call_on."""
        home = self.home
        assert home is not None
        pc = peer.pc = RTCPeerConnection(config)

        @pc.on("track")
        def on_track(track: Any) -> None:
            if track.kind == "audio" and peer.voice is None:
                peer.voice = OperatorVoice(self.bus, peer.owner, track, may_speak, home=home)

        @pc.on("datachannel")
        def on_datachannel(channel: Any) -> None:
            label = channel.label
            if label == names.CAPTURE_POSES_CHANNEL:  # the server's to send on (video.py); what comes is ignored
                peer.pose_channel = channel
                if peer.video is not None:
                    peer.video.pose_channel = channel
                return
            channel.on("message", lambda message: call_on(home, self._channel_message, peer, session, message, label))

        @pc.on("connectionstatechange")
        def on_state() -> None:
            if pc.connectionState in ("failed", "closed"):
                call_on(home, self._connection_ended, peer, pc.connectionState)

        try:
            await pc.setRemoteDescription(RTCSessionDescription(offered, "offer"))
        except OperationError:
            raise _Refusal(sdp.no_common_codec(offer)) from None
        except (ValueError, KeyError, IndexError, TypeError) as exc:
            raise _Refusal(f"malformed SDP: {exc}") from None
        directions = {m.rtp.muxId: m.direction for m in offer.media}
        for transceiver in pc.getTransceivers():
            if directions.get(transceiver.mid) not in ("sendrecv", "recvonly"):  # the client does not receive
                continue
            if transceiver.kind == "video" and self.video is not None and peer.video is None:
                hub = self.video if self.blurred_video is None or self.access.sees_faces(session.role) \
                    else self.blurred_video
                peer.video = CameraTrack(hub)
                peer.video.pose_channel = peer.pose_channel
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
        """The codec the video sender will use, and the sender."""
        for transceiver in pc.getTransceivers():
            if transceiver.kind == "video" and transceiver.sender.track is not None:
                return sdp.video_codec(pc.localDescription.sdp, transceiver.mid), transceiver.sender
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


class _Refusal(Exception):
    """A negotiation refused for a reason the client can fix; the text goes into the response."""
