"""The outbox of one client: what waits to be sent, in which order, encoded how. Sans-I/O: messages and replies
go in, frames to write come out (`take`), and the clock is an argument, so tests drive it without sockets.

Replies and status messages go first, in order, in a bounded queue. Topic messages wait per subscription in a
queue of the subscription's length; a full queue drops its oldest (a slow reader loses old messages, never slows
a publisher). A throttled subscription sends at most one message per period, the newest it holds.
"""

from __future__ import annotations

import itertools
import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from client_protocol.registry import TypeRegistry

from ..bus import Published
from ..wire import dumps, png_pack, publish_cbor, publish_text, publish_text_in_style, split_fragments

log = logging.getLogger(__name__)

Frame = str | bytes


@dataclass(frozen=True)
class SubscriptionRequest:
    throttle_rate: int
    queue_length: int
    fragment_size: int | None
    compression: str


class TopicSubscription:
    """Everything one client asked of one topic. However many subscription ids it holds, the client gets one
    frame per message, sent at the lowest throttle rate, with the smallest fragment size and the longest queue."""

    def __init__(self, topic: str, default_bound: int, source: str | None = None) -> None:
        self.topic = topic
        self.source = source or topic  # the bus topic it is served from (a face-blurred view: core/access.py)
        self.requests: dict[Any, SubscriptionRequest] = {}
        self.default_bound = default_bound
        self.queue: deque[Published] = deque(maxlen=default_bound)
        self.token = 0
        self.last_sent = -math.inf
        self.throttle_s = 0.0
        self.fragment_size: int | None = None
        self.compression = "none"
        self.dropped = 0

    def update(self) -> None:
        reqs = list(self.requests.values())
        self.throttle_s = min(r.throttle_rate for r in reqs) / 1000.0
        sizes = [r.fragment_size for r in reqs if r.fragment_size]
        self.fragment_size = min(sizes) if sizes else None
        self.compression = reqs[-1].compression
        queue_length = max(r.queue_length for r in reqs)
        # queue_length 0: unthrottled, a bounded backlog for slow readers; throttled, only the newest message.
        bound = queue_length or (1 if self.throttle_s > 0 else self.default_bound)
        if bound != self.queue.maxlen:
            self.queue = deque(self.queue, maxlen=bound)


class Outbox:
    def __init__(self, registry: TypeRegistry, control_bound: int, *, wake: Callable[[], None] = lambda: None,
                 counters: dict[str, int] | None = None, ids: itertools.count | None = None,
                 name: str = "") -> None:
        """`wake` is called whenever something is queued (the session sets its event); `counters["dropped"]`
        counts messages lost to full queues or failed encodings; `ids` numbers outgoing fragment sets."""
        self.registry = registry
        self.control: deque[Frame] = deque(maxlen=control_bound)
        self.pending: dict[str, TopicSubscription] = {}  # subscriptions with queued messages, in arrival order
        self.wake = wake
        self.counters = counters if counters is not None else {"dropped": 0}
        self.ids = ids if ids is not None else itertools.count(1)
        self.name = name
        self.time_style: str | None = None  # the client's, when not the registry's (publish frames rewritten)
        # Set by the connection's writer: writes one frame to the socket at once and says whether it could (not
        # while the socket is backed up). Used only while nothing waits here: whatever the writer took before is
        # in the socket already, so the order holds, and a slow reader's frames still queue and drop as above.
        # It spares a frame the writer task's turn of the loop (the relay's way: a closed loop at its speed).
        self.write_now: Callable[[Frame], bool] | None = None

    def push(self, frame: Frame) -> None:
        """A reply or status frame, sent before any topic message."""
        if self.write_now is not None and not self.control and not self.pending and self.write_now(frame):
            return
        self.control.append(frame)
        self.wake()

    def deliver(self, sub: TopicSubscription, published: Published) -> None:
        """A message published on a topic the client subscribed to (the bus calls this for every subscriber)."""
        if self.write_now is not None and not self.control and not self.pending and sub.throttle_s == 0 \
                and not sub.fragment_size:
            frames = self._encode(sub, published)
            if not frames or (len(frames) == 1 and self.write_now(frames[0])):
                return
        if len(sub.queue) == sub.queue.maxlen:
            sub.dropped += 1
            self.counters["dropped"] += 1
        sub.queue.append(published)
        if sub.topic not in self.pending:
            self.pending[sub.topic] = sub
        self.wake()

    def forget(self, topic: str) -> None:
        """The client unsubscribed: what it had queued on the topic is not sent."""
        self.pending.pop(topic, None)

    def clear(self) -> None:
        self.pending.clear()
        self.control.clear()

    def take(self, now: float) -> tuple[list[Frame], float]:
        """The frames that may go out at `now` (replies first, then topics, throttles obeyed), and when more will
        be due if nothing new arrives (math.inf: not before something is queued)."""
        frames: list[Frame] = []
        control = self.control
        while control:
            frames.append(control.popleft())
        wake_at = math.inf
        pending = self.pending
        for topic, sub in list(pending.items()):
            if sub.throttle_s > 0:
                due = sub.last_sent + sub.throttle_s
                if now < due:
                    wake_at = min(wake_at, due)
                    continue
                frames.extend(self._encode(sub, sub.queue.popleft()))
                sub.last_sent = now
            else:
                while sub.queue:
                    frames.extend(self._encode(sub, sub.queue.popleft()))
            if not sub.queue:
                del pending[topic]
            elif sub.throttle_s > 0:
                wake_at = min(wake_at, now + sub.throttle_s)
        return frames, wake_at

    def _encode(self, sub: TopicSubscription, published: Published) -> list[Frame]:
        """The frames of one message as `sub` asks. One that cannot be encoded is dropped and logged: it must not
        stop this client's stream."""
        try:
            if sub.compression in ("cbor", "cbor-raw"):
                return [publish_cbor(published, self.registry, raw=sub.compression == "cbor-raw")]
            style = self.time_style
            text = publish_text(published) if style is None else publish_text_in_style(published, style)
            if sub.compression == "png":
                packed = published.encoded.get("png")
                if packed is None:
                    packed = published.encoded["png"] = png_pack(text)
                if sub.fragment_size and len(packed) > sub.fragment_size:
                    return list(split_fragments("png", packed, sub.fragment_size, self._fragment_id(published)))
                return [dumps({"op": "png", "data": packed})]
            if sub.fragment_size and len(text) > sub.fragment_size:
                return split_fragments("fragment", text, sub.fragment_size, self._fragment_id(published))
            return [text]
        except Exception:
            log.exception("%s: a message on %s could not be encoded and was dropped", self.name, sub.topic)
            self.counters["dropped"] += 1
            return []

    def _fragment_id(self, published: Published) -> str:
        return f"{published.topic}:{next(self.ids)}"
