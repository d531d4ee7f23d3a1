"""One client's peer connection, and the figures its sender's statistics give."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

from aiortc import RTCPeerConnection

from .audio import RATE as AUDIO_RATE
from .audio import OperatorVoice, RobotAudioTrack
from .poses import PoseChannel
from .video import VIDEO_CLOCK_RATE, CameraTrack


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
    pose_channel: Any = None  # the "capture_poses" data channel the client opened (media loop; video.py sends)
    closing: bool = False
    # from the newest stats
    bytes_sent: int = 0
    stats_at: float = 0.0
    bitrate: float = -1.0
    rtt: float = -1.0
    jitter: float = -1.0
    packets_lost: int = 0
    fraction_lost: float = 0.0

    async def refresh_stats(self) -> None:
        """On the media loop. The video sender's figures; without video (audio only), the audio sender's. (Bytes
        per second of the real network: the machine's monotonic clock, whatever the server's clock.)"""
        assert self.pc is not None
        senders = [x for x in self.pc.getSenders() if x.track is not None]
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
                if self.stats_at:
                    self.bitrate = 8 * (stats.bytesSent - self.bytes_sent) / max(1e-3, now - self.stats_at)
                self.bytes_sent, self.stats_at = stats.bytesSent, now
            elif stats.type == "remote-inbound-rtp":
                self.rtt = stats.roundTripTime if stats.roundTripTime is not None else -1.0
                self.jitter = (stats.jitter or 0) / clock_rate
                self.packets_lost = max(0, stats.packetsLost or 0)
                self.fraction_lost = (stats.fractionLost or 0) / 256.0
