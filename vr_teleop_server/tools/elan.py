"""A session recording as video coders use it: the head camera as an H.264 MP4 and an ELAN `.eaf` beside it whose
tiers are what the recording knows happened (labels, the human's and the robot's actions, proposals, decisions,
speech, the autonomy level), aligned to the video.

Time zero is the recording's first camera frame (an annotation's times are relative to the media's start); without
a camera, the recording's first message. Each frame is shown from its own log time to the next one's (variable
frame rate: the MP4's timestamps are the recording's, in milliseconds), so the video and the tiers share one clock.
"""

from __future__ import annotations

import base64
import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Any

import av
import cv2
import numpy as np
import pympi

from client_protocol import names
from client_protocol.events import EventKind

from ..recording.format import Recorded, read_recording

POINT_MS = 500  # a moment (a decision, an intervention) is shown this long, as ELAN needs an end after its start
TIERS = ("labels", "human actions", "robot actions", "proposals", "decisions", "pupils' speech",
         "teacher's speech", "autonomy level")


class ExportError(ValueError):
    """A recording that cannot be exported; the message names the file and the problem."""


@dataclass
class Export:
    eaf: Path
    video: Path | None
    frames: int
    duration_s: float
    counts: dict[str, int] = field(default_factory=dict)


@dataclass
class _Timeline:
    """Annotations in seconds on the recording's clock, per tier, before the zero is known."""
    spans: dict[str, list[tuple[float, float, str]]] = field(default_factory=lambda: {t: [] for t in TIERS})
    open: dict[tuple[str, str], tuple[float, str]] = field(default_factory=dict)

    def add(self, tier: str, start: float, end: float, value: str) -> None:
        self.spans[tier].append((start, end, value))

    def begin(self, tier: str, key: str, t: float, value: str) -> None:
        self.open.setdefault((tier, key), (t, value))

    def finish(self, tier: str, key: str, t: float, value: str | None = None) -> None:
        if (tier, key) in self.open:
            start, began = self.open.pop((tier, key))
            self.add(tier, start, t, value or began)

    def close_all(self, t: float) -> None:
        for (tier, _key), (start, value) in list(self.open.items()):
            self.add(tier, start, t, value)
        self.open.clear()


def _records(path: Path) -> Iterator[Recorded]:
    if not path.is_file():
        raise ExportError(f"{path}: no such file; give the path of a recording (serve --record FILE.mcap)")
    try:
        with path.open("rb") as f:
            magic = f.read(8)
        if magic != b"\x89MCAP0\r\n":
            raise ExportError(f"{path}: not an MCAP recording (it does not start with MCAP's magic bytes); "
                              "give a file written by `vr-teleop serve --record` or `study run`")
        yield from read_recording(path)
    except (OSError, json.JSONDecodeError) as exc:
        raise ExportError(f"{path}: cannot read the recording ({exc})") from None


def _jpeg(data: Any) -> bytes:
    raw = data.get("data", "")
    return base64.b64decode(raw) if isinstance(raw, str) else bytes(raw)


def export_elan(path: Path, out: Path) -> Export:
    """Writes OUT/STEM.mp4 (when the recording holds camera frames) and OUT/STEM.eaf; ExportError on a bad file."""
    out.mkdir(parents=True, exist_ok=True)
    video_path = out / f"{path.stem}.mp4"
    line = _Timeline()
    encoder: _Encoder | None = None
    first = last = None
    try:
        for rec in _records(path):
            t = rec.time_ns * 1e-9
            first = t if first is None else first
            last = t
            if rec.topic == names.CAMERA_TOPIC:
                if encoder is None:
                    encoder = _Encoder(video_path, t)
                encoder.add(t, _jpeg(rec.data))
            else:
                _take(line, rec, t)
    except ExportError:
        if encoder is not None:
            encoder.abandon()
        raise
    if first is None or last is None:
        raise ExportError(f"{path}: the recording holds no messages (cut off before its first chunk?)")
    line.close_all(last)
    zero = encoder.zero if encoder is not None else first
    frames = encoder.close() if encoder is not None else 0
    eaf_path = out / f"{path.stem}.eaf"
    counts = _write_eaf(eaf_path, line, zero, video_path if encoder is not None else None)
    return Export(eaf=eaf_path, video=video_path if encoder is not None else None, frames=frames,
                  duration_s=round(last - zero, 3), counts=counts)


