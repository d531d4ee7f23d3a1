"""The playout-delay RTP header extension on the camera's packets: the viewer is told to show frames at once.

Chromium's receiver keeps a jitter buffer whose target delay it raises when frames come unevenly and lowers only
slowly; on a loaded sender its frame age grew with the run's length. A sender may bound that delay with the
playout-delay extension (http://www.webrtc.org/experiments/rtp-hdrext/playout-delay: 12 bits of minimum and 12 of
maximum delay in 10 ms units), as low-latency senders (cloud gaming, remote desktop) do; min 0 and max 0 make
Chromium render each frame as soon as it is decoded, with no smoothing. Chromium offers the extension in its SDP.

aiortc (1.16) neither answers nor sends it, so this project extends it in two places, both per peer connection:
- negotiation: after the offer is set and before the answer is made, the offered extension (with the offer's id)
  is added to the video transceiver's negotiated extensions (`RTCRtpTransceiver._headerExtensions`, which aiortc
  builds the answer's a=extmap lines from);
- sending: the video sender's header-extension map (aiortc.rtp.HeaderExtensionsMap, held in a private attribute
  of RTCRtpSender) is replaced by `PlayoutDelayMap`, a subclass that adds the extension to every packet it
  serializes, after the ones aiortc writes (aiortc.rtp's public pack/unpack functions).
Both are aiortc internals: pyproject bounds aiortc's version, and `enable` checks they are there and says so in
the log when they are not (the video then goes without the extension, as before).
"""

from __future__ import annotations

import logging
from typing import Any

from aiortc import RTCRtpTransceiver
from aiortc.rtcrtpparameters import RTCRtpHeaderExtensionParameters, RTCRtpParameters
from aiortc.rtp import HeaderExtensions, HeaderExtensionsMap, pack_header_extensions, unpack_header_extensions
from aiortc.sdp import SessionDescription

log = logging.getLogger(__name__)

URI = "http://www.webrtc.org/experiments/rtp-hdrext/playout-delay"
MIN_DELAY_MS = 0
MAX_DELAY_MS = 0
_SENDER_MAP = "_RTCRtpSender__rtp_header_extensions_map"  # RTCRtpSender's private extension map (aiortc 1.x)


def value(min_ms: int = MIN_DELAY_MS, max_ms: int = MAX_DELAY_MS) -> bytes:
    """The extension's 3 bytes: minimum and maximum delay, 12 bits each, in 10 ms units."""
    lo, hi = min(0xFFF, min_ms // 10), min(0xFFF, max_ms // 10)
    return bytes(((lo >> 4) & 0xFF, ((lo & 0xF) << 4) | (hi >> 8), hi & 0xFF))


class PlayoutDelayMap(HeaderExtensionsMap):
    """aiortc's extension map, plus the playout delay on every packet once the extension was negotiated."""

    def __init__(self) -> None:
        super().__init__()
        self.playout_delay_id = 0
        self._value = value()

    def configure(self, parameters: RTCRtpParameters) -> None:
        super().configure(parameters)
        for ext in parameters.headerExtensions:
            if ext.uri == URI:
                self.playout_delay_id = ext.id

    def set(self, values: HeaderExtensions) -> tuple[int, bytes]:
        profile, data = super().set(values)
        if not self.playout_delay_id:
            return profile, data
        extensions = unpack_header_extensions(profile, data) if data else []
        return pack_header_extensions([*extensions, (self.playout_delay_id, self._value)])


def enable(transceiver: RTCRtpTransceiver, offer: SessionDescription) -> bool:
    """Between setRemoteDescription(offer) and createAnswer(): answer the offer's playout-delay extension on this
    video transceiver and make its sender send it. False (and nothing changed) when the offer lacks it or this
    aiortc's internals differ."""
    offered = next((ext for media in offer.media if media.kind == "video" and media.rtp.muxId == transceiver.mid
                    for ext in media.rtp.headerExtensions if ext.uri == URI), None)
    negotiated: Any = getattr(transceiver, "_headerExtensions", None)
    if offered is None:
        return False
    if not isinstance(negotiated, list) or not isinstance(getattr(transceiver.sender, _SENDER_MAP, None),
                                                          HeaderExtensionsMap):
        log.warning("this aiortc (%s) does not hold header extensions where media/playout_delay.py expects them: "
                    "the camera goes without the playout-delay extension", _aiortc_version())
        return False
    if not any(ext.uri == URI for ext in negotiated):
        negotiated.append(RTCRtpHeaderExtensionParameters(id=offered.id, uri=URI))
    setattr(transceiver.sender, _SENDER_MAP, PlayoutDelayMap())
    return True


def _aiortc_version() -> str:
    import aiortc

    return getattr(aiortc, "__version__", "?")
