"""Pose round trip and flood throughput through the server, against a bare websockets relay in the same run.

One client publishes geometry_msgs/PoseStamped; a second, subscribed, receives it. Reported for each server:
latency p50/p99/max at 90 Hz, and sustained msgs/s when flooding with a bounded number in flight. Both servers
run as separate processes, so the clients (this process) do not share a core's GIL with them. The clients write
rosbridge frames by hand on purpose: the same bytes go to the server and to the relay, which knows no rosbridge,
and the figure is the raw wire's.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import websockets
from websockets.asyncio.client import connect

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from testbed.processes import free_port, start, stop  # noqa: E402

TOPIC = "/vr/head/pose"


def pose(seq: int) -> str:
    return json.dumps({"op": "publish", "topic": TOPIC, "msg": {
        "header": {"seq": seq, "stamp": {"secs": 0, "nsecs": 0}, "frame_id": "unity_left_handed"},
        "pose": {"position": {"x": 0.12, "y": 1.61, "z": 0.05},
                 "orientation": {"x": 0.01, "y": 0.2, "z": 0.0, "w": 0.98}}}})


class Server:
    def __init__(self, kind: str) -> None:
        self.port = free_port()
        cmd = ([sys.executable, "-m", "vr_teleop_server.cli", "serve", "--port", str(self.port), "--log-level", "warning",
                "--backend", "none"]
               if kind == "ours" else [sys.executable, str(ROOT / "bench" / "relay.py"), "--port", str(self.port)])
        self.proc = start(cmd)
        self.url = f"ws://127.0.0.1:{self.port}"

    def stop(self) -> None:
        stop(self.proc, 5)


async def setup(url: str, ours: bool):
    pub = await connect(url, compression=None, max_size=None)
    sub = await connect(url, compression=None, max_size=None)
    if ours:
        await sub.send(json.dumps({"op": "subscribe", "topic": TOPIC, "type": "geometry_msgs/PoseStamped"}))
        await pub.send(json.dumps({"op": "advertise", "topic": TOPIC, "type": "geometry_msgs/PoseStamped"}))
        await asyncio.sleep(0.3)
    return pub, sub


def seq_of(frame: str | bytes) -> int:
    return json.loads(frame)["msg"]["header"]["seq"]


async def latency(url: str, ours: bool, duration: float, rate: float, samples: bool = False):
    """Percentiles of the publish-to-receive delay (ms), or with `samples` the delays themselves."""
    pub, sub = await setup(url, ours)
    sent: dict[int, float] = {}
    delays: list[float] = []
    n = int(duration * rate)

    async def receive() -> None:
        while len(delays) < n:
            frame = await sub.recv()
            delays.append(time.perf_counter() - sent[seq_of(frame)])

    receiver = asyncio.create_task(receive())
    start = time.perf_counter()
    for i in range(n):
        await asyncio.sleep(max(0.0, start + i / rate - time.perf_counter()))
        sent[i] = time.perf_counter()
        await pub.send(pose(i))
    await asyncio.wait_for(receiver, 10)
    await pub.close()
    await sub.close()
    ms = np.array(delays) * 1000
    if samples:
        return list(ms)
    return {"p50_ms": float(np.percentile(ms, 50)), "p99_ms": float(np.percentile(ms, 99)), "max_ms": float(ms.max()),
            "n": len(ms)}


async def flood(url: str, ours: bool, duration: float, window: int, pid: int) -> tuple[float, float]:
    """Messages a second through the server, and the server process's CPU microseconds a message (the figure a
    busy machine moves least)."""
    pub, sub = await setup(url, ours)
    server = psutil.Process(pid)
    received = 0
    credit = asyncio.Semaphore(window)
    stop = time.perf_counter() + duration

    async def receive() -> None:
        nonlocal received
        while True:
            await sub.recv()
            received += 1
            credit.release()

    receiver = asyncio.create_task(receive())
    frames = [pose(i) for i in range(1000)]
    start = time.perf_counter()
    cpu = sum(server.cpu_times()[:2])
    i = 0
    while time.perf_counter() < stop:
        await credit.acquire()
        await pub.send(frames[i % 1000])
        i += 1
    elapsed = time.perf_counter() - start
    count = received
    cpu = sum(server.cpu_times()[:2]) - cpu
    receiver.cancel()
    await pub.close()
    await sub.close()
    return count / elapsed, cpu / max(count, 1) * 1e6


def machine() -> str:
    return (f"{os.cpu_count()} cores, Python {platform.python_version()}, websockets {websockets.__version__}, "
            f"{platform.machine()} {platform.system()}")


async def run(duration: float, rate: float, window: int, rounds: int = 1) -> None:
    """The relay and the server take turns `rounds` times, the order alternating, so that both see the same moments
    of a shared machine: latencies pooled, the flood's median."""
    samples: dict[str, list[float]] = {"relay": [], "ours": []}
    floods: dict[str, list[float]] = {"relay": [], "ours": []}
    cpus: dict[str, list[float]] = {"relay": [], "ours": []}
    for r in range(rounds):
        for kind in (("relay", "ours") if r % 2 == 0 else ("ours", "relay")):
            server = Server(kind)
            try:
                samples[kind] += await latency(server.url, kind == "ours", duration, rate, samples=True)
                rate_, cpu = await flood(server.url, kind == "ours", duration, window, server.proc.pid)
                floods[kind].append(rate_)
                cpus[kind].append(cpu)
            finally:
                server.stop()
    results = {kind: {"p50_ms": float(np.percentile(samples[kind], 50)), "p99_ms": float(np.percentile(samples[kind], 99)),
                      "max_ms": float(np.max(samples[kind])), "msgs_per_s": float(np.median(floods[kind])),
                      "cpu_us": float(np.median(cpus[kind]))}
               for kind in samples}
    ours, relay = results["ours"], results["relay"]
    print(f"# roundtrip: PoseStamped at {rate:g} Hz for {duration:g} s, then flooding with {window} in flight "
          f"for {duration:g} s; {rounds} round(s), taking turns\n# machine: {machine()}")
    print(f"{'figure':<22}{'vr-teleop':>12}{'bare relay':>12}{'ratio':>8}")
    for key, label in (("p50_ms", "latency p50 (ms)"), ("p99_ms", "latency p99 (ms)"), ("max_ms", "latency max (ms)"),
                       ("msgs_per_s", "flood (msgs/s)"), ("cpu_us", "server CPU/msg (us)")):
        print(f"{label:<22}{ours[key]:>12.3f}{relay[key]:>12.3f}{ours[key] / relay[key]:>8.2f}")
    if rounds > 1:
        print("flood per round (msgs/s), ours / relay: "
              + ", ".join(f"{o:.0f} / {b:.0f}" for o, b in zip(floods["ours"], floods["relay"])))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--duration", type=float, default=10.0, help="seconds per measurement (default 10)")
    parser.add_argument("--rate", type=float, default=90.0, help="pose rate in Hz (default 90)")
    parser.add_argument("--window", type=int, default=50, help="messages in flight when flooding (default 50)")
    parser.add_argument("--rounds", type=int, default=1, help="turns each server takes, alternating (default 1)")
    parser.add_argument("--quick", action="store_true", help="2 s per measurement")
    args = parser.parse_args()
    asyncio.run(run(2.0 if args.quick else args.duration, args.rate, args.window, args.rounds))


if __name__ == "__main__":
    main()
