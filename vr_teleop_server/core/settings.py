"""The protocol server's settings: listen address, TLS, and the limits every session enforces.

The app's ServerSettings extends these with the robot, features and files; the core sees only its own part.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

MIB = 1024 * 1024


class CoreSettings(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    host: str = "127.0.0.1"
    port: int = Field(9090, ge=0, le=65535)
    time_style: Literal["ros1", "ros2"] = Field(
        "ros1", description="time fields sent as {secs, nsecs} (ROS 1 clients) or {sec, nanosec} (ROS 2)")
    max_message_size: int = Field(16 * MIB, ge=1024, description="frames larger than this get a status error")
    hard_frame_factor: int = Field(
        4, ge=1, description="frames over max_message_size x this close the connection (code 1009), so that a "
                             "hostile client cannot make the server buffer without bound")
    service_timeout: float = Field(10.0, gt=0, description="seconds a call waits when the caller sets no timeout")
    queue_bound: int = Field(100, ge=1, description="messages kept per subscription for a slow reader when the "
                                                    "subscriber set no queue_length")
    control_queue_bound: int = Field(1000, ge=10, description="replies and status messages kept for a slow reader")
    fragment_timeout: float = Field(10.0, gt=0, description="seconds an incomplete fragment set is kept")
    max_pending_calls: int = Field(100, ge=1, description="service calls one client may have in progress")
    certfile: Path | None = Field(None, description="TLS certificate (PEM): serve wss:// and https://")
    keyfile: Path | None = Field(None, description="TLS private key (PEM), with certfile")

    @property
    def max_frame_size(self) -> int:
        return self.max_message_size * self.hard_frame_factor
