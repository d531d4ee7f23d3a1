"""Explicit control across the emulated WAN (netem/): the server in the server namespace, the operator replayed from
the client namespace, an observer beside the server. Shared by tests/test_netem.py and bench/wan.py.

- `serve(net)`: `python -m vr_teleop_server.cli serve --backend sim --insecure` bound to the server namespace's
  address (open access: the replay client has no token support; --insecure lets an open server bind a
  non-loopback address, and nothing but our own client namespace can reach it).
- `Observer`: the package's rosbridge client inside the server namespace (no impairment between it and the
  server), recording every head command and teleop event with its receive time: the server's own view of what the
  robot was told.
- `replay_in(net, steps, url)`: `vr-teleop replay`'s client, run inside the client namespace.
"""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from client_protocol import names
from netem import Emulator
from testbed.processes import environment
from testbed.waiting import wait_for
from vr_teleop_server.tools.replay import Collected, PoseRoad, Step, expected_commands, run_replay

PORT = 9090  # the namespace is ours alone: a fixed port is free
# The observer's start: a Python process importing numpy, pydantic and the replay tool, which on a 2-core machine
# loaded many times over took 40 s; it says "ready" once subscribed, or exits.
READY_TIMEOUT_S = 120.0
HEAD_COMMAND = "/qt_robot/head_position/command"
HEAD_POSE = "/vr/head/pose"
EVENTS = "/vr_teleop/events"
TELEMETRY = "/vr_teleop/telemetry"
ROOT = Path(__file__).resolve().parent.parent
# The server and the replayed headset run at this niceness, as the forwarder asks for real-time priority
# (netem/forwarder.py): what these runs measure is the link, and a headset or a server starved by the test suite's
# other worker on a 2-core machine is the host's (a real headset is a device of its own).
NICE = -10


def serve(net: Emulator, *extra: str, start_timeout: float = 120.0, env: dict[str, str] | None = None) -> str:
    """Starts the server in the server namespace and returns its URL once it listens (the emulator stops it);
    `env`: more environment (SSL_CERT_FILE to trust a self-signed relay). Teleoperated unless `extra` asks for an
    autonomy level, as the harness's other servers (testbed/server.py): the head commands these tests judge are the
    operator's, and attention turning the head before anyone engages is not what a link test measures."""
    log = tempfile.NamedTemporaryFile("w+", prefix="wan-serve-", suffix=".log", delete=False)
    env = environment(**(env or {}))
    autonomy = () if "--autonomy" in extra else ("--autonomy", "teleoperated")
    proc = net.popen("server", ["nice", "-n", str(NICE), sys.executable, "-m", "vr_teleop_server.cli", "serve",
                                "--host", net.server_ip,
                                "--port", str(PORT), "--insecure", "--backend", "sim", "--log-level", "warning",
                                *autonomy, *extra], stdout=subprocess.PIPE, stderr=log, text=True, env=env, cwd=ROOT)
    result: dict[str, str] = {}

    def wait_line() -> None:
        for line in proc.stdout:
            if "listening on" in line:
                result["url"] = line.split("listening on", 1)[1].strip()
                return

    reader = threading.Thread(target=wait_line, daemon=True)
    reader.start()
    reader.join(start_timeout)
    if "url" not in result:
        log.seek(0)
        raise RuntimeError(f"the server did not start in the server namespace: {log.read()[-2000:]}")
    return result["url"]


@dataclass
class Observed:
    head: list[tuple[float, list[float]]] = field(default_factory=list)  # receive time (monotonic), [yaw, pitch]
    events: list[tuple[float, dict[str, Any]]] = field(default_factory=list)  # receive time, event (detail parsed)
    poses: list[tuple[float, float]] = field(default_factory=list)  # receive time, header stamp (s) of head poses
    render_times: dict[int, float] = field(default_factory=dict)  # video RTP timestamp -> render time (telemetry)
    channel: dict[str, int] = field(default_factory=dict)  # the newest telemetry's poses-channel counts (dc_*)

    def kinds(self) -> list[str]:
        return [e["kind"] for _t, e in self.events]


