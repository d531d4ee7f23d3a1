"""The recorder: taps the bus and the sessions' frames into an MCAP file (format.py says what it holds).

Crash safety: messages go into small zstd chunks, and an unfinished chunk is closed every FLUSH_S and flushed to
disk, so that a killed server leaves all but the last second or so readable (format.read_recording).

With `serve --blur-faces` (`blur`), a camera frame kept is written only once its faces are blurred (in the blur's
thread), with its blur note (features/face_blur.py) beside it; the raw frame is never written, nor the blurred
camera topic (its frames are these frames).
"""

from __future__ import annotations

import asyncio
import json
import logging
from pathlib import Path
from typing import TYPE_CHECKING

from mcap.writer import CompressionType, Writer

from client_protocol import names
from client_protocol.registry import TypeRegistry
from simclock import WALL, Clock

from ..core.bus import Bus, Published
from ..core.tasks import cancel_and_wait
from ..core.wire import message_json
from .format import FRAME_JSON_SCHEMA, FRAME_SCHEMA

if TYPE_CHECKING:
    from ..features.face_blur import FaceBlur

log = logging.getLogger(__name__)

FLUSH_S = 0.5
CHUNK_SIZE = 256 * 1024


class Recorder:
    def __init__(self, path: Path, registry: TypeRegistry, camera_fps: float = 2.0, bus: Bus | None = None,
                 clock: Clock = WALL, blur: FaceBlur | None = None) -> None:
        """`bus`: the bus start() taps; without one, messages come only through write_message (synth). `clock`
        stamps the messages (log time: its time(), in nanoseconds). `blur`: camera frames are recorded blurred."""
        self.clock = clock
        self.blur = blur
        self._blurring: set[asyncio.Task[None]] = set()
        self.path = path
        self.bus = bus
        self.registry = registry
        self.camera_period = 1.0 / camera_fps if camera_fps > 0 else None
        self._last_camera = -1e18
        path.parent.mkdir(parents=True, exist_ok=True)
        self._file = path.open("wb")
        self._writer = Writer(self._file, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="vr-teleop-server")
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, str, str], int] = {}
        self._seq = 0
        self._dirty = False
        self._task: asyncio.Task[None] | None = None
        self.messages = 0

    def write_metadata(self, name: str, values: dict[str, str]) -> None:
        """A metadata record (recording/format.py SESSION_METADATA: what the file should hold), before messages."""
        self._writer.add_metadata(name, values)

    # ---- lifetime -----------------------------------------------------------------------------------------------
    def start(self) -> None:
        """Taps the bus, after writing each state topic's last message (core/bus.py Topic.state): a recording
        started while the server runs opens with the state it starts in."""
        if self.bus is not None:
            for topic in list(self.bus.topics.values()):
                if topic.state and topic.last is not None:
                    self.on_published(topic.last)
            self.bus.taps.append(self.on_published)
        self._task = asyncio.ensure_future(self._flush_loop())

    async def _flush_loop(self) -> None:
        while True:
            await asyncio.sleep(FLUSH_S)
            self.flush()

    def flush(self) -> None:
        """Closes the open chunk and pushes it to disk, so a crash loses at most FLUSH_S of the session."""
        if not self._dirty:
            return
        self._dirty = False
        # mcap's Writer has no public way to close a chunk early; its private one is the only way short of
        # giving up compression (tests/test_recording.py kills a recording server to hold this to account).
        self._writer._Writer__finalize_chunk()  # type: ignore[attr-defined]
        self._file.flush()

    # ---- records ------------------------------------------------------------------------------------------------
    def _schema(self, name: str) -> int:
        sid = self._schemas.get(name)
        if sid is None:
            if name == FRAME_SCHEMA:
                schema = FRAME_JSON_SCHEMA
            else:
                try:
                    schema = self.registry.model(name).model_json_schema(by_alias=True)
                except (KeyError, ValueError):
                    schema = {"type": "object", "description": f"{name}: a type this server does not know"}
            sid = self._schemas[name] = self._writer.register_schema(name, "jsonschema",
                                                                    json.dumps(schema).encode())
        return sid

    def _channel(self, topic: str, schema: str, key: str, metadata: dict[str, str]) -> int:
        cid = self._channels.get((topic, schema, key))
        if cid is None:
            cid = self._channels[(topic, schema, key)] = self._writer.register_channel(
                topic, "json", self._schema(schema), metadata)
        return cid

    def _write(self, channel: int, data: bytes, time_ns: int | None = None) -> None:
        now = round(self.clock.time() * 1e9) if time_ns is None else time_ns
        self._seq += 1
        self._writer.add_message(channel, log_time=now, data=data, publish_time=now, sequence=self._seq)
        self._dirty = True
        self.messages += 1

    def on_published(self, published: Published) -> None:
        if published.topic == names.CAMERA_BLURRED_TOPIC:
            return
        if published.topic == names.CAMERA_TOPIC:
            now = self.clock.monotonic()
            if self.camera_period is None or now - self._last_camera < self.camera_period:
                return
            self._last_camera = now
            if self.blur is not None:
                task = asyncio.ensure_future(self._write_blurred(published, round(self.clock.time() * 1e9)))
                self._blurring.add(task)
                task.add_done_callback(self._blurring.discard)
                return
        self.write_message(published.topic, published.type, published.sender, message_json(published).encode())

    async def _write_blurred(self, published: Published, time_ns: int) -> None:
        """A kept camera frame, its faces blurred, at the time it was published; and its blur note."""
        assert self.blur is not None
        msg = published.data
        plan = self.blur.plan(msg["header"]["seq"])
        try:
            jpeg = await self.blur.blur_jpeg(msg["data"], plan)
        except Exception:  # never the raw frame instead
            log.exception("a camera frame could not be blurred; it is not recorded")
            return
        if jpeg is None or self._file.closed:
            return
        blurred = Published(published.topic, published.type, None, True, published.sender,
                            {**msg, "data": jpeg}, published.codec or self.registry.codec(published.type))
        self.write_message(published.topic, published.type, published.sender, message_json(blurred).encode(), time_ns)
        self.write_message(names.FACE_BLUR_TOPIC, "vr_teleop_msgs/FaceBlur", published.sender,
                           json.dumps(plan.note(msg["header"])).encode(), time_ns)

    def write_message(self, topic: str, type_name: str, sender: str, data: bytes, time_ns: int | None = None) -> None:
        """A topic message as JSON bytes (also how `vr-teleop synth` writes its headset sessions)."""
        channel = self._channel(topic, type_name, sender, {"sender": sender, "ros_type": type_name})
        self._write(channel, data, time_ns)

    def on_frame(self, client: str, direction: str, frame: str | bytes, time_ns: int | None = None) -> None:
        """A rosbridge frame a client sent ("in", publish frames excepted) or the server sent it ("out")."""
        if isinstance(frame, bytes):
            return  # CBOR and PNG frames carry topic messages, which the bus side records
        topic = names.RECORDING_IN_CHANNEL if direction == "in" else names.RECORDING_OUT_CHANNEL
        channel = self._channel(topic, FRAME_SCHEMA, client, {"client": client, "direction": direction})
        self._write(channel, frame.encode(), time_ns)

    def on_connection(self, client: str, event: str, peer: str) -> None:
        channel = self._channel(names.RECORDING_CONNECTIONS_CHANNEL, FRAME_SCHEMA, "", {})
        self._write(channel, json.dumps({"op": event, "client": client, "peer": peer}).encode())

    async def stop(self) -> None:
        if self.bus is not None and self.on_published in self.bus.taps:
            self.bus.taps.remove(self.on_published)
        await cancel_and_wait(self._task)
        if self._blurring:  # the frames being blurred are written before the file closes
            await asyncio.gather(*self._blurring, return_exceptions=True)
        self.finish()

    def finish(self) -> None:
        self._writer.finish()
        self._file.close()
        log.info("recording %s closed: %d messages", self.path, self.messages)
