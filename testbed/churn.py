"""Clients that come and go: `visitor` connects, takes up subscriptions, advertisements, a service, pending calls and
half a fragment set, then leaves (cleanly or by dropping TCP), again and again; `owner_counts` is what a server holds
for its clients. tests/test_faults.py asserts that the counts come back after the churn; bench/suite.py prints them.

The visitor writes rosbridge frames by hand on purpose: it is the raw wire's worst case (a half fragment set, a
dropped connection, calls never answered), which no well-behaved client would send."""

from __future__ import annotations

import asyncio
import json
import os
import random
import time

from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed
from websockets.protocol import State

from .waiting import until


def owner_counts(app) -> dict[str, int]:
    """What a server holds per owner kind (call it on the server's loop): sessions, bus subscriptions, publishers,
    topics, services, actions, the process's asyncio tasks and file descriptors."""
    bus = app.bus
    return {"sessions": len(app.sessions),
            "subscriptions": sum(len(t.subscribers) for t in bus.topics.values()),
            "publishers": sum(len(t.publishers) for t in bus.topics.values()),
            "topics": len(bus.topics), "services": len(bus.services), "actions": len(bus.actions),
            "tasks": len(asyncio.all_tasks()), "fds": len(os.listdir("/proc/self/fd"))}


async def visitor(url: str, n: int, stop: float, rng: random.Random, stats: dict[str, int]) -> None:
    """Connects, takes up subscriptions, advertisements, a service, pending calls and half a fragment set, then
    leaves: cleanly or by dropping the TCP connection."""
    while time.monotonic() < stop:
        async with connect(url, compression=None, max_size=None, open_timeout=20) as ws:
            got = [0]
            reader = asyncio.create_task(drain(ws, got))
            mine = f"/churn/{n}"
            frames = [{"op": "subscribe", "id": "s", "topic": "/churn/shared", "type": "std_msgs/String"},
                      {"op": "subscribe", "id": "s2", "topic": mine, "type": "std_msgs/String",
                       "throttle_rate": 50, "queue_length": 3},
                      {"op": "advertise", "topic": "/churn/shared", "type": "std_msgs/String"},
                      {"op": "advertise_service", "service": f"{mine}/svc", "type": "std_srvs/Trigger"},
                      {"op": "advertise_action", "action": f"{mine}/act", "type": "fake/Act"},
                      {"op": "call_service", "id": "t", "service": "/rosapi/get_time"},
                      # a call to another visitor's service that may never be answered
                      {"op": "call_service", "id": "x", "service": f"/churn/{(n + 1) % 20}/svc", "timeout": 5},
                      {"op": "fragment", "id": "half", "data": "{\"op\":", "num": 0, "total": 2}]
            for frame in frames:
                await ws.send(json.dumps(frame))
            published = rng.randrange(1, 20)
            for i in range(published):
                await ws.send(json.dumps({"op": "publish", "topic": "/churn/shared", "msg": {"data": str(i)}}))
            # A random stay, counted in the frames the server sends it (the shared topic brings its own messages
            # back, among the others'), not in seconds: it leaves with some still on their way.
            stay = rng.randrange(0, published + 1)
            await until(lambda: got[0] >= stay or ws.state is not State.OPEN, 30)
            if rng.random() < 0.5:
                ws.transport.abort()  # gone without a closing handshake
                stats["aborted"] += 1
            stats["visits"] += 1
        await reader


async def drain(ws, got: list[int] | None = None) -> None:
    """Reads whatever comes, counting the frames in `got[0]`."""
    try:
        async for _frame in ws:
            if got is not None:
                got[0] += 1
    except ConnectionClosed:  # the visitor dropped the connection itself
        pass
