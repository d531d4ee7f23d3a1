"""The benchmark suite behind `make bench`: every figure with its same-run baseline and the ratio, in one table.

Servers run as their own processes (`vr-teleop serve`, bench/relay.py); the clients are this process.
- pose round trip: PoseStamped at 90 Hz from one client to a subscribed other, p50 and p99, against the bare
  websockets relay (frames passed between the two clients unparsed);
- sustained msgs/s, publish to subscribe, with 1 and 10 subscribers and a bounded number in flight (every
  subscriber must have received a message before it counts as delivered), against the relay's fan-out; the relay
  and the server take turns three times and each one's median counts (this machine is shared and noisy);
- pose to head command: a head pose in, the joint command explicit control makes of it out, against a bare echo;
- camera: fps received and frame age on arrival for 1 and 5 subscribers, against the rate asked of the stand-in
  (30 fps at 640x480) and, for 5, against the 1-subscriber figures;
- soak: the server's resident memory with one stalled subscriber while a headset streams and a 10 KB topic flows,
  end against start (`--quick`: 60 s, else 10 minutes), and the reading subscriber's rate against the publish rate;
- churn: 20 clients connecting and disconnecting (dropping half of their connections) for 20 s (`--quick`) or a
  minute, in-process so that tasks, bus subscriptions and descriptors can be counted: after against before;
- replay: the synthesised 5-minute classroom session replayed at x10 against the session's own length / 10
  (`--quick`: its first 60 s).

The clients here write rosbridge frames by hand on purpose: the figures are the raw wire's (the same bytes sent to
our server and to the bare relay, which knows no rosbridge), a stalled reader's socket, and the churn visitor's
worst case (testbed/churn.py). The replay row drives the server with the package's client (tools/replay.py).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import random
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil
import websockets
from websockets.asyncio.client import connect

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path[:0] = [str(HERE), str(ROOT)]

import roundtrip
import teleop
from testbed.processes import free_port, serve, start, stop

CAMERA = "/camera/color/image_raw/compressed"


class Row:
    def __init__(self, figure: str, value: float, baseline: float | None, base_name: str, unit: str,
                 better: str = "lower") -> None:
        self.figure, self.value, self.baseline, self.base_name, self.unit, self.better = \
            figure, value, baseline, base_name, unit, better

    def line(self) -> str:
        ratio = f"{self.value / self.baseline:6.2f}x" if self.baseline else "     -"
        base = f"{self.baseline:10.2f}" if self.baseline is not None else "         -"
        return f"| {self.figure:<56} | {self.value:10.2f} | {base} | {ratio} | {self.unit:<8} | {self.base_name}"


# ---- publish to subscribe -------------------------------------------------------------------------------------
async def fan_out(url: str, ours: bool, subscribers: int, duration: float, window: int) -> float:
    """Messages a second that reached every subscriber, with at most `window` on their way to the slowest."""
    pub = await connect(url, compression=None, max_size=None)
    subs = [await connect(url, compression=None, max_size=None) for _ in range(subscribers)]
    if ours:
        for s in subs:
            await s.send(json.dumps({"op": "subscribe", "topic": roundtrip.TOPIC, "type": "geometry_msgs/PoseStamped",
                                     "queue_length": 10 * window}))
        await pub.send(json.dumps({"op": "advertise", "topic": roundtrip.TOPIC, "type": "geometry_msgs/PoseStamped"}))
        await asyncio.sleep(0.5)
    counts = [0] * subscribers
    progress = asyncio.Event()

    async def receive(k: int) -> None:
        async for _ in subs[k]:
            counts[k] += 1
            progress.set()

    receivers = [asyncio.create_task(receive(k)) for k in range(subscribers)]
    frames = [roundtrip.pose(i) for i in range(1000)]
    sent = 0
    start = time.perf_counter()
    stop_at = start + duration
    while time.perf_counter() < stop_at:
        while sent - min(counts) >= window:
            progress.clear()
            try:
                await asyncio.wait_for(progress.wait(), 5)
            except TimeoutError:  # a message was dropped on the way: stop counting here
                stop_at = 0
                break
        await pub.send(frames[sent % 1000])
        sent += 1
    elapsed = time.perf_counter() - start
    delivered = min(counts)
    await asyncio.gather(*(ws.close() for ws in [pub, *subs]))  # the receivers read on until the close frames
    for r in receivers:
        r.cancel()
    return delivered / elapsed


async def pubsub_rows(duration: float, window: int, rounds: int = 3) -> list[Row]:
    """The relay and our server take turns, `rounds` times: on a shared machine a burst of someone else's load
    then falls on both alike. Throughput is each one's median round; latency percentiles pool every round."""
    runs: dict[str, dict[str, list[float]]] = {kind: {"delays": [], "one": [], "ten": []} for kind in ("relay", "ours")}
    for _ in range(rounds):
        for kind in ("relay", "ours"):
            server = roundtrip.Server(kind)
            try:
                await asyncio.sleep(0.3)
                runs[kind]["delays"] += await roundtrip.latency(server.url, kind == "ours", duration, 90.0,
                                                                samples=True)
                runs[kind]["one"].append(await fan_out(server.url, kind == "ours", 1, duration, window))
                runs[kind]["ten"].append(await fan_out(server.url, kind == "ours", 10, duration, window))
            finally:
                server.stop()
    figures = {kind: {"p50_ms": float(np.percentile(r["delays"], 50)), "p99_ms": float(np.percentile(r["delays"], 99)),
                      "one": float(np.median(r["one"])), "ten": float(np.median(r["ten"]))}
               for kind, r in runs.items()}
    o, r = figures["ours"], figures["relay"]
    n = len(runs["ours"]["delays"])
    return [Row(f"pose round trip p50, 90 Hz ({n} poses)", o["p50_ms"], r["p50_ms"], "bare relay", "ms"),
            Row("pose round trip p99, 90 Hz", o["p99_ms"], r["p99_ms"], "bare relay", "ms"),
            Row(f"publish->subscribe, 1 subscriber ({window} in flight)", o["one"], r["one"], "bare relay",
                "msg/s", "higher"),
            Row(f"publish->subscribe, 10 subscribers (each, median of {rounds})", o["ten"], r["ten"], "relay fan-out",
                "msg/s", "higher")]