def _take(line: _Timeline, rec: Recorded, t: float) -> None:
    d = rec.data
    if rec.topic == names.STUDY_LABELS_TOPIC:
        # the dashboard's label buttons: a start or stop becomes a state update from the trial (below); an
        # intervention is a moment of its own
        if d.get("kind") == EventKind.INTERVENTION.value:
            action = json.loads(d.get("detail") or "{}").get("action", "")
            line.add("labels", t, t, f"intervention {action}".strip())
    elif rec.topic == names.STUDY_STATE_UPDATES_TOPIC:
        key = f"{d.get('trial')}:{d.get('id')}"
        tiers = ["human actions" if d.get("agent") == "human" else "robot actions"]
        if d.get("source") == "label":  # marked by the experimenter (/study/label/* or the dashboard's keys)
            tiers.append("labels")
        for tier in tiers:
            line.begin(tier, key, t, d.get("action", ""))
            if d.get("finished"):  # a start and stop in one update (/study/label/add) is a moment
                line.finish(tier, key, t)
    elif rec.topic == names.AUTONOMY_PROPOSALS_TOPIC:
        line.begin("proposals", str(d.get("id")), t, f"{d.get('action')} ({d.get('reason', '')})")
    elif rec.topic == names.AUTONOMY_OUTCOMES_TOPIC:
        line.finish("proposals", str(d.get("id")), t)
        who = d.get("decided_by") or d.get("initiator", "")
        line.add("decisions", t, t, f"{d.get('outcome')} {d.get('action')} by {who}")
    elif rec.topic == names.SIM_BYSTANDERS_TOPIC:
        for b in d.get("bystanders", []):
            if b.get("speaking"):
                line.begin("pupils' speech", b["name"], t, b["name"])
            else:
                line.finish("pupils' speech", b["name"], t)
    elif rec.topic == names.EVENT_TOPIC and d.get("kind") == EventKind.VOICE_ACTIVITY.value:
        detail = json.loads(d.get("detail") or "{}")
        if detail.get("activity"):
            direction = detail.get("direction_deg")
            line.begin("pupils' speech", "microphone", t,
                       "voice" + ("" if direction is None else f" at {direction:.0f} deg"))
        else:
            line.finish("pupils' speech", "microphone", t)
    elif rec.topic == names.AUTONOMY_STATE_TOPIC and d.get("level"):
        current = line.open.get(("autonomy level", "level"))
        if current is None or current[1] != d["level"]:
            line.finish("autonomy level", "level", t)
            line.begin("autonomy level", "level", t, d["level"])
    elif rec.topic == names.RECORDING_IN_CHANNEL and d.get("op") == "call_service" \
            and d.get("service") == names.SPEECH_SAY_SERVICE:
        line.begin("teacher's speech", f"{rec.sender}:{d.get('id')}", t, str((d.get("args") or {}).get("message", "")))
    elif rec.topic == names.RECORDING_OUT_CHANNEL and d.get("op") == "service_response" \
            and d.get("service") == names.SPEECH_SAY_SERVICE:
        line.finish("teacher's speech", f"{rec.sender}:{d.get('id')}", t)


def _write_eaf(path: Path, line: _Timeline, zero: float, video: Path | None) -> dict[str, int]:
    eaf = pympi.Elan.Eaf(author="vr-teleop export elan")
    if video is not None:
        # ELAN resolves RELATIVE_MEDIA_URL against the .eaf's folder: the two move together
        eaf.add_linked_file(video.name, relpath=f"./{video.name}", mimetype="video/mp4")
    counts = {}
    for tier in TIERS:
        eaf.add_tier(tier)
        counts[tier] = 0
        for start, end, value in sorted(line.spans[tier]):
            a = max(0, round((start - zero) * 1000))
            b = round((end - zero) * 1000)
            if b < 0:
                continue  # over before the video starts
            b = max(b, a + POINT_MS) if b - a < 1 else b
            eaf.add_annotation(tier, a, b, value)
            counts[tier] += 1
    eaf.remove_tier("default")
    eaf.to_file(str(path))
    return counts


class _Encoder:
    """JPEG frames in, H.264 out, each frame stamped with its log time in ms from the first."""

    def __init__(self, path: Path, zero: float) -> None:
        self.path, self.zero = path, zero
        self.container: Any = None
        self.stream: Any = None
        self.frames = 0
        self._last_pts = -1

    def add(self, t: float, jpeg: bytes) -> None:
        image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            return  # a frame that does not decode is left out; its neighbours cover its time
        pts = round((t - self.zero) * 1000)
        if pts <= self._last_pts:
            return  # two frames in one millisecond: the first stands
        if self.container is None:
            h, w = image.shape[:2]
            self.container = av.open(str(self.path), "w")
            self.stream = self.container.add_stream("libx264", rate=30)
            self.stream.width, self.stream.height = w - w % 2, h - h % 2
            self.stream.pix_fmt = "yuv420p"
            self.stream.time_base = Fraction(1, 1000)
            self.stream.codec_context.time_base = Fraction(1, 1000)
        image = image[:self.stream.height, :self.stream.width]
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="bgr24")
        frame.pts, frame.time_base = pts, Fraction(1, 1000)
        self.container.mux(self.stream.encode(frame))
        self._last_pts = pts
        self.frames += 1

    def close(self) -> int:
        if self.container is not None:
            self.container.mux(self.stream.encode(None))
            self.container.close()
        return self.frames

    def abandon(self) -> None:
        if self.container is not None:
            self.container.close()
        self.path.unlink(missing_ok=True)


def summary(result: Export) -> str:
    lines = []
    if result.video is None:
        lines.append("no camera in this recording: wrote the .eaf alone, with no video linked "
                     "(record with serve --record-camera-fps above 0 for a video)")
    else:
        lines.append(f"wrote {result.video}: {result.frames} frames, {result.duration_s:.1f} s (H.264, the "
                     "recording's own frame times)")
    lines.append(f"wrote {result.eaf}: {sum(result.counts.values())} annotations, time zero at the "
                 f"{'first camera frame' if result.video else 'first message'}")
    lines += [f"  {tier:<18} {n}" for tier, n in result.counts.items()]
    return "\n".join(lines)
