"""Faults: incomplete fragment sets are collected, a client that stops reading costs bounded memory and slows
nobody, and clients that come and go leave nothing behind (tasks, subscriptions, services, file descriptors).

Memory is measured with tracemalloc (the server runs in this process, in its own thread): what the server holds
is the growth of traced memory, which the tests show to be large while fragments wait and small afterwards.
Durations are short here but for the churn (a minute, as the issue asks); `make bench` runs the long soak.
"""

from __future__ import annotations

import asyncio
import gc
import json
import os
import random
import subprocess
import threading
import time
import tracemalloc

import numpy as np
import psutil
import pytest
from support import RawClient, physics_ran, wait_for
from testbed import processes
from testbed.server import Pace
from testbed.churn import drain, owner_counts, visitor
from websockets.asyncio.client import connect
from websockets.sync.client import connect as sync_connect

from client_protocol import names

pytestmark = pytest.mark.slow  # a minute of churn, stalled clients, memory traced

MIB = 1024 * 1024
CHURN_SECONDS = float(os.environ.get("CHURN_SECONDS", "60"))  # the issue asks for a minute


@pytest.fixture
def traced():
    tracemalloc.start()
    yield
    tracemalloc.stop()


def traced_now() -> int:
    gc.collect()
    return tracemalloc.get_traced_memory()[0]


def fragment_sets(server) -> int:
    return server.call(lambda: sum(len(s.fragments) for s in server.server.sessions.values()))


def test_incomplete_fragment_sets_are_collected_and_memory_does_not_grow(servers, traced):
    server = servers(fragment_timeout=2.0)
    client = RawClient(server.url)
    client.send({"op": "set_level", "level": "warning"})
    piece = "x" * 16_000
    sets = 150

    def round_(n: int) -> tuple[int, int]:
        before = traced_now()
        for i in range(sets):  # two pieces of three, never the third
            for num in (0, 1):
                client.send({"op": "fragment", "id": f"r{n}-{i}", "data": piece, "num": num, "total": 3})
        assert wait_for(lambda: fragment_sets(server) == sets, 30), "the server did not hold every set"
        held = traced_now() - before
        expired = []
        while len(expired) < sets:
            message = client.recv(timeout=10)
            assert message["op"] == "status" and message["level"] == "warning", message
            assert "2 of 3 arrived" in message["msg"], message
            expired.append(message["id"])
        assert sorted(expired) == sorted(f"r{n}-{i}" for i in range(sets))
        assert fragment_sets(server) == 0
        return held, traced_now()

    base = traced_now()
    results = [round_(n) for n in range(3)]
    for held, after in results:
        assert held > 0.8 * sets * 2 * len(piece), f"held only {held} bytes: the measurement does not see the sets"
        assert after - base < 1 * MIB, f"{(after - base) / MIB:.1f} MiB stayed after the sets expired"
    assert results[-1][1] - results[0][1] < 0.5 * MIB, "memory grew from round to round"
    client.alive()
    client.close()


def test_a_client_that_stops_reading_costs_bounded_memory_and_slows_nobody(servers, traced):
    server = servers()
    topic, count, size = "/flood", 2400, 10_000
    stalled = sync_connect(server.url, compression=None, max_size=None, max_queue=4).__enter__()  # then stops reading
    stalled.send(json.dumps({"op": "subscribe", "topic": topic, "type": "std_msgs/String"}))
    watcher = RawClient(server.url)
    watcher.send({"op": "subscribe", "topic": topic, "type": "std_msgs/String"})
    publisher = RawClient(server.url)
    publisher.send({"op": "advertise", "topic": topic, "type": "std_msgs/String"})
    assert wait_for(lambda: server.call(lambda: len(server.server.bus.topics[topic].subscribers)) == 2)

    received: list[float] = []

    def watch() -> None:
        while len(received) < count:
            try:
                frame = watcher.recv_frame(timeout=10)
            except TimeoutError:
                return
            if json.loads(frame).get("topic") == topic:
                received.append(time.monotonic())

    reader = threading.Thread(target=watch, daemon=True)
    reader.start()
    body = "y" * size
    base = traced_now()
    start = time.monotonic()
    half = 0
    pace = Pace(800)  # about 800 messages a second
    for i in range(count):
        publisher.send({"op": "publish", "topic": topic, "msg": {"data": f"{i:06d}{body}"}})
        pace.wait()
        if i == count // 2:  # by now the socket's buffers and the stalled client's queue are full
            half = traced_now() - base
    sent_s = time.monotonic() - start
    reader.join(120)  # only catches a reader that stopped
    grown = traced_now() - base

    stalled_session = next(s for s in server.server.sessions.values() if s.subscriptions.get(topic)
                            and s.counters["dropped"] > 0)
    queued = server.call(lambda: len(stalled_session.subscriptions[topic].queue))
    assert queued <= server.settings.queue_bound
    # What stays is the stalled client's full queue (each message as its value, its JSON and its frame), no more:
    # the second half of the flood adds nothing.
    assert grown < 3 * server.settings.queue_bound * size + MIB, f"server memory grew by {grown / MIB:.1f} MiB"
    assert grown - half < 0.5 * MIB, f"memory kept growing: {half / MIB:.2f} MiB half-way, " \
                                      f"{grown / MIB:.2f} MiB at the end"
    assert len(received) == count, f"the reading client got {len(received)} of {count} messages"
    got_s = received[-1] - received[0]  # a speed figure, printed (bench/suite.py's soak row holds it to account)
    print(f"{count * size / MIB:.0f} MiB published in {sent_s:.1f} s, the reader's stream took {got_s:.1f} s; "
          f"server memory grew {half / MIB:.2f} MiB in the first half, {grown / MIB:.2f} MiB in all; the stalled client's queue held {queued}, "
          f"{stalled_session.counters['dropped']} dropped")
    watcher.alive()
    stalled.close()