# ---- explicit control over the wire ---------------------------------------------------------------------------
def teleop_rows(duration: float) -> list[Row]:
    ours = serve("--backend", "sim")
    echo_port = free_port()
    echo = start([sys.executable, str(HERE / "relay.py"), "--echo", "--port", str(echo_port)])
    try:
        lat, base = asyncio.run(teleop.wire_latency(ours.url, f"ws://127.0.0.1:{echo_port}", duration))
    finally:
        stop(ours)
        stop(echo)
    return [Row("head pose -> head command p50, 90 Hz", float(np.percentile(lat, 50)),
                float(np.percentile(base, 50)), "bare echo", "ms"),
            Row("head pose -> head command p99, 90 Hz", float(np.percentile(lat, 99)),
                float(np.percentile(base, 99)), "bare echo", "ms")]


# ---- camera -----------------------------------------------------------------------------------------------------
async def camera(url: str, subscribers: int, duration: float) -> tuple[float, float]:
    """Mean fps received per subscriber and the median frame age on arrival (ms)."""
    subs = [await connect(url, compression=None, max_size=None) for _ in range(subscribers)]
    for s in subs:
        await s.send(json.dumps({"op": "subscribe", "topic": CAMERA, "type": "sensor_msgs/CompressedImage"}))
    for s in subs:
        await asyncio.wait_for(s.recv(), 20)  # the first frame pays for warm-up
    arrivals: list[list[float]] = [[] for _ in subs]
    ages: list[float] = []

    async def receive(k: int) -> None:
        async for raw in subs[k]:
            now = time.time()
            stamp = json.loads(raw)["msg"]["header"]["stamp"]
            arrivals[k].append(time.monotonic())
            ages.append((now - (stamp["secs"] + stamp["nsecs"] * 1e-9)) * 1000)

    tasks = [asyncio.create_task(receive(k)) for k in range(subscribers)]
    await asyncio.sleep(duration)
    await asyncio.gather(*(s.close() for s in subs))
    for t in tasks:
        t.cancel()
    fps = [(len(a) - 1) / (a[-1] - a[0]) for a in arrivals if len(a) > 1]
    return float(np.mean(fps)) if fps else 0.0, float(np.median(ages)) if ages else float("nan")


def camera_rows(duration: float) -> list[Row]:
    server = serve("--backend", "sim", "--camera-size", "640x480", "--camera-fps", "30")
    try:
        fps1, age1 = asyncio.run(camera(server.url, 1, duration))
        fps5, age5 = asyncio.run(camera(server.url, 5, duration))
    finally:
        stop(server)
    return [Row("camera 640x480, 1 subscriber: fps", fps1, 30.0, "30 fps asked", "fps", "higher"),
            Row("camera 640x480, 1 subscriber: frame age p50", age1, None, "-", "ms"),
            Row("camera 640x480, 5 subscribers: fps (each)", fps5, fps1, "1 subscriber", "fps", "higher"),
            Row("camera 640x480, 5 subscribers: frame age p50", age5, age1, "1 subscriber", "ms")]


