"""Every client's link on /vr_teleop/telemetry (vr_teleop_msgs/Telemetry, 2 Hz), and /vr_teleop/clock, which puts
the server's clock on a client's (the render times telemetry reports are the server's).

What a client's entry says is vr_teleop_msgs/ClientTelemetry's (client_protocol/definitions.py): each entry is that
message's model, filled from the client's session, its peer connection (peer.py) and what this keeps between
reports (ClientLink). Times are the server's clock (simclock): its wall time for stamps, its monotonic time for ages.
"""

from __future__ import annotations

import asyncio
import logging
from collections import deque
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from pydantic import BaseModel

from client_protocol import names
from simclock import WALL, Clock

from ..core.access import AccessPolicy, Role
from ..core.bus import Bus, Published
from ..robot.interface import Robot
from . import link_quality
from .media_loop import MediaLoop
from .peer import Peer
from .video import VIDEO_CLOCK_RATE

log = logging.getLogger(__name__)

TELEMETRY_PERIOD_S = 0.5
MAX_FRAME_TIMES = 64  # render times per client per report (30 fps x 0.5 s is 15; a late report catches up)
NOT_KNOWN = -1.0
OWNER = "/vr_teleop_server/media"


class SessionView(Protocol):
    """What the media service reads of a session."""

    name: str
    role: Role | None
    operator: str
    subscriptions: Mapping[str, Any]
    ping: Callable[[], Awaitable[float]] | None


@dataclass
class ClientLink:
    """What telemetry keeps of one client between reports."""

    ws_rtt: float = NOT_KNOWN
    ping: asyncio.Task[None] | None = None
    poses: deque[float] = field(default_factory=lambda: deque(maxlen=256))  # arrivals, the clock's monotonic
    camera_base: int | None = None  # camera messages published before this client subscribed
    json_age_sum: float = 0.0
    json_age_n: int = 0
    webrtc_sent_reported: int = 0
    frames_reported: int = 0  # video frames whose render times went out already
    webrtc_age_reported: float = 0.0