class Observer:
    """Watches head commands, events (and with `poses`, head poses) from inside the server namespace until stop().

    It is a process of its own (this file run as a script), so the replay client's work in this process does not
    delay its receive times; CLOCK_MONOTONIC is the machine's, so its times compare with the replay's."""

    def __init__(self, net: Emulator, url: str, poses: bool = False) -> None:
        self.got = Observed()
        self._out = tempfile.NamedTemporaryFile("w+", prefix="wan-observer-", suffix=".jsonl", delete=False)
        env = environment()
        self._proc = net.popen("server", [sys.executable, __file__, url, "1" if poses else "0"],
                               stdout=self._out, stdin=subprocess.PIPE, env=env, cwd=ROOT)
        def ready_or_gone() -> bool:
            self._out.seek(0)
            return self._out.readline().strip() == '"ready"' or self._proc.poll() is not None

        if not wait_for(ready_or_gone, READY_TIMEOUT_S) or self._proc.poll() is not None:
            raise RuntimeError("the observer could not subscribe")

    def stop(self) -> Observed:
        """Once the observer has read everything the server sent it before now (it answers "synced" after the
        server's answer to a call made now: the server sends in order), stops it and returns what it saw."""
        self._proc.stdin.write(b"sync\n")
        self._proc.stdin.flush()

        def synced_or_gone() -> bool:
            with open(self._out.name, "rb") as out:
                out.seek(max(0, out.seek(0, os.SEEK_END) - 64))
                return b'"synced"' in out.read() or self._proc.poll() is not None

        if not wait_for(synced_or_gone, READY_TIMEOUT_S) or self._proc.poll() is not None:
            raise RuntimeError("the observer did not answer")
        self._proc.stdin.close()  # it stops when its stdin closes
        self._proc.wait(10)
        self._out.seek(0)
        for line in self._out.read().splitlines()[1:-1]:  # between "ready" and "synced"
            kind, t, value = json.loads(line)
            if kind == "head":
                self.got.head.append((t, value))
            elif kind == "pose":
                self.got.poses.append((t, value))
            elif kind == "frames":
                self.got.render_times.update((rtp, render) for rtp, render in value)
            elif kind == "channel":
                self.got.channel = value
            else:
                self.got.events.append((t, value))
        self._out.close()
        os.unlink(self._out.name)
        return self.got


async def _observe(url: str, poses: bool) -> None:
    """Prints "ready" once the server has the subscriptions, then one JSON line per head command, event, head pose
    or telemetry report's video frames ([RTP timestamp, render time] pairs): [kind, receive time, value]. The
    receive time is taken as the package's client hands the message over, as it reads the frame. A line on stdin
    asks for "synced", printed last, once the server has answered a call made then."""
    from vr_teleop_server.client import connect

    loop = asyncio.get_running_loop()
    closed = threading.Event()  # set from the thread that reads stdin, seen at once by the callbacks
    syncs: asyncio.Queue[None] = asyncio.Queue()

    def read_stdin() -> None:
        for _line in sys.stdin:
            loop.call_soon_threadsafe(syncs.put_nowait, None)
        closed.set()

    stdin_closed = loop.run_in_executor(None, read_stdin)
    out = sys.stdout

    def write(line: list[Any]) -> None:
        # After stop() nothing more is written: the client may still be reading a backlog (a loaded machine), which
        # it then drains without the work, so that the loop comes round to closing.
        if not closed.is_set():
            print(json.dumps(line), file=out)

    def head(msg: dict[str, Any]) -> None:
        write(["head", time.monotonic(), list(msg["data"])])

    def pose(msg: dict[str, Any]) -> None:
        now, stamp = time.monotonic(), msg["header"]["stamp"]
        write(["pose", now, stamp.get("secs", stamp.get("sec", 0)) + stamp.get("nsecs", stamp.get("nanosec", 0)) / 1e9])

    def telemetry(msg: dict[str, Any]) -> None:
        now, clients = time.monotonic(), msg["clients"]
        write(["frames", now, [[rtp, render] for c in clients
                               for rtp, render in zip(c["frame_rtp_timestamps"], c["frame_render_times"])]])
        counts = {k: sum(c.get(k, 0) for c in clients) for k in ("dc_received", "dc_refused", "dc_stale_dropped")}
        if counts["dc_received"]:
            write(["channel", now, counts])

    def event(msg: dict[str, Any]) -> None:
        if msg.get("source") != "teleop":
            return
        now, event = time.monotonic(), dict(msg)
        try:
            event["detail"] = json.loads(event.get("detail") or "{}")
        except ValueError:
            pass
        write(["event", now, event])

    async with await connect(url, id_prefix="observer") as client:
        await client.subscribe(HEAD_COMMAND, callback=head, queue_length=100_000)
        await client.subscribe(EVENTS, callback=event, queue_length=10_000)
        await client.subscribe(TELEMETRY, callback=telemetry, queue_length=1_000)
        if poses:
            await client.subscribe(HEAD_POSE, callback=pose, queue_length=100_000)
        # The server has the subscriptions once it answers a later call (it handles a client's frames in order);
        # the answer's values are not read, which spares this process the message types' registry.
        await (await client.request(names.ROSAPI_GET_TIME_SERVICE))
        print(json.dumps("ready"), file=out, flush=True)

        async def sync() -> None:
            await syncs.get()
            # The answer comes after every message the server sent before it, each handed to its callback; what
            # comes after it is not written, so that "synced" is the last line.
            await (await client.request(names.ROSAPI_GET_TIME_SERVICE))
            closed.set()
            print(json.dumps("synced"), file=out, flush=True)

        syncing = asyncio.ensure_future(sync())
        await asyncio.wait([stdin_closed, asyncio.ensure_future(client.wait_closed())],
                           return_when=asyncio.FIRST_COMPLETED)
        syncing.cancel()
    out.flush()


