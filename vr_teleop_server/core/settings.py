"""The protocol server's settings: listen address, TLS, and the limits every session enforces.

The app's ServerSettings extends these with the robot, features and files; the core sees only its own part. A field
marked `Cli(...)` is one of `vr-teleop serve`'s options (cli/options.py makes them from the fields: name, help from
the description, choices from a Literal, default from the field), so a setting is written once.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

MIB = 1024 * 1024


@dataclass(frozen=True)
class Cli:
    """A settings field as a `serve` option: its group in `--help`, its value's name, and (rarely) its flag."""

    group: str
    metavar: str | None = None
    flag: str | None = None  # default: --field-name
    env: str | None = None  # an environment variable read when the flag is not given (secrets)


class CoreSettings(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    host: Annotated[str, Cli("server")] = Field("127.0.0.1", description="address to listen on")
    port: Annotated[int, Cli("server")] = Field(9090, ge=0, le=65535, description="port to listen on")
    time_style: Annotated[Literal["ros1", "ros2"], Cli("server")] = Field(
        "ros1", description="send time as {secs, nsecs} (ros1) or {sec, nanosec} (ros2); both are accepted")
    max_message_size: Annotated[int, Cli("server", metavar="BYTES")] = Field(
        16 * MIB, ge=1024, description="larger frames get a status error")
    hard_frame_factor: int = Field(
        4, ge=1, description="frames over max_message_size x this close the connection (code 1009), so that a "
                             "hostile client cannot make the server buffer without bound")
    service_timeout: Annotated[float, Cli("server", metavar="S")] = Field(
        10.0, gt=0, description="seconds a service call waits when the caller gives no timeout")
    queue_bound: int = Field(100, ge=1, description="messages kept per subscription for a slow reader when the "
                                                    "subscriber set no queue_length")
    control_queue_bound: int = Field(1000, ge=10, description="replies and status messages kept for a slow reader")
    fragment_timeout: float = Field(10.0, gt=0, description="seconds an incomplete fragment set is kept")
    max_pending_calls: int = Field(100, ge=1, description="service calls one client may have in progress")
    certfile: Annotated[Path | None, Cli("access")] = Field(
        None, description="TLS certificate (PEM): serve wss:// and https://")
    keyfile: Annotated[Path | None, Cli("access")] = Field(None, description="TLS private key (PEM)")

    @property
    def max_frame_size(self) -> int:
        return self.max_message_size * self.hard_frame_factor
