"""The emulator's forwarder process: two TUN devices, one moved into each namespace, and every IPv4 packet read from
one written to the other when its direction's impairment (model.py) says so.

Run by netem.emulator as `python -m netem.forwarder SPEC_JSON`. It prints one JSON line when both devices exist
(`{"ready": true}`), then answers JSON commands read from stdin, one a line:
    {"cmd": "set", "direction": "up" | "down" | "both", "params": {...}}   replace the impairment (all keys)
    {"cmd": "stats"}                                                         counters per direction
    {"cmd": "stats", "late_samples": true}                                   and every timed write's lateness (s)
The spec's optional "link" (per direction) is the client edge's own link, stacked with "params" (edges.py).
It exits when stdin closes (so it dies with whoever started it; its TUN devices vanish with it: they are not
persistent) or on SIGTERM.

Timing: the link's delays are one timer per direction on this process's event loop (packets wait in a queue
ordered by delivery time, then arrival), so how late a busy host wakes it is added to
every packet's delay. It asks for real-time scheduling (SCHED_FIFO, low priority: it sleeps except to move
packets, and the kernel keeps 5% of each second for everyone else), else nice -10, and reports its own lateness
(`late_ms` in stats) so a measurement can tell the link from the host.
"""

from __future__ import annotations

import asyncio
import fcntl
import heapq
import json
import os
import signal
import struct
import subprocess
import sys
from typing import Any

from .model import DIRECTIONS, Direction, DirectionParams, Stacked

TUNSETIFF = 0x400454CA
IFF_TUN = 0x0001
IFF_NO_PI = 0x1000
MAX_PACKET = 65536
READ_BATCH = 64  # packets read per wake-up before letting the timers run
RT_PRIORITY = 10  # see the module docstring
NICE = -10


def open_tun(name: str) -> int:
    """A non-persistent TUN device (no packet-info header) in this process's namespace; returns its fd."""
    fd = os.open("/dev/net/tun", os.O_RDWR | os.O_NONBLOCK)
    try:
        fcntl.ioctl(fd, TUNSETIFF, struct.pack("16sH", name.encode(), IFF_TUN | IFF_NO_PI))
    except OSError:
        os.close(fd)
        raise
    return fd