# ---- soak with a stalled client ---------------------------------------------------------------------------------
async def soak(url: str, pid: int, duration: float) -> tuple[float, float, float, float]:
    """(RSS MiB after warm-up, RSS MiB at the end, messages the reader got, messages published)."""
    proc = psutil.Process(pid)
    stalled = await connect(url, compression=None, max_size=None, max_queue=1)
    reader = await connect(url, compression=None, max_size=None)
    pub = await connect(url, compression=None, max_size=None)
    for ws in (stalled, reader):
        await ws.send(json.dumps({"op": "subscribe", "topic": "/soak/blob", "type": "std_msgs/String"}))
        await ws.send(json.dumps({"op": "subscribe", "topic": roundtrip.TOPIC, "type": "geometry_msgs/PoseStamped"}))
    await pub.send(json.dumps({"op": "advertise", "topic": "/soak/blob", "type": "std_msgs/String"}))
    await asyncio.sleep(0.5)
    # the stalled client never reads: its socket and queue fill, then the server drops its oldest messages
    got = 0

    async def read() -> None:
        nonlocal got
        async for raw in reader:
            if '"/soak/blob"' in raw:
                got += 1

    reading = asyncio.create_task(read())
    blob = json.dumps({"op": "publish", "topic": "/soak/blob", "msg": {"data": "z" * 10_000}})
    start = time.monotonic()
    warm_rss = None
    published = 0
    i = 0
    while time.monotonic() - start < duration:
        await pub.send(roundtrip.pose(i))
        if i % 3 == 0:
            await pub.send(blob)
            published += 1
        i += 1
        if warm_rss is None and time.monotonic() - start > min(30.0, duration / 4):
            warm_rss, got_at_warm, published_at_warm = proc.memory_info().rss, got, published
        await asyncio.sleep(max(0.0, start + i / 90 - time.monotonic()))
    await asyncio.sleep(1.0)
    end_rss = proc.memory_info().rss
    reading.cancel()
    for ws in (reader, pub):
        await ws.close()
    stalled.transport.abort()
    return warm_rss / 2**20, end_rss / 2**20, got - got_at_warm, published - published_at_warm


def soak_rows(duration: float) -> list[Row]:
    server = serve("--backend", "none")
    try:
        warm, end, got, published = asyncio.run(soak(server.url, server.pid, duration))
    finally:
        stop(server)
    return [Row(f"soak {duration:g} s, 1 stalled client: server RSS", end, warm, "RSS after warm-up", "MiB"),
            Row("soak: 10 KB messages the reader got", got, published, "published", "msgs", "higher")]


# ---- churn ------------------------------------------------------------------------------------------------------
def churn_rows(seconds: float) -> list[Row]:
    from testbed.churn import owner_counts, visitor
    from testbed.server import RunningServer
    from vr_teleop_server.settings import ServerSettings

    server = RunningServer(ServerSettings(port=0, backend="none"))
    app = server.server

    async def visits(duration: float) -> dict[str, int]:
        stats = {"visits": 0, "aborted": 0}
        end = time.monotonic() + duration
        await asyncio.gather(*(visitor(server.url, n, end, random.Random(n), stats) for n in range(20)))
        return stats

    try:
        asyncio.run(visits(1.0))
        time.sleep(2.0)
        before = server.call(lambda: owner_counts(app))
        stats = asyncio.run(visits(seconds))
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and server.call(lambda: owner_counts(app))["sessions"]:
            time.sleep(0.1)
        time.sleep(1.0)
        after = server.call(lambda: owner_counts(app))
    finally:
        server.stop()
    rows = [Row(f"churn {seconds:g} s, 20 clients: visits", stats["visits"], None, "-", "visits", "higher")]
    for key, label in (("tasks", "asyncio tasks"), ("subscriptions", "bus subscriptions"),
                       ("fds", "file descriptors"), ("sessions", "sessions")):
        rows.append(Row(f"churn: {label} after", after[key], before[key], "before", "count"))
    return rows


