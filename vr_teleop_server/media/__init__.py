"""WebRTC media beside the rosbridge stream (issue 20): the head camera as video encoded once per codec, the
robot's audio out and the operator's voice in, the offer and clock services, and the link telemetry.

Layer: with core and robot (imports bus, access and the Robot interface; never features or app)."""

from .service import CLOCK_SERVICE, OFFER_SERVICE, TELEMETRY_TOPIC, MediaService

__all__ = ["CLOCK_SERVICE", "OFFER_SERVICE", "TELEMETRY_TOPIC", "MediaService"]
