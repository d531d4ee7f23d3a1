"""Session recordings in MCAP, and a reader that survives a crash mid-file.

What a recording holds (all JSON-encoded, so that Foxglove opens it):
- every message published on the server's bus, whoever sent it (a client's poses, the server's joint commands,
  joint states, teleop state, events, clamps...), on a channel named by its topic with the ROS type as schema
  name (a JSON Schema generated from the type) and `sender` in the channel metadata. These are also what the
  server sent subscribers. Camera frames are kept at a reduced rate (serve --record-camera-fps, 0 for none);
- every other rosbridge frame each client sent (call_service, subscribe, fragments...), on "/rosbridge/in", and
  every reply or status the server sent it, on "/rosbridge/out"; `client` in the channel metadata;
- connections and disconnections on "/rosbridge/connections".
A recording started while the server runs (a live study's trial) opens with the last message of each topic
declared as state (core/bus.py Topic.state: the robot's description, the autonomy state, the classroom's
bystanders, the menus...), so that it holds the state it began in; a trial's own events (/study/*) are history and
are not carried into the next recording.
Log time is the wall clock in nanoseconds.

Crash safety: messages go into small zstd chunks, and an unfinished chunk is closed every FLUSH_S and flushed to
disk. A server killed with SIGKILL leaves a file without its summary; read_recording() reads it sequentially up
to the last whole chunk, i.e. all but the last second or so.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import StreamReader


FRAME_SCHEMA = "rosbridge/Frame"
FRAME_JSON_SCHEMA = {"type": "object", "description": "a rosbridge v2 frame as sent on the WebSocket",
                     "properties": {"op": {"type": "string"}}, "required": ["op"]}


@dataclass(frozen=True)
class Recorded:
    time_ns: int
    topic: str
    schema: str
    metadata: dict[str, str]
    data: dict[str, Any]

    @property
    def sender(self) -> str:
        return self.metadata.get("sender") or self.metadata.get("client", "")


MCAP_MAGIC = b"\x89MCAP0\r\n"  # the first and last 8 bytes of every MCAP file (its spec's "Magic")
SESSION_METADATA = "vr_teleop.session"  # a metadata record: what the file should hold ("duration_s": synth's)


class NotARecording(ValueError):
    """A file that is not MCAP at all (a recording of ours is)."""


@dataclass(frozen=True)
class RecordingCheck:
    """`closed`: the file ends as a finished MCAP file does (its summary and closing magic); a writer that was
    killed or a copy that was cut short leaves it open. `planned_s`: the session's length when the writer knew it
    beforehand (synth writes it), None otherwise."""
    closed: bool
    planned_s: float | None


def check_recording(path: Path) -> RecordingCheck:
    """Whether a file is an MCAP file, and a closed one; NotARecording names a foreign or empty file."""
    with path.open("rb") as f:
        head = f.read(len(MCAP_MAGIC))
        if head != MCAP_MAGIC:
            what = "an empty file" if not head else "it does not begin as MCAP files do"
            raise NotARecording(f"{path}: not an MCAP file ({what}); give a recording of `vr-teleop serve "
                                "--record` or `vr-teleop synth`")
        size = f.seek(0, 2)
        f.seek(max(size - len(MCAP_MAGIC), len(MCAP_MAGIC)))
        closed = size > 2 * len(MCAP_MAGIC) and f.read() == MCAP_MAGIC
        f.seek(0)
        return RecordingCheck(closed, _planned_s(f))


def _planned_s(f: Any) -> float | None:
    """The session metadata's duration: written first, so only the records before the first message are read."""
    try:
        for record in StreamReader(f, skip_magic=False, emit_chunks=True).records:
            if isinstance(record, Metadata) and record.name == SESSION_METADATA:
                return float(record.metadata["duration_s"])
            if isinstance(record, (Message, Chunk)):
                return None
    except Exception:  # noqa: BLE001 (a torn file fails however the parser meets it: no metadata then)
        return None
    return None


def read_recording(path: Path) -> Iterator[Recorded]:
    """Every message in log order; a file cut short (a crash) yields what it holds up to its last whole chunk.
    NotARecording for a file that is not MCAP."""
    with path.open("rb") as f:
        if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            check_recording(path)  # raises, naming the problem
        f.seek(0)
        try:
            reader = make_reader(f)
            summary = reader.get_summary()
        except (McapError, ValueError, EOFError, AssertionError, OSError):  # OSError: too short to seek to a footer
            summary = None
        if summary is not None:
            f.seek(0)
            for schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
                yield _recorded(schema, channel, message)
            return
        f.seek(0)
        yield from _read_stream(f)


def _read_stream(f: Any) -> Iterator[Recorded]:
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    records = StreamReader(f, skip_magic=False, emit_chunks=False).records
    while True:
        try:
            record = next(records)
        except StopIteration:
            return
        except Exception:  # noqa: BLE001 (the torn end of a killed writer fails however the parser meets it)
            return
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            channel = channels.get(record.channel_id)
            if channel is not None:
                yield _recorded(schemas.get(channel.schema_id), channel, record)


def _recorded(schema: Schema | None, channel: Channel, message: Message) -> Recorded:
    return Recorded(message.log_time, channel.topic, schema.name if schema else "", dict(channel.metadata),
                    json.loads(message.data))
