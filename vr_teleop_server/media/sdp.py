"""Offers and answers in aiortc's SDP model (aiortc.sdp), pure: no peer connection, no loop.

aiortc refuses a whole offer when one audio or video section shares no codec with it; an offer that also carries
the poses data channel must not lose the channel for that. Such a section is taken out of the offer before aiortc
sees it and put back into the answer with port 0 (RFC 3264 section 6: a rejected stream), where the offer had it.
Everything here goes through aiortc's own parser and writer, the ones its peer connection reads offers with.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace

from aiortc import RTCIceParameters
from aiortc.rtcrtpsender import RTCRtpSender
from aiortc.sdp import MediaDescription, SessionDescription

AV = ("audio", "video")
_NOT_CODECS = ("rtx", "red", "ulpfec")  # retransmission and redundancy formats ride along a codec


@dataclass(frozen=True)
class Rejected:
    """An offered section answered with port 0: its place in the offer, its kind, and the answer's section."""

    index: int
    kind: str
    section: MediaDescription


def parse(sdp: str) -> SessionDescription:
    return SessionDescription.parse(sdp)


def codecs(media: MediaDescription) -> list[str]:
    """A section's codec names, without the formats that only ride along one."""
    return sorted({c.name for c in media.rtp.codecs if c.name.lower() not in _NOT_CODECS})


def no_common_codec(offer: SessionDescription, kinds: list[str] | None = None) -> str:
    """The refusal's words: what the offer has of each kind, and what this server takes."""
    parts = [f"{media.kind}: {', '.join(codecs(media)) or 'none'}" for media in offer.media
             if media.kind in (kinds or AV)]
    return (f"no common codec: the offer has {'; '.join(parts)}; this server sends video as VP8 or H264 and audio "
            "as Opus (or PCMU/PCMA), and takes Opus from the client")


def _usable(media: MediaDescription) -> bool:
    ours = {(c.mimeType.split("/")[1].lower(), c.clockRate) for c in RTCRtpSender.getCapabilities(media.kind).codecs}
    return any((c.name.lower(), c.clockRate) in ours for c in media.rtp.codecs if c.name.lower() not in _NOT_CODECS)


def without_unusable_media(sdp: str, offer: SessionDescription) -> tuple[str, list[Rejected]]:
    """The offer (`sdp`, parsed as `offer`) without its audio/video sections that share no codec with this server,
    out of the BUNDLE group too, and the answer's section for each; `sdp` itself when every section is usable."""
    rejected = [Rejected(index, media.kind, _rejected_section(media)) for index, media in enumerate(offer.media)
                if media.kind in AV and not _usable(media)]
    if not rejected:
        return sdp, []
    gone = {r.index for r in rejected}
    mids = {offer.media[i].rtp.muxId for i in gone}
    kept = copy.copy(offer)  # the session level as offered
    kept.media = [m for i, m in enumerate(offer.media) if i not in gone]
    kept.group = [replace(g, items=[x for x in g.items if x not in mids]) for g in offer.group]
    kept.group = [g for g in kept.group if g.items]
    return str(kept), rejected


def with_rejected_media(answer: str, rejected: list[Rejected]) -> str:
    """The answer with each rejected section put back where the offer had it (an answer keeps the offer's order)."""
    description = parse(answer)
    for r in sorted(rejected, key=lambda r: r.index):
        description.media.insert(r.index, r.section)
    return str(description)


def _rejected_section(offered: MediaDescription) -> MediaDescription:
    section = MediaDescription(kind=offered.kind, port=0, profile=offered.profile, fmt=offered.fmt)
    section.host = "0.0.0.0"
    section.direction = "inactive"
    section.rtp.muxId = offered.rtp.muxId
    section.ice = RTCIceParameters()  # none: aiortc's writer reads the parameters of every section
    return section


def video_codec(answer: str, mid: str | None) -> str:
    """The codec a video sender of this mid will use: the first of the answer's section (aiortc's rule)."""
    for media in parse(answer).media:
        if media.kind == "video" and media.rtp.muxId == mid and media.rtp.codecs:
            return media.rtp.codecs[0].name.upper()
    return ""