def replay_in(net: Emulator, steps: list[Step], url: str, speed: float = 1.0,
              road: PoseRoad | None = None) -> tuple[Collected, float]:
    """The replay client inside the client namespace: every pose and call goes through the impaired link. With a
    road (testbed/media_client.py's ChannelRoad), the operator's streams take the poses data channel once it holds control;
    the road's peer connection is made inside the namespace too (its sockets are the thread's)."""
    def replay() -> Collected:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), NICE)  # this thread alone (Linux: per thread)
        return asyncio.run(run_replay(steps, url, speed, camera=False, progress=False, road=road))

    return net.run_in("client", replay)


def intent_errors(steps: list[Step], got: Collected, seen: Observed, rate_hz: float = 30.0,
                  delay_s: float = 0.0) -> np.ndarray:
    """How far the robot's head was told to be from where the operator meant it, sampled `rate_hz` times a second
    from the first head command to the last head pose sent: degrees, the larger of yaw and pitch. The command at a
    moment is the newest the server had sent (while it holds, the one it holds at); the intent is what the same
    mapping computes offline from the poses at the moments the operator sent them (so filter and velocity caps are
    in the intent, and the network's delay, holds and bursts are what the error shows). With `delay_s`, the command
    at t is held against the intent at t - delay_s: the measure of time-delayed teleoperation, x_robot(t) against
    x_operator(t - T), which leaves out the link's fixed one-way delay T (no transport removes it) and keeps its
    jitter, queueing, losses and holds."""
    expected = expected_commands(steps, got)
    sent = sorted((t, i) for t, i in got.sent_head if "head" in expected.get(i, {}))
    if not sent or not seen.head:
        return np.zeros(0)
    sent_t = np.array([t for t, _i in sent])
    intent = np.array([expected[i]["head"] for _t, i in sent])
    command_t = np.array([t for t, _c in seen.head])
    commands = np.array([c for _t, c in seen.head])
    grid = np.arange(max(command_t[0], sent_t[0] + delay_s), sent_t[-1] + delay_s, 1.0 / rate_hz)
    k_intent = np.searchsorted(sent_t, grid - delay_s, side="right") - 1
    k_command = np.searchsorted(command_t, grid, side="right") - 1
    return np.abs(commands[k_command] - intent[k_intent]).max(axis=1)


def pose_latencies(steps: list[Step], got: Collected, seen: Observed) -> np.ndarray:
    """Pose-to-command latency (s) per head pose that reached the server: from the operator sending it to the bus
    getting it, which is when the server steps on it and publishes its command (in the same callback)."""
    sent_at = {}
    for t, i in got.sent_head:
        stamp = steps[i].payload["header"]["stamp"]
        sent_at[round(stamp.get("secs", 0) + stamp.get("nsecs", 0) / 1e9, 6)] = t
    return np.array([t - sent_at[key] for t, stamp in seen.poses if (key := round(stamp, 6)) in sent_at])


if __name__ == "__main__":
    asyncio.run(_observe(sys.argv[1], sys.argv[2] == "1"))