def test_clients_coming_and_going_leak_nothing(server):
    app = server.server

    async def visits(seconds: float) -> dict[str, int]:
        stats = {"visits": 0, "aborted": 0}
        rng = random.Random(7)
        stop = time.monotonic() + seconds
        await asyncio.gather(*(visitor(server.url, n, stop, random.Random(rng.random()), stats) for n in range(20)))
        return stats

    def settled() -> dict[str, int]:
        return server.call(lambda: owner_counts(app))

    idle = settled()  # before any visitor came
    asyncio.run(visits(1.0))  # warm-up: lazily created things (rosapi topics, loop internals) now exist
    # The warm-up's visitors are gone once the server holds for clients what it held before them (topics, services
    # and descriptors aside: those may be the lazily created ones).
    left = ("sessions", "subscriptions", "publishers", "actions", "tasks")
    assert wait_for(lambda: all(settled()[k] == idle[k] for k in left), 30), (idle, settled())
    before = settled()
    stats = asyncio.run(visits(CHURN_SECONDS))
    def same(after: dict[str, int]) -> bool:  # descriptors may only be fewer: the warm-up's may still be closing
        return {**after, "fds": 0} == {**before, "fds": 0} and after["fds"] <= before["fds"]
    assert wait_for(lambda: same(settled()), 30), f"before {before}, after {settled()}"
    assert stats["visits"] >= 2 * CHURN_SECONDS and stats["aborted"] > 0, stats
    print(f"{stats['visits']} visits by 20 clients in {CHURN_SECONDS:g} s ({stats['aborted']} dropped without "
          f"closing); after them: {settled()}")


def test_an_operator_dropped_mid_motion_leaves_the_robot_holding_within_the_watchdog_time(servers):
    """The operator's TCP connection vanishes while the head sweeps: the joint targets given to the simulation
    stop changing within the watchdog time, and the head comes to rest."""
    from scipy.spatial.transform import Rotation

    server = servers(backend="sim")
    standin = server.server.robot.standin
    watchdog = server.settings.teleop.watchdog_timeout_s
    targets: list[tuple[float, float]] = []  # (when, HeadYaw target)
    original = standin.set_targets

    def recorded(t):
        if "HeadYaw" in t:
            targets.append((time.monotonic(), float(t["HeadYaw"])))
        return original(t)

    standin.set_targets = recorded

    def head(seq: int) -> str:
        yaw = 30 * np.sin(2 * np.pi * 0.5 * seq / 90)  # a sweep of +-30 degrees at 0.5 Hz
        q = Rotation.from_euler("Y", -yaw, degrees=True).as_quat()
        return json.dumps({"op": "publish", "topic": "/vr/head/pose", "msg": {
            "header": {"frame_id": "unity_left_handed"}, "pose": {"position": {"x": 0, "y": 1.6, "z": 0},
                                                      "orientation": dict(zip("xyzw", map(float, q)))}}})

    async def operate() -> float:
        ws = await connect(server.url, compression=None, max_size=None)
        reader = asyncio.create_task(drain(ws))
        seq = 0
        start = time.monotonic()
        pace = Pace(90)  # a headset's rate
        engaged = False
        while True:
            await ws.send(head(seq))
            seq += 1
            if seq == 20:
                await ws.send(json.dumps({"op": "call_service", "id": "e", "service": "/vr_teleop/control/engage",
                                          "args": {"data": True}}))
                engaged = True
            moving = [v for when, v in targets if when > start + 1.0]
            if engaged and len(moving) > 30 and max(moving) - min(moving) > 5:  # mid-sweep
                dropped = time.monotonic()
                ws.transport.abort()
                await reader
                return dropped
            assert time.monotonic() - start < 20, f"the head never followed: {targets[-5:]}"
            await pace.tick()

    dropped = asyncio.run(operate())
    assert physics_ran(standin, 1.5)  # the robot's own time, well past the watchdog's: a change would be in by now
    after = [(when, v) for when, v in targets if when > dropped]
    before = [v for when, v in targets if when <= dropped]
    changes = [when for (when, v), (_w, prev) in zip(after, [(0, before[-1])] + after) if abs(v - prev) > 1e-6]
    last_change = (changes[-1] - dropped) if changes else 0.0
    assert last_change <= watchdog + 0.3, f"targets still changed {last_change:.2f} s after the drop"
    first = standin.joint_positions()["HeadYaw"]
    assert physics_ran(standin, 0.3)  # what a head still on its way would have moved in
    assert abs(standin.joint_positions()["HeadYaw"] - first) < 0.5, "the head is still moving"
    print(f"last head target change {1000 * last_change:.0f} ms after the drop (watchdog {watchdog:g} s)")