# ---- replay -----------------------------------------------------------------------------------------------------
def replay_rows(quick: bool, speed: float = 10.0) -> list[Row]:
    from testbed.sessions import classroom_steps
    from vr_teleop_server.tools.replay import report, run_replay

    steps = classroom_steps(60.0 if quick else None)
    with tempfile.TemporaryDirectory() as tmp:
        server = serve("--backend", "sim", "--gesture-dir", str(Path(tmp) / "g"), "--audio-dir", str(Path(tmp) / "a"))
        try:
            got, elapsed = asyncio.run(run_replay(steps, server.url, speed, camera=True, progress=False))
            r = report(steps, got, elapsed, speed)
        finally:
            stop(server)
    session = r["session_s"]
    return [Row(f"replay {session:.0f} s classroom at x{speed:g}: wall time", r["replay_s"], session / speed,
                f"session / {speed:g}", "s"),
            Row(f"replay at x{speed:g}: last command served after", r["served_s"] or 0.0, session / speed,
                f"session / {speed:g}", "s"),
            Row(f"replay at x{speed:g}: pose->command latency p99", r["latency_ms"]["p99"] or 0.0, None, "-", "ms")]


def machine() -> str:
    import mujoco
    import pydantic

    cpu = platform.processor() or platform.machine()
    return (f"{os.cpu_count()} cores ({cpu}), load {os.getloadavg()[0]:.2f}, Python {platform.python_version()}, "
            f"websockets {websockets.__version__}, pydantic {pydantic.__version__}, mujoco {mujoco.__version__}, "
            f"{platform.system()} {platform.release()}")


PART_ROWS = {
    "pubsub": "pose round trip and publish->subscribe, 1 and 10 subscribers, against the bare relay",
    "teleop": "pose to head command, against a bare echo",
    "camera": "camera fps and frame age, 1 and 5 subscribers",
    "soak": "server memory with a stalled client",
    "churn": "tasks, subscriptions, descriptors and sessions after 20 clients churn",
    "replay": "the classroom session replayed at x10",
}


def expected_s(name: str, quick: bool) -> float:
    """About how long a part runs: its measuring time (what main() passes it) plus start-up, from past runs."""
    return {
        "pubsub": 3 * 2 * 3 * (2.0 if quick else 10.0) + 3 * 2 * 2.0,  # rounds x servers x (latency, 1, 10 subs)
        "teleop": 2 * (5.0 if quick else 20.0) + 8.0,  # the echo baseline and ours, plus a sim server's start
        "camera": 2 * (4.0 if quick else 10.0) + 8.0,
        "soak": (60.0 if quick else 600.0) + 5.0,
        "churn": (20.0 if quick else 60.0) + 6.0,
        "replay": (60.0 if quick else 300.0) / 10.0 + 15.0,  # the session / 10, synthesis and a sim server
    }[name]


def _dur(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.1f} min"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="short runs (about 3 minutes in all)")
    parser.add_argument("--only", nargs="+", choices=["pubsub", "teleop", "camera", "soak", "churn", "replay"])
    args = parser.parse_args(argv)
    q = args.quick
    parts = {
        "pubsub": lambda: asyncio.run(pubsub_rows(2.0 if q else 10.0, 50)),
        "teleop": lambda: teleop_rows(5.0 if q else 20.0),
        "camera": lambda: camera_rows(4.0 if q else 10.0),
        "soak": lambda: soak_rows(60.0 if q else 600.0),
        "churn": lambda: churn_rows(20.0 if q else 60.0),
        "replay": lambda: replay_rows(q),
    }
    rows: list[Row] = []
    failed = []
    chosen = args.only or list(parts)
    total = sum(expected_s(name, q) for name in chosen)
    done = 0.0
    for i, name in enumerate(chosen, 1):
        # Progress on stderr (stdout is the table): which row, about how long it takes, how much is left.
        print(f"[{i}/{len(chosen)}] running {name}: {PART_ROWS[name]}; expected about {_dur(expected_s(name, q))} "
              f"({_dur(total - done)} left in all)", file=sys.stderr, flush=True)
        start = time.monotonic()
        try:
            rows += parts[name]()
        except Exception as exc:  # noqa: BLE001 (one broken figure must not hide the others)
            failed.append(f"{name}: {type(exc).__name__}: {exc}")
        done += expected_s(name, q)
        print(f"[{i}/{len(chosen)}] {name} took {_dur(time.monotonic() - start)}", file=sys.stderr, flush=True)
    print(f"\n# vr-teleop-server benchmarks{' (--quick)' if q else ''}, {time.strftime('%Y-%m-%d %H:%M')}")
    print(f"# machine: {machine()}")
    print(f"| {'figure':<56} | {'value':>10} | {'baseline':>10} | {'ratio':>7} | {'unit':<8} | baseline is")
    print(f"|{'-' * 58}|{'-' * 12}|{'-' * 12}|{'-' * 9}|{'-' * 10}|{'-' * 20}")
    for row in rows:
        print(row.line())
    for f in failed:
        print(f"# FAILED {f}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