class Forwarder:
    def __init__(self, fds: dict[str, tuple[int, int]], params: dict[str, DirectionParams], seed: int | None,
                 link: dict[str, DirectionParams] | None = None) -> None:
        """fds: direction -> (read from, write to); params: the delay profile's (changed by `set`); link: the
        client edge's own link (edges.py), fixed, crossed before the profile going up and after it coming down."""
        self.fds = fds
        self.dirs = {d: Direction(params[d], None if seed is None else seed + i) for i, d in enumerate(DIRECTIONS)}
        self.links = {d: Direction(link[d], None if seed is None else seed + 10 + i)
                      for i, d in enumerate(DIRECTIONS)} if link else {}
        self.paths: dict[str, Direction | Stacked] = dict(self.dirs)
        if self.links:
            self.paths = {"up": Stacked(self.links["up"], self.dirs["up"]),
                          "down": Stacked(self.dirs["down"], self.links["down"])}
        self.write_errors = 0
        self.not_ipv4 = 0
        self._late: list[float] = []  # how late each timed write ran (s), since the last stats
        self._loop: asyncio.AbstractEventLoop | None = None
        # per direction: (delivery time, arrival number, packet, whether it waited) in delivery order; one timer
        self._queues: dict[str, list[tuple[float, int, bytes, bool]]] = {d: [] for d in DIRECTIONS}
        self._timers: dict[str, asyncio.TimerHandle | None] = {d: None for d in DIRECTIONS}
        self._seq = 0

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        for d, (src, _dst) in self.fds.items():
            loop.add_reader(src, self._readable, loop, d)

    def _readable(self, loop: asyncio.AbstractEventLoop, d: str) -> None:
        src = self.fds[d][0]
        model = self.paths[d]
        queue = self._queues[d]
        for _ in range(READ_BATCH):
            try:
                packet = os.read(src, MAX_PACKET)
            except BlockingIOError:
                break
            if not packet or packet[0] >> 4 != 4:
                self.not_ipv4 += 1  # IPv6 router solicitations and the like: the link is IPv4 only
                continue
            now = loop.time()
            when = model.admit(len(packet), now)
            if when is None:
                continue
            self._seq += 1
            heapq.heappush(queue, (when, self._seq, packet, when > now))
        self._deliver(d)

    def _deliver(self, d: str) -> None:
        """Writes every packet of direction `d` that is due, in order of delivery time and, at equal times, of
        arrival (a link that keeps order bunches packets up to the same time: they must leave in the order they
        came, which separate timers at equal times do not guarantee), then sets one timer for the next."""
        queue, (_src, dst) = self._queues[d], self.fds[d]
        timer = self._timers[d]
        if timer is not None:
            timer.cancel()
        now = self._loop.time()
        while queue and queue[0][0] <= now:
            when, _seq, packet, timed = heapq.heappop(queue)
            if timed and len(self._late) < 1_000_000:
                self._late.append(now - when)
            self._write(dst, packet)
        self._timers[d] = self._loop.call_at(queue[0][0], self._deliver, d) if queue else None

    def _write(self, fd: int, packet: bytes) -> None:
        try:
            os.write(fd, packet)
        except OSError:
            self.write_errors += 1

    def command(self, msg: dict[str, Any]) -> dict[str, Any]:
        cmd = msg.get("cmd")
        if cmd == "set":
            which = msg.get("direction", "both")
            targets = DIRECTIONS if which == "both" else (which,)
            if any(t not in DIRECTIONS for t in targets):
                return {"ok": False, "error": f"direction must be up, down or both, not {which!r}"}
            try:
                params = DirectionParams.from_dict(msg.get("params") or {}, f"set {which}")
            except ValueError as exc:
                return {"ok": False, "error": str(exc)}
            for t in targets:
                self.dirs[t].set(params)
            return {"ok": True}
        if cmd == "stats":
            late = sorted(self._late)
            self._late = []

            def pct(q: float) -> float | None:
                return round(late[min(len(late) - 1, int(q * len(late)))] * 1e3, 3) if late else None

            out = {"ok": True, "stats": {d: m.counters.to_dict() for d, m in self.dirs.items()},
                   "link": {d: m.counters.to_dict() for d, m in self.links.items()},
                   "write_errors": self.write_errors, "not_ipv4": self.not_ipv4,
                   "late_ms": {"n": len(late), "p50": pct(0.5), "p99": pct(0.99)}}
            if msg.get("late_samples"):
                out["late_s"] = late
            return out
        return {"ok": False, "error": f"unknown command {cmd!r}; use set or stats"}


async def _serve(spec: dict[str, Any]) -> None:
    loop = asyncio.get_running_loop()
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(RT_PRIORITY))
    except OSError:
        try:
            os.nice(NICE)
        except OSError:  # not allowed: timing is then only as good as the host's load lets it be
            pass
    tuns = {side: open_tun(spec["tun"][side]) for side in ("client", "server")}
    for side in ("client", "server"):
        subprocess.run(["ip", "link", "set", "dev", spec["tun"][side], "netns", spec["netns"][side]], check=True)
    params = {d: DirectionParams.from_dict(spec["params"][d], d) for d in DIRECTIONS}
    link = {d: DirectionParams.from_dict(spec["link"][d], f"link.{d}") for d in DIRECTIONS} if spec.get("link") \
        else None
    fwd = Forwarder({"up": (tuns["client"], tuns["server"]), "down": (tuns["server"], tuns["client"])},
                    params, spec.get("seed"), link)
    fwd.start(loop)
    stop = asyncio.Event()
    loop.add_signal_handler(signal.SIGTERM, stop.set)
    reader = asyncio.StreamReader()
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    print(json.dumps({"ready": True, "pid": os.getpid()}), flush=True)

    async def commands() -> None:
        while line := await reader.readline():
            try:
                reply = fwd.command(json.loads(line))
            except (ValueError, AttributeError) as exc:
                reply = {"ok": False, "error": f"bad command: {exc}"}
            print(json.dumps(reply), flush=True)
        stop.set()  # stdin closed: whoever started us is gone

    task = asyncio.ensure_future(commands())
    await stop.wait()
    task.cancel()
    for fd in tuns.values():
        os.close(fd)


def main() -> None:
    asyncio.run(_serve(json.loads(sys.argv[1])))


if __name__ == "__main__":
    main()
