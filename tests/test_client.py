"""The package's rosbridge client (vr_teleop_server/client) against a real server: over a WebSocket, and over the
in-process connection on a simulated clock, with the same calls."""

from __future__ import annotations

import asyncio

import pytest

from client_protocol import names
from simclock import SimulatedClock
from simclock import run as run_on_clock
from testbed.server import in_loop
from vr_teleop_server.client import CallFailed, Client, Refused, connect, outcome


async def _exercise(client: Client) -> None:
    """What every caller relies on: typed calls, the refusal rule, subscriptions, and sync()."""
    now = await client.call(names.ROSAPI_GET_TIME_SERVICE)
    assert set(now["time"]) == {"secs", "nsecs"}  # validated against rosapi/GetTime's response: ROS 1 time

    with pytest.raises(Refused) as refusal:  # not an SDP offer: refused inside a successful response
        await client.call(names.MEDIA_OFFER_SERVICE, {"sdp": "not an offer", "type": "offer"})
    assert "malformed SDP" in refusal.value.message and refusal.value.values["success"] is False
    with pytest.raises(CallFailed):
        await client.call("/no/such/service")

    topic = "/client_test/chatter"
    sub = await client.subscribe(topic, "std_msgs/String")
    seen: list[dict] = []
    await client.subscribe(topic, "std_msgs/String", seen.append)
    await client.advertise(topic, "std_msgs/String")
    await client.sync()  # both subscriptions are the server's now: nothing published next is missed
    for text in ("one", "two", "three"):
        await client.publish(topic, {"data": text})
    assert await sub.next() == {"data": "one"}
    assert await sub.next(lambda m: m["data"] == "three") == {"data": "three"}  # "two" read and passed over
    assert [m["data"] for m in seen] == ["one", "two", "three"]
    await sub.unsubscribe()


async def test_over_a_websocket():
    async with in_loop() as server:
        async with await connect(server.url) as client:
            await _exercise(client)


def test_over_the_in_process_connection_on_the_simulated_clock():
    clock = SimulatedClock()

    async def main() -> float:
        # A stand-in's, with nothing of its own to do (no pupils talking, no attention rendering the camera for its
        # face detector): the simulated minute below then passes at once.
        async with in_loop(clock=clock, backend="sim", bystander_interval=0) as server:
            async with Client(server.transport.connect_local()) as client:
                await _exercise(client)
                started = clock.monotonic()
                with pytest.raises(TimeoutError):  # a wait with no answer ends on the loop's (simulated) clock
                    sub = await client.subscribe("/client_test/silent", "std_msgs/String")
                    await sub.next(timeout=60.0)
                waited = clock.monotonic() - started
                # A call the server cannot take (args must be an object) is answered by a status error only: the
                # call fails with its message once the wait ends (simulated: no wall-clock window).
                with pytest.raises(CallFailed, match="call_service"):
                    await client.call(names.ROSAPI_GET_TIME_SERVICE, "not an object")  # type: ignore[arg-type]
                await client.sync()  # and the connection still works
                return waited

    assert run_on_clock(main(), clock) == pytest.approx(60.0, abs=0.1)  # not sooner, and no wall-clock wait


def test_the_refusal_rule():
    assert outcome({"op": "service_response", "result": True, "values": {"success": True}}) == {"success": True}
    with pytest.raises(Refused, match="busy"):
        outcome({"result": True, "values": {"success": False, "message": "busy"}}, "/x")
    with pytest.raises(Refused):  # LuxAI's services say status
        outcome({"result": True, "values": {"status": False}})
    with pytest.raises(CallFailed, match="no such service"):
        outcome({"result": False, "values": "no such service"})


async def test_a_closed_connection_fails_the_waits():
    async with in_loop() as server:
        client = await connect(server.url)
        sub = await client.subscribe("/client_test/chatter", "std_msgs/String")
        waiting = asyncio.ensure_future(sub.next())
        await server.stop()
        await client.wait_closed()
        with pytest.raises(ConnectionError):
            await waiting
        await client.close()

