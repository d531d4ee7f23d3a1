"""The outbox without sockets: messages and replies in, the exact frames a client would read out, the clock an
argument (as websockets tests its protocol core: bytes in, bytes out)."""

from __future__ import annotations

import json

import cbor2

from client_protocol.registry import TypeRegistry
from vr_teleop_server.core.bus import Bus, Published
from vr_teleop_server.core.session.outbox import Outbox, SubscriptionRequest, TopicSubscription
from vr_teleop_server.core.wire import png_unpack

TOPIC = "/chatter"


class Harness:
    def __init__(self, control_bound: int = 10) -> None:
        self.bus = Bus(TypeRegistry())
        self.bus.declare_topic(TOPIC, "std_msgs/String")
        self.wakes = 0
        self.outbox = Outbox(self.bus.registry, control_bound, wake=self._wake)

    def _wake(self) -> None:
        self.wakes += 1

    def subscription(self, *, throttle_ms: int = 0, queue_length: int = 0, fragment_size: int | None = None,
                     compression: str = "none", default_bound: int = 100) -> TopicSubscription:
        sub = TopicSubscription(TOPIC, default_bound)
        sub.requests["s1"] = SubscriptionRequest(throttle_ms, queue_length, fragment_size, compression)
        sub.update()
        return sub

    def publish(self, sub: TopicSubscription, text: str) -> Published:
        published = self.bus.publish(TOPIC, {"data": text})
        self.outbox.deliver(sub, published)
        return published


def datas(frames: list) -> list[str]:
    return [json.loads(f)["msg"]["data"] for f in frames]


def test_replies_go_first_in_order_then_topic_messages_exactly_as_sent():
    h = Harness()
    sub = h.subscription()
    h.publish(sub, "a")
    h.outbox.push('{"op":"status","level":"error","msg":"one"}')
    h.outbox.push('{"op":"service_response","id":"7","result":true}')
    frames, wake_at = h.outbox.take(now=0.0)
    assert frames == ['{"op":"status","level":"error","msg":"one"}',
                      '{"op":"service_response","id":"7","result":true}',
                      '{"op":"publish","topic":"/chatter","msg":{"data":"a"}}']
    assert wake_at == float("inf")
    assert h.outbox.take(now=0.0) == ([], float("inf"))  # nothing twice
    assert h.wakes == 3  # every message and reply woke the writer


def test_a_full_queue_drops_its_oldest_and_counts_it():
    h = Harness()
    sub = h.subscription(queue_length=2)
    for text in "abcde":
        h.publish(sub, text)
    frames, _ = h.outbox.take(now=0.0)
    assert datas(frames) == ["d", "e"]
    assert h.outbox.counters["dropped"] == 3 and sub.dropped == 3


def test_the_reply_queue_is_bounded_too():
    h = Harness(control_bound=3)
    for i in range(5):
        h.outbox.push(f'{{"op":"status","msg":"{i}"}}')
    frames, _ = h.outbox.take(now=0.0)
    assert [json.loads(f)["msg"] for f in frames] == ["2", "3", "4"]


def test_a_throttled_subscription_sends_the_newest_once_per_period():
    h = Harness()
    sub = h.subscription(throttle_ms=100)
    h.publish(sub, "first")
    frames, wake_at = h.outbox.take(now=10.0)
    assert datas(frames) == ["first"] and wake_at == float("inf")
    h.publish(sub, "second")
    h.publish(sub, "third")
    frames, wake_at = h.outbox.take(now=10.05)  # inside the period: nothing, and when to come back
    assert frames == [] and abs(wake_at - 10.1) < 1e-9
    frames, _ = h.outbox.take(now=10.1)
    assert datas(frames) == ["third"]  # a throttled subscription keeps only the newest
    assert h.outbox.counters["dropped"] == 1


def test_forget_drops_what_an_unsubscribed_client_had_queued():
    h = Harness()
    sub = h.subscription()
    h.publish(sub, "a")
    h.outbox.forget(TOPIC)
    assert h.outbox.take(now=0.0) == ([], float("inf"))


def test_fragments_reassemble_to_the_publish_frame():
    h = Harness()
    sub = h.subscription(fragment_size=10)
    h.publish(sub, "x" * 40)
    frames, _ = h.outbox.take(now=0.0)
    pieces = [json.loads(f) for f in frames]
    assert {p["op"] for p in pieces} == {"fragment"} and len({p["id"] for p in pieces}) == 1
    assert [p["num"] for p in pieces] == list(range(pieces[0]["total"]))
    assert all(len(p["data"]) <= 10 for p in pieces)
    whole = json.loads("".join(p["data"] for p in pieces))
    assert whole == {"op": "publish", "topic": TOPIC, "msg": {"data": "x" * 40}}


def test_cbor_and_png_encodings():
    h = Harness()
    cbor_sub = h.subscription(compression="cbor")
    h.publish(cbor_sub, "hello")
    (frame,), _ = h.outbox.take(now=0.0)
    assert isinstance(frame, bytes)
    assert cbor2.loads(frame) == {"op": "publish", "topic": TOPIC, "msg": {"data": "hello"}}
    png_sub = h.subscription(compression="png")
    h.publish(png_sub, "hello")
    (frame,), _ = h.outbox.take(now=0.0)
    packed = json.loads(frame)
    assert packed["op"] == "png"
    assert json.loads(png_unpack(packed["data"])) == {"op": "publish", "topic": TOPIC, "msg": {"data": "hello"}}


def test_a_message_that_cannot_be_encoded_is_dropped_and_the_stream_goes_on():
    h = Harness()
    sub = h.subscription(compression="cbor")
    bad = h.publish(sub, "bad")
    bad.encoded["cbor"] = None  # the cache says nothing: the encoder runs
    bad._value = object()  # and meets a value it cannot encode
    h.publish(sub, "good")
    frames, _ = h.outbox.take(now=0.0)
    assert [cbor2.loads(f)["msg"]["data"] for f in frames] == ["good"]
    assert h.outbox.counters["dropped"] == 1


def test_a_frame_goes_to_the_socket_at_once_only_while_nothing_waits_and_the_socket_takes_it():
    """The writer's direct path (Outbox.write_now): used while nothing is queued, so the order holds; a socket
    that does not take the frame (backed up) leaves it queued as before; a throttled subscription always queues."""
    h = Harness()
    sub = h.subscription()
    written: list = []
    taking = [True]

    def write_now(frame) -> bool:
        if taking[0]:
            written.append(frame)
        return taking[0]

    h.outbox.write_now = write_now
    h.publish(sub, "a")
    h.outbox.push('{"op":"status","level":"info","msg":"one"}')
    assert datas(written[:1]) == ["a"] and written[1:] == ['{"op":"status","level":"info","msg":"one"}']
    assert h.outbox.take(now=0.0) == ([], float("inf")) and h.wakes == 0
    taking[0] = False  # backed up: queued, the writer woken
    h.publish(sub, "b")
    taking[0] = True  # taking again, but "b" waits: "c" must not overtake it
    h.publish(sub, "c")
    h.outbox.push('{"op":"status","level":"info","msg":"two"}')
    frames, _ = h.outbox.take(now=0.0)
    assert frames[0] == '{"op":"status","level":"info","msg":"two"}' and datas(frames[1:]) == ["b", "c"]
    assert len(written) == 2 and h.wakes == 3
    throttled = h.subscription(throttle_ms=100)
    h.publish(throttled, "d")
    assert len(written) == 2 and datas(h.outbox.take(now=0.0)[0]) == ["d"]