def _serve_sim() -> tuple[subprocess.Popen, str]:
    proc = processes.serve("--backend", "sim", "--bystander-interval", "0", log_level="warning",
                           stderr=subprocess.PIPE)
    return proc, proc.url


def _render_worker(server: subprocess.Popen) -> psutil.Process:
    workers = [p for p in psutil.Process(server.pid).children() if "sim.render_process" in " ".join(p.cmdline())]
    assert len(workers) == 1, f"expected one render process under the server, found {workers}"
    return workers[0]


def _camera_frame(client: RawClient, timeout: float = 30.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        message = client.recv(timeout)
        if message.get("op") == "publish" and message.get("topic") == names.CAMERA_TOPIC:
            return message
    raise AssertionError("no camera frame")


def test_the_render_process_does_not_outlive_a_killed_server():
    server, url = _serve_sim()
    try:
        worker = _render_worker(server)
    finally:
        server.kill()  # no clean shutdown: the worker sees its socket close
        server.communicate()
    assert wait_for(lambda: not worker.is_running() or worker.status() == psutil.STATUS_ZOMBIE, 30), \
        "the render process outlived the server"


def test_a_crashed_render_process_closes_the_camera_and_leaves_the_server_and_robot_working():
    server, url = _serve_sim()
    log: list[str] = []

    def read_log() -> None:
        for line in server.stderr:
            log.append(line)

    reader = threading.Thread(target=read_log, daemon=True)
    reader.start()
    try:
        client = RawClient(url)
        client.send({"op": "subscribe", "topic": names.CAMERA_TOPIC, "type": "sensor_msgs/CompressedImage"})
        _camera_frame(client)
        _render_worker(server).kill()

        def camera_stopped() -> bool:  # a second without a frame: the camera is closed, not slow
            stop = time.monotonic() + 1.0
            while time.monotonic() < stop:
                try:
                    message = client.recv(0.2)
                except TimeoutError:
                    continue
                if message.get("topic") == names.CAMERA_TOPIC:
                    return False
            return True

        assert wait_for(camera_stopped, 60), "camera frames went on after the render process died"
        # The camera hears of the death when its request to the worker sees the socket close, which is when the
        # killed process has finished exiting: at nice +10 on a loaded machine that took more than the second
        # above (and the rest of this test), and the server said nothing once it was stopping. Wait for it.
        assert wait_for(lambda: any("camera is closed" in line for line in log), 60), "".join(log)
        client.send({"op": "unsubscribe", "topic": names.CAMERA_TOPIC})
        client.alive()  # the server still serves this connection
        client.send({"op": "subscribe", "topic": names.JOINT_STATE_TOPIC, "type": "sensor_msgs/JointState"})
        client.send({"op": "publish", "topic": names.HEAD_COMMAND_TOPIC, "msg": {"data": [25.0, 0.0]}})

        def head_yaw() -> float:
            while True:
                message = client.recv(5)
                if message.get("topic") == names.JOINT_STATE_TOPIC:
                    state = message["msg"]
                    return state["position"][state["name"].index("HeadYaw")]

        assert wait_for(lambda: abs(head_yaw() - 25.0) < 1.0, 30), "the robot stopped following commands"
        client.close()
    finally:
        server.terminate()
        server.wait(30)
        reader.join(10)
    err = "".join(log)
    assert "render process" in err and "camera is closed" in err, err