class Telemetry:
    """Publishes /vr_teleop/telemetry and provides /vr_teleop/clock, on the server's loop."""

    def __init__(self, bus: Bus, access: AccessPolicy, sessions: Callable[[], Mapping[str, SessionView]],
                 peers: Mapping[str, Peer], media_loop: MediaLoop, *, robot: Robot | None,
                 control: Callable[[str], link_quality.ControlLink | None], clock: Clock = WALL) -> None:
        self.bus = bus
        self.access = access
        self.sessions = sessions
        self.peers = peers
        self.media_loop = media_loop
        self.robot = robot
        self.control = control  # the watchdog as a connection's operator meets it (for the link quality)
        self.clock = clock
        self.links: dict[str, ClientLink] = {}
        self.entry_model = bus.registry.model("vr_teleop_msgs/ClientTelemetry")
        self.report_model = bus.registry.model("vr_teleop_msgs/Telemetry")
        self._task: asyncio.Task[None] | None = None
        # camera frames published, per topic: the camera's, and its blurred view (serve --blur-faces), which serves
        # a spectator's subscription to the camera
        self._camera_published = {names.CAMERA_TOPIC: 0, names.CAMERA_BLURRED_TOPIC: 0}
        self._pose_token = 0

    def start(self) -> None:
        self.bus.provide(names.CLOCK_SERVICE, "vr_teleop_msgs/Clock", self._clock_service)
        self.bus.declare_topic(names.TELEMETRY_TOPIC, "vr_teleop_msgs/Telemetry", persistent=True)
        self._pose_token = self.bus.subscribe(OWNER, names.HEAD_POSE_TOPIC, "geometry_msgs/PoseStamped",
                                              self._on_pose)
        self.bus.taps.append(self._tap)
        self.bus.owner_dropped.append(self._owner_dropped)
        self._task = asyncio.ensure_future(self._report_loop())

    def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            self._task = None
        for link in self.links.values():
            if link.ping is not None:
                link.ping.cancel()
        self.links.clear()
        if self._tap in self.bus.taps:
            self.bus.taps.remove(self._tap)
        if self._owner_dropped in self.bus.owner_dropped:
            self.bus.owner_dropped.remove(self._owner_dropped)
        self.bus.unsubscribe(names.HEAD_POSE_TOPIC, self._pose_token)

    async def _clock_service(self, request: Any) -> dict[str, Any]:
        received = self.clock.time()
        return {"success": True, "message": "", "client_send": request.client_send, "server_receive": received,
                "server_send": self.clock.time()}

    def _owner_dropped(self, owner: str) -> None:
        self.links.pop(owner, None)

    def _on_pose(self, published: Published) -> None:
        link = self.links.get(published.sender)
        if link is None and published.sender in self.sessions():
            link = self.links[published.sender] = ClientLink()
        if link is not None:
            link.poses.append(self.clock.monotonic())

    def _tap(self, published: Published) -> None:
        if published.topic not in self._camera_published:
            return
        self._camera_published[published.topic] += 1
        stamp = (published.data or {}).get("header", {}).get("stamp")
        if stamp is None:
            return
        render = (stamp.get("secs", stamp.get("sec", 0)) or 0) + (stamp.get("nsecs", stamp.get("nanosec", 0)) or 0) / 1e9
        age = max(0.0, self.clock.time() - render)
        for name, session in self.sessions().items():
            sub = session.subscriptions.get(names.CAMERA_TOPIC)
            if sub is not None and sub.source == published.topic:
                link = self.links.setdefault(name, ClientLink())
                link.json_age_sum += age
                link.json_age_n += 1

    async def _report_loop(self) -> None:
        while True:
            try:
                await self.report()
            except asyncio.CancelledError:
                raise
            except Exception:
                log.exception("telemetry failed")
            await asyncio.sleep(TELEMETRY_PERIOD_S)

    def _ping(self, session: SessionView, link: ClientLink) -> None:
        if session.ping is None or (link.ping is not None and not link.ping.done()):
            return
        ping = session.ping

        async def measure() -> None:
            try:
                link.ws_rtt = await asyncio.wait_for(ping(), 5.0)
            except Exception:  # closed, or no pong in time: keep the last figure
                pass

        link.ping = asyncio.ensure_future(measure())

    async def report(self) -> None:
        clients = []
        for name, session in list(self.sessions().items()):
            link = self.links.setdefault(name, ClientLink())
            self._ping(session, link)
            peer = self.peers.get(name)
            if peer is not None and not peer.closing and peer.pc is not None:
                await self.media_loop.run(peer.refresh_stats())
            # Read after the stats: poses keep arriving while the media loop answers, and an age is never negative.
            clients.append(self.entry(name, session, link, peer, self.clock.monotonic()))
        t = self.clock.time()
        secs = int(t)
        self.bus.publish(names.TELEMETRY_TOPIC, self.report_model.model_validate(
            {"header": {"stamp": {"secs": secs, "nsecs": int((t - secs) * 1e9)}}, "clients": clients}))

    def entry(self, name: str, session: SessionView, link: ClientLink, peer: Peer | None, now: float) -> BaseModel:
        """One client's vr_teleop_msgs/ClientTelemetry; its fields left out are the message's zeros."""
        fields: dict[str, Any] = {
            "client": name, "role": session.role or ("supervisor" if self.access.open else ""),
            "ws_rtt": link.ws_rtt, "pose_rate": float(sum(1 for t in link.poses if now - t <= 1.0)),
            "pose_age": now - link.poses[-1] if link.poses else NOT_KNOWN, "webrtc": peer is not None}
        sent, dropped, age_sum, age_n = self._camera(session, link)
        if peer is not None:
            fields.update(self._peer_fields(link, peer))
            if peer.video is not None:
                video = peer.video
                sent += video.frames_sent
                dropped += video.frames_dropped
                age_sum += video.age_sum - link.webrtc_age_reported
                age_n += video.frames_sent - link.webrtc_sent_reported
                link.webrtc_age_reported, link.webrtc_sent_reported = video.age_sum, video.frames_sent
        fields.update(camera_frames_sent=sent % 2**32, camera_frames_dropped=dropped % 2**32,
                      camera_frame_age=age_sum / age_n if age_n else NOT_KNOWN)
        control = self.control(name)
        jitter = link_quality.pose_jitter(link.poses, now)
        quality, warning = "", ""
        if control is not None and link.poses:  # a link is judged once there is one: control taken, poses flowing
            quality, warning = link_quality.assess(ws_rtt=link.ws_rtt, rtc_rtt=fields.get("rtc_rtt", NOT_KNOWN),
                                                   fraction_lost=fields.get("rtc_fraction_lost", 0.0),
                                                   pose_jitter_s=jitter, control=control)
        fields.update(pose_jitter=jitter, watchdog_threshold=control.threshold_s if control else NOT_KNOWN,
                      watchdog_holds=control.holds_last_minute if control else 0, link_quality=quality,
                      link_warning=warning)
        return self.entry_model(**{**self._not_known(), **fields})

    @staticmethod
    def _not_known() -> dict[str, float]:
        """The figures that read -1 until measured (the message's zero would be a measurement)."""
        return dict.fromkeys(("rtc_rtt", "rtc_jitter", "rtc_bitrate", "rtc_target_bitrate"), NOT_KNOWN)

    def _camera(self, session: SessionView, link: ClientLink) -> tuple[int, int, float, int]:
        """Camera frames on the JSON topic sent to and dropped for this client, and their ages since the last."""
        sub = session.subscriptions.get(names.CAMERA_TOPIC)
        sent = dropped = 0
        age_sum, age_n = link.json_age_sum, link.json_age_n
        link.json_age_sum, link.json_age_n = 0.0, 0
        if sub is not None:
            published = self._camera_published[sub.source]
            if link.camera_base is None:
                link.camera_base = published - len(sub.queue) - sub.dropped
            dropped = sub.dropped
            sent = max(0, published - link.camera_base - dropped - len(sub.queue))
        else:
            link.camera_base = None
        return sent, dropped, age_sum, age_n

    def _peer_fields(self, link: ClientLink, peer: Peer) -> dict[str, Any]:
        fields: dict[str, Any] = {
            "rtc_state": peer.pc.connectionState if peer.pc is not None else "new", "rtc_rtt": peer.rtt,
            "rtc_jitter": peer.jitter, "rtc_packets_lost": peer.packets_lost,
            "rtc_fraction_lost": peer.fraction_lost, "rtc_bitrate": peer.bitrate}
        video = peer.video
        if video is not None:
            fields.update(video_codec=video.codec, rtc_frames_sent=video.frames_sent,
                          rtc_target_bitrate=float(video.hub.bitrate(video.codec)) if video.codec else NOT_KNOWN)
            recent = video.recent(min(MAX_FRAME_TIMES, video.frames_sent - link.frames_reported))
            link.frames_reported = video.frames_sent
            newest = video.recent(1)
            if newest:
                fields.update(rtp_timestamp=newest[0][0], rtp_render_time=newest[0][1],
                              rtp_clock_rate=VIDEO_CLOCK_RATE, frame_rtp_timestamps=[r for r, _ in recent],
                              frame_render_times=[t for _, t in recent])
        if peer.poses is not None:
            counts = peer.poses.counts
            fields.update(dc_received=counts.received % 2**32, dc_refused=counts.refused % 2**32,
                          dc_stale_dropped=counts.stale_dropped % 2**32, dc_last_refusal=counts.last_refusal)
        voice = peer.voice
        if voice is not None and voice.task is not None and not voice.task.done():
            fields["operator_voice_level"] = (self.robot.voice_level if voice.may_speak and self.robot is not None
                                              else voice.level)
        return fields
