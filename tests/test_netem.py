"""The WAN emulator (netem/) and explicit control across it (issue 21).

The emulator is measured with real UDP and TCP stacks in its two namespaces: RTT, jitter and loss within 10% of
the profile, the bandwidth cap with a TCP transfer, and nothing left behind (namespaces, TUN devices,
processes), also when the body of the `with` raises. Then the server runs in the server namespace
(`python -m vr_teleop_server.cli serve --insecure`: the replayed client has no token support, so the namespace
address is served open, which is why --insecure is given) and a 35 s synthesised head-motion session is replayed
from the client namespace over the WebSocket path.

The emulator tests need root and /dev/net/tun; without them they are skipped saying so.
"""

from __future__ import annotations

import os
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from netem import (DIRECTIONS, Direction, DirectionParams, Emulator, Stacked, available, cleanup_leftovers,
                   load_profiles)
from testbed.waiting import Pace, wait_for


def needs_netns(test):
    """A test in network namespaces: marked netns (and slow), skipped where namespaces cannot be made."""
    marked = pytest.mark.skipif(available() is not None, reason=available() or "")(test)
    return pytest.mark.slow(pytest.mark.netns(marked))


# ---- the impairment model, pure ------------------------------------------------------------------------------------
def test_profiles_file_has_the_issue_profiles_and_round_trips_as_asked() -> None:
    profiles = load_profiles()
    assert set(profiles) >= {"lan", "wifi", "city", "continent", "bad"}
    # delays in the file are one-way per direction: a round trip is both
    assert profiles["lan"].rtt_ms == pytest.approx(1.0)
    assert profiles["wifi"].rtt_ms == pytest.approx(5.0)
    assert profiles["wifi"].rtt_jitter_ms == pytest.approx(3.0, rel=0.01)
    assert profiles["city"].rtt_ms == pytest.approx(20.0)
    assert profiles["continent"].rtt_ms == pytest.approx(150.0)
    assert profiles["continent"].rtt_jitter_ms == pytest.approx(15.0, rel=0.01)
    assert profiles["bad"].rtt_ms == pytest.approx(300.0)
    assert profiles["bad"].up.rate_kbit == 1000 and profiles["bad"].down.rate_kbit == 1000
    for name, loss in (("wifi", 0.005), ("city", 0.005), ("continent", 0.02), ("bad", 0.05)):
        assert all(profiles[name].direction(d).loss == loss for d in DIRECTIONS)
    assert profiles["wifi"].up.burst > 1
    assert profiles["wifi"].up.rate_kbit > 0  # a domestic Wi-Fi's rate: the home edge's own link (edges.py)


def test_bad_parameters_are_refused_by_name() -> None:
    with pytest.raises(ValueError, match="loss"):
        DirectionParams(loss=1.5)
    with pytest.raises(ValueError, match="burst"):
        DirectionParams(burst=0.5)
    with pytest.raises(ValueError, match="unknown key.*latency"):
        DirectionParams.from_dict({"latency": 3}, "x.up")


def _loss_runs(direction: Direction, n: int) -> tuple[float, float]:
    lost = [direction.admit(100, i * 1e-3) is None for i in range(n)]
    runs, run = [], 0
    for x in lost:
        if x:
            run += 1
        elif run:
            runs.append(run)
            run = 0
    return sum(lost) / n, (statistics.mean(runs) if runs else 0.0)


def test_gilbert_elliott_loss_has_the_asked_mean_and_burst_length() -> None:
    rate, burst = _loss_runs(Direction(DirectionParams(loss=0.05, burst=4), seed=1), 200_000)
    assert rate == pytest.approx(0.05, rel=0.1)
    assert burst == pytest.approx(4, rel=0.1)
    rate, burst = _loss_runs(Direction(DirectionParams(loss=0.05), seed=2), 200_000)
    assert rate == pytest.approx(0.05, rel=0.1)
    assert burst < 1.2  # independent losses: runs of one, now and then two


def test_bandwidth_serialises_and_the_queue_is_bounded() -> None:
    d = Direction(DirectionParams(rate_kbit=1000, queue_ms=50, delay_ms=10))
    times = [d.admit(1250, 0.0) for _ in range(100)]  # 100 packets of 10 ms each at 1 Mbit/s, all at once
    kept = [t for t in times if t is not None]
    assert kept[:3] == pytest.approx([0.020, 0.030, 0.040])  # serialised one after another, then the delay
    assert len(kept) == 6 and d.counters.queue_dropped == 94  # the queue holds 50 ms: the rest is tail-dropped


def test_order_is_kept_under_jitter_unless_reordering_is_asked() -> None:
    d = Direction(DirectionParams(delay_ms=50, jitter_ms=20), seed=3)
    times = [d.admit(100, i * 1e-3) for i in range(2000)]
    assert times == sorted(times)
    d = Direction(DirectionParams(delay_ms=50, jitter_ms=20, keep_order=False), seed=3)
    times = [d.admit(100, i * 1e-3) for i in range(2000)]
    assert times != sorted(times)
    d = Direction(DirectionParams(delay_ms=5, reorder=0.1, reorder_ms=3), seed=4)
    times = [d.admit(100, i * 1e-3) for i in range(2000)]
    overtaken = sum(1 for a, b in zip(times, times[1:]) if b < a)
    assert overtaken == pytest.approx(d.counters.reordered, rel=0.1) and 150 < d.counters.reordered < 250


def test_stacked_links_add_their_delays_and_a_packet_lost_on_the_first_never_reaches_the_second() -> None:
    first = Direction(DirectionParams(delay_ms=3.0, rate_kbit=800, loss=0.1), seed=1)
    second = Direction(DirectionParams(delay_ms=75.0, loss=0.1), seed=2)
    path = Stacked(first, second)
    out = [path.admit(1000, i * 0.1) for i in range(2000)]  # 10 ms on the wire at 800 kbit/s, 100 ms apart
    delivered = [t - i * 0.1 for i, t in enumerate(out) if t is not None]
    assert delivered and all(d == pytest.approx(0.010 + 0.003 + 0.075) for d in delivered)
    assert second.counters.packets == first.counters.delivered  # only what the first let through
    assert len(delivered) == second.counters.delivered
    assert 1 - len(delivered) / 2000 == pytest.approx(1 - 0.9 * 0.9, abs=0.03)  # losses compound


def test_the_forwarder_keeps_order_when_jitter_bunches_packets_up() -> None:
    """The forwarder itself (netem/forwarder.py), its two ends datagram socket pairs instead of TUN devices: with
    keep_order, jitter makes packets queue up to the same delivery time, and they must still leave in the order
    they came (timers at equal times are not; over continent a pose channel then dropped one head pose in eight as
    overtaken)."""
    import asyncio

    from netem.forwarder import Forwarder

    up_in, up_tun = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    down_tun, down_out = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    sockets = (up_in, up_tun, down_tun, down_out)
    for s in sockets:
        s.setblocking(False)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    params = DirectionParams(delay_ms=5.0, jitter_ms=4.0, keep_order=True)
    n = 3000

    async def run() -> list[int]:
        loop = asyncio.get_running_loop()
        # up: read from up_tun, write to down_tun; packets start as IPv4 does (version nibble 4)
        fwd = Forwarder({"up": (up_tun.fileno(), down_tun.fileno()), "down": (down_tun.fileno(), up_tun.fileno())},
                        {"up": params, "down": DirectionParams()}, seed=3)
        fwd.start(loop)
        loop.remove_reader(down_tun.fileno())  # only the up direction is exercised
        got: list[int] = []

        async def receive() -> None:
            while len(got) < n:
                got.append(struct.unpack("<I", (await loop.sock_recv(down_out, 64))[1:])[0])

        receiver = asyncio.ensure_future(receive())
        for i in range(n):
            up_in.send(b"\x45" + struct.pack("<I", i))
            if i % 10 == 0:
                await asyncio.sleep(0.0005)  # packets about 0.1 ms apart, well inside the jitter
        await asyncio.wait_for(receiver, 30.0)
        assert fwd.write_errors == 0
        return got

    try:
        got = asyncio.run(run())
    finally:
        for s in sockets:
            s.close()
    assert len(got) == n
    assert got == sorted(got), f"{sum(a > b for a, b in zip(got, got[1:]))} packets overtaken"


def test_a_cut_link_drops_everything() -> None:
    d = Direction(DirectionParams(delay_ms=5, down=True))
    assert all(d.admit(100, i * 1e-3) is None for i in range(100)) and d.counters.cut == 100


# ---- the emulator, measured with real stacks -----------------------------------------------------------------------
def _leftovers(net: Emulator) -> list[str]:
    """What of this emulator still exists: namespaces, TUN devices (anywhere), the forwarder process."""
    found = []
    names = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    found += [ns for ns in net.netns.values() if ns in names]
    links = subprocess.run(["ip", "-o", "link"], capture_output=True, text=True).stdout
    found += [dev for dev in net.tun.values() if dev in links]
    return found


SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)  # the kernel stamps each datagram as it arrives
PROBE = struct.Struct("!Iddd")  # seq, client send, server kernel receive, server send (wall clock, shared here)


def _kernel_rx(sock: socket.socket) -> tuple[bytes, float, tuple[str, int]]:
    data, ancdata, _flags, addr = sock.recvmsg(64, 64)
    for level, kind, value in ancdata:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
            sec, nsec = struct.unpack("qq", value[:16])
            return data, sec + nsec / 1e9, addr
    return data, time.time(), addr


def _udp_socket() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    s.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    return s


def _echo_server(ip: str, port: int, seen: set[int], stop_after: float, bound: threading.Event) -> None:
    s = _udp_socket()
    s.bind((ip, port))
    s.settimeout(stop_after)
    bound.set()
    try:
        while True:
            data, rx, addr = _kernel_rx(s)
            seq, sent, _rx, _tx = PROBE.unpack(data)
            seen.add(seq)
            s.sendto(PROBE.pack(seq, sent, rx, time.time()), addr)
    except socket.timeout:
        pass
    finally:
        s.close()


def _probe(ip: str, port: int, count: int, spacing: float, drain: float) -> dict[int, float]:
    """Sends `count` numbered probes `spacing` s apart; returns seq -> the echo's time on the link (s): the round
    trip less the echo server's turnaround, from the kernel's receive stamps (so the figures do not include how
    late a loaded host woke the test's threads)."""
    s = _udp_socket()
    s.connect((ip, port))
    path: dict[int, float] = {}

    def receive() -> None:
        s.settimeout(drain)
        try:
            while True:
                data, rx, _addr = _kernel_rx(s)
                seq, sent, srv_rx, srv_tx = PROBE.unpack(data)
                path.setdefault(seq, (srv_rx - sent) + (rx - srv_tx))
        except (socket.timeout, OSError):
            pass

    receiver = threading.Thread(target=receive, daemon=True)
    receiver.start()
    pace = Pace(1.0 / spacing)  # late probes go out at once: the mean rate is kept
    for seq in range(count):
        s.send(PROBE.pack(seq, time.time(), 0.0, 0.0))
        pace.wait()
    receiver.join()
    s.close()
    return path


def _jitter(values: list[float]) -> float:
    """The standard deviation from the interquartile range (a normal's): this machine is a virtual one shared by
    several busy processes, and the forwarder is woken tens of ms late now and then (its stats say how often);
    that tail is the host, not the link, and it leaves the quartiles alone."""
    q1, q3 = np.percentile(values, [25, 75])
    return float(q3 - q1) / 1.349


def _expected_jitter(profile, late_s: list[float]) -> float:
    """The spread (as _jitter measures it) of a round trip across the profile's two directions, each packet also
    written as late as the forwarder's own measured lateness (drawn from its samples): what the probes should see
    on this host now. On an idle host the lateness is a fraction of a millisecond and this is the profile's."""
    rng = np.random.default_rng(7)
    n = 200_000
    rtt = (np.maximum(0.0, rng.normal(profile.up.delay_ms, profile.up.jitter_ms, n))
           + np.maximum(0.0, rng.normal(profile.down.delay_ms, profile.down.jitter_ms, n)))
    if late_s:
        late_ms = np.asarray(late_s) * 1e3
        rtt += rng.choice(late_ms, n) + rng.choice(late_ms, n)
    return _jitter(rtt)


@needs_netns
def test_continent_rtt_jitter_and_loss_match_the_profile() -> None:
    with Emulator("continent") as net:
        profile = net.profile
        # Delay and jitter: 3000 probes 6 ms apart (the spread is then known within 2%, one sigma). So close, the
        # profile's order-keeping would bunch them up (a probe late by the jitter holds up the next: less spread
        # than asked, as on a real queue), so it is switched off for this part: each probe gets its own delay.
        net.set(keep_order=False)
        seen: set[int] = set()
        bound = threading.Event()
        server = net.start_in("server", _echo_server, net.server_ip, 7001, seen, 2.0, bound)
        assert bound.wait(10)
        net.stats()  # the forwarder's lateness counts from here
        rtt = net.run_in("client", _probe, net.server_ip, 7001, 3000, 0.006, 1.0)
        net.set(keep_order=True)
        host = net.stats(late_samples=True)
        rtts_ms = [v * 1e3 for v in rtt.values()]
        expected = _expected_jitter(profile, host["late_s"])
        figures = (f"RTT median {statistics.median(rtts_ms):.1f} ms, jitter {_jitter(rtts_ms):.2f} ms (the profile "
                   f"{profile.rtt_jitter_ms:.2f}, with the forwarder's own lateness {expected:.2f}); that lateness "
                   f"{host['late_ms']}")
        assert statistics.median(rtts_ms) == pytest.approx(profile.rtt_ms, rel=0.1), figures
        # The link's spread is the profile's; a busy host only adds to it, by as much as the forwarder measured
        # itself late (the cause of this assertion's failures under load: jitter 21.3 ms against 15.0 with the
        # forwarder's lateness at p99 76 ms).
        assert 0.9 * profile.rtt_jitter_ms <= _jitter(rtts_ms) <= 1.1 * expected, figures
        server.join()
        # Loss: 40 000 probes quickly (about 800 losses each way expected: a 10% error is 2.9 binomial sigmas).
        before = net.stats()["stats"]
        seen = set()
        bound = threading.Event()
        server = net.start_in("server", _echo_server, net.server_ip, 7002, seen, 3.0, bound)
        assert bound.wait(10)
        n = 40_000
        rtt = net.run_in("client", _probe, net.server_ip, 7002, n, 1 / 6000, 1.5)
        server.join()
        up_loss = 1 - len(seen) / n
        down_loss = 1 - len(rtt) / len(seen)
        stats = net.stats()["stats"]
        # every loss was the emulator's (no socket or TUN queue overflowed)
        assert n - len(seen) == stats["up"]["lost"] - before["up"]["lost"]
        assert len(seen) - len(rtt) == stats["down"]["lost"] - before["down"]["lost"]
        assert up_loss == pytest.approx(profile.up.loss, rel=0.1)
        assert down_loss == pytest.approx(profile.down.loss, rel=0.1)
    assert _leftovers(net) == []


def _tcp_sink(ip: str, port: int, got: list[tuple[float, int]], listening: threading.Event) -> None:
    srv = socket.socket()
    srv.bind((ip, port))
    srv.listen(1)
    listening.set()
    srv.settimeout(10)
    conn, _ = srv.accept()
    with conn:
        while data := conn.recv(65536):
            got.append((time.monotonic(), len(data)))
    srv.close()


def _tcp_send(ip: str, port: int, seconds: float) -> int:
    c = socket.create_connection((ip, port), timeout=10)
    chunk = b"\0" * 16384
    sent = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        sent += c.send(chunk)
    c.close()
    return sent


@needs_netns
def test_bandwidth_cap_holds_for_a_tcp_transfer() -> None:
    """`bad`'s 1 Mbit/s with its queue, without its loss (which would keep TCP well below any cap): TCP's goodput
    settles within 10% under the cap (IP and TCP headers take 52 of each 1500 bytes) and never above it."""
    with Emulator("bad") as net:
        net.set(loss=0.0, delay_ms=20)
        cap_bps = net.params["up"].rate_kbit * 1e3
        got: list[tuple[float, int]] = []
        listening = threading.Event()
        sink = net.start_in("server", _tcp_sink, net.server_ip, 7003, got, listening)
        assert listening.wait(10)
        net.run_in("client", _tcp_send, net.server_ip, 7003, 6.0)
        sink.join()
        t = np.array([g[0] for g in got])
        b = np.cumsum([g[1] for g in got])
        start = t[0] + 2.0  # past slow start
        i, j = np.searchsorted(t, start), len(t) - 1
        goodput = (b[j] - b[i]) * 8 / (t[j] - t[i])
        assert goodput == pytest.approx(cap_bps * 1448 / 1500, rel=0.1)
        assert goodput <= cap_bps
    assert _leftovers(net) == []


@needs_netns
def test_nothing_is_left_behind_when_the_body_raises() -> None:
    cleanup_leftovers()  # a killed earlier run's namespaces, if any
    with pytest.raises(RuntimeError, match="boom"):
        with Emulator("lan") as net:
            sleeper = net.popen("server", ["sleep", "600"])
            forwarder = net.forwarder_pid
            assert _leftovers(net)
            raise RuntimeError("boom")
    assert _leftovers(net) == []
    assert sleeper.poll() is not None
    with pytest.raises(ProcessLookupError):
        os.kill(forwarder, 0)


@needs_netns
def test_leftovers_of_a_killed_run_are_cleaned_up() -> None:
    """A run killed with SIGKILL leaves its namespaces (its forwarder and TUN devices die with it)."""
    script = ("import os, sys; from netem import Emulator; net = Emulator('lan'); net.start(); "
              "print(' '.join(net.netns.values()), net.forwarder_pid, flush=True); os.kill(os.getpid(), 9)")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    client_ns, server_ns, forwarder = done.stdout.split()
    names = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    assert client_ns in names and server_ns in names
    def gone() -> bool:  # the forwarder exits once its stdin closes with its parent (a zombie until reaped)
        try:
            return "zombie" in open(f"/proc/{forwarder}/status").read().lower()
        except FileNotFoundError:
            return True

    assert wait_for(gone, 30)
    removed = cleanup_leftovers()
    assert client_ns in removed and server_ns in removed
    names = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    assert client_ns not in names and server_ns not in names


def test_a_seed_makes_a_run_repeatable() -> None:
    a, b = Direction(DirectionParams(loss=0.3), seed=5), Direction(DirectionParams(loss=0.3), seed=5)
    assert [a.admit(10, 0) for _ in range(50)] == [b.admit(10, 0) for _ in range(50)]


# ---- explicit control across the emulated WAN ----------------------------------------------------------------------
HEAD_CAP = 90.0  # deg/s, HeadYaw and HeadPitch in robot_models/data/qtrobot.yaml


def _head_session(tmp_path, seconds: float = 30.0):
    """`look-around`, then nods and more looking around, then 2 s at rest: a synthesised head-motion session of
    at least `seconds`."""
    from vr_teleop_server.tools import synth
    from vr_teleop_server.tools.replay import load_steps

    rng = np.random.default_rng(21)
    session = synth.build("look-around", 21)
    while session.duration < seconds - 2.0:
        synth.nod(session, rng)
        synth.look_around(session, rng)
    session.head.hold(2.0)  # ends at rest, so the robot must have caught up
    path = tmp_path / "head.mcap"
    synth.write(session, path, seed=21)
    steps, _client = load_steps(path)
    return steps


def _check_no_jump(seen, settings) -> list[float]:
    """Every head command moves each joint at most cap x max_step_dt from the one before (the mapper never lets a
    step use more time than that), and each resume after a hold at most the ramp's start fraction of that: the
    robot eases back. A hold shows as a silence of the head commands around the stalled/active events (the
    server publishes nothing while it holds; a topic's frames keep their order, frames of two topics may not, so
    the resume is found as the end of the longest silence near the active event). Returns the resume steps."""
    largest = HEAD_CAP * settings.max_step_dt_s
    resume_bound = largest * settings.ramp_start_fraction
    times = np.array([t for t, _c in seen.head])
    commands = np.array([c for _t, c in seen.head])
    steps = np.abs(np.diff(commands, axis=0)).max(axis=1)
    gaps = np.diff(times)
    assert steps.max() <= largest + 1e-6, f"a jump of {steps.max():.2f} deg (bound {largest:.2f})"
    resume_steps = []
    stalled_at = None
    for t, e in seen.events:
        if e["kind"] == "watchdog_stalled":
            stalled_at = t
        elif e["kind"] == "watchdog_active" and stalled_at is not None:
            near = np.flatnonzero((times[1:] >= t - 0.2) & (times[1:] <= t + 0.2))
            assert near.size, f"no head command around the resume at {t}"
            k = near[np.argmax(gaps[near])]
            assert gaps[k] >= 0.5 * (t - stalled_at), "the head was commanded while the robot held"
            assert steps[k] <= resume_bound + 1e-6, f"resumed with a step of {steps[k]:.2f} deg " \
                                                    f"(bound {resume_bound:.2f}: the ramp)"
            resume_steps.append(float(steps[k]))
            stalled_at = None
    return resume_steps


@needs_netns
def test_on_continent_the_websocket_path_may_hold_but_resumes_by_itself_without_a_jump(tmp_path) -> None:
    from vr_teleop_server.teleop import TeleopSettings
    from testbed.wan_support import Observer, intent_errors, replay_in, serve

    steps = _head_session(tmp_path, 30.0)
    with Emulator("continent") as net:
        url = serve(net, "--camera-fps", "5")
        observer = Observer(net, url)
        got, elapsed = replay_in(net, steps, url)
        seen = observer.stop()
    assert _leftovers(net) == []
    kinds = seen.kinds()
    assert "engage" in kinds and len(seen.head) > 1000, kinds
    last_sent = got.sent_head[-1][0]  # after it the session is over: the stream stops, the robot holds
    during = [e["kind"] for t, e in seen.events if t <= last_sent]
    for n, kind in enumerate(during):  # every hold while the operator moved resumed by itself
        if kind == "watchdog_stalled":
            assert "watchdog_active" in kinds[n + 1:], kinds
    for _t, e in seen.events:
        if e["kind"] in ("watchdog_stalled", "watchdog_active"):
            assert 0.2 <= e["detail"]["threshold_s"] <= 0.5, e
    resumes = _check_no_jump(seen, TeleopSettings())
    errors = intent_errors(steps, got, seen)
    assert errors.size > 30 * 30
    # it followed: the head within 10 degrees of the operator's intent most of the time (the intent sweeps +-60
    # deg at up to ~60 deg/s and the commands are a one-way delay, 75 ms, and a retransmission now and then
    # behind it; a head that did not follow would be ~30 degrees off), and exactly where meant once at rest
    p50, p95 = np.percentile(errors, [50, 95])
    print(f"continent, WebSocket: {during.count('watchdog_stalled')} holds in {steps[-1].t:.0f} s (resume steps "
          f"{[round(r, 3) for r in resumes]} deg); head error against intent p50 {p50:.2f} p95 {p95:.2f} deg")
    assert p50 < 10.0, (p50, p95)
    assert errors[-1] < 1.0, errors[-20:]


@needs_netns
def test_a_link_down_for_2_s_holds_within_the_ceiling_and_resumes_only_on_fresh_poses(tmp_path) -> None:
    from vr_teleop_server.teleop import TeleopSettings
    from testbed.wan_support import Observer, replay_in, serve

    steps = _head_session(tmp_path, 16.0)
    with Emulator("city") as net:
        url = serve(net, "--camera-fps", "5", "--watchdog-ceiling", "0.5")
        observer = Observer(net, url)
        cut: dict[str, float] = {}

        def outage() -> None:
            time.sleep(7.0)  # the scenario's own clock: the link goes down 7 s into the 16 s session
            net.set(down=True)
            cut["down"] = time.monotonic()
            time.sleep(2.0)  # the scenario's own clock: what is tested is a link down for 2 s
            net.set(down=False)
            cut["up"] = time.monotonic()

        link = threading.Thread(target=outage, daemon=True)
        link.start()
        replay_in(net, steps, url)
        link.join()
        seen = observer.stop()
    assert _leftovers(net) == []
    stalls = [(t, e) for t, e in seen.events if e["kind"] == "watchdog_stalled" and t > cut["down"]]
    assert stalls, seen.kinds()
    held_at, hold = stalls[0]
    assert hold["detail"]["threshold_s"] <= 0.5  # the ceiling
    assert held_at < cut["up"]  # held during the outage, not after it
    resumes = [(t, e) for t, e in seen.events if e["kind"] == "watchdog_active" and t > held_at]
    assert resumes, seen.kinds()
    resumed_at, resume = resumes[0]
    assert resumed_at > cut["up"]  # not before the link was back
    # on a pose made within the threshold: not one of the backlog TCP delivered when the link came back
    assert resume["detail"]["pose_made_age_s"] <= resume["detail"]["threshold_s"], resume
    last_before = max(t for t, _c in seen.head if t < held_at)
    _check_no_jump(seen, TeleopSettings())
    print(f"link down at +0, held {held_at - cut['down']:.3f} s later ({held_at - last_before:.3f} s after the last "
          f"head command; threshold {hold['detail']['threshold_s']} s), link up at +{cut['up'] - cut['down']:.2f} s, "
          f"resumed at +{resumed_at - cut['down']:.2f} s on a pose {resume['detail']['pose_made_age_s']} s old")


@needs_netns
def test_on_continent_poses_over_the_data_channel_never_hold_and_the_robot_follows(tmp_path) -> None:
    from testbed.media_client import ChannelRoad
    from vr_teleop_server.teleop import TeleopSettings
    from testbed.wan_support import Observer, intent_errors, pose_latencies, replay_in, serve

    steps = _head_session(tmp_path, 30.0)
    road = ChannelRoad()
    with Emulator("continent") as net:
        url = serve(net, "--camera-fps", "5")
        observer = Observer(net, url, poses=True)
        got, elapsed = replay_in(net, steps, url, road=road)
        seen = observer.stop()
    assert _leftovers(net) == []
    kinds = seen.kinds()
    assert "engage" in kinds and len(seen.head) > 500, kinds
    engaged_at = next(t for t, e in seen.events if e["kind"] == "engage")
    last_sent = got.sent_head[-1][0]
    streams = sum(1 for s in steps if s.kind == "publish" and s.topic.startswith("/vr/"))
    assert got.by_road > 0.8 * streams, (got.by_road, streams)  # after engaging, everything took the channel
    # A hold is the link's unless the operator's client itself sent nothing for most of the watchdog's threshold
    # just before it: then it is the host's, which stalled the headset this test plays from a thread of its own
    # process (a real headset shares no one's CPU; the collector's passes are kept out by conftest's freeze, the
    # scheduler's delays on a machine the suite's other worker keeps busy are not). Each hold's silence is counted.
    sends = np.array([t for t, _i in got.sent_head])

    def client_silence(t: float) -> float:
        """The longest gap between the client's head poses overlapping the half second before `t`."""
        window = sends[max(np.searchsorted(sends, t - 0.5) - 1, 0):np.searchsorted(sends, t)]
        return float(np.diff(np.append(window, t)).max()) if window.size else 0.5

    stalls = [(e, client_silence(t)) for t, e in seen.events
              if e["kind"] == "watchdog_stalled" and engaged_at <= t <= last_sent]
    holds = [(e, quiet) for e, quiet in stalls if quiet < 0.75 * e["detail"]["threshold_s"]]
    sender = road.sender
    head_sent = sum(1 for t, i in got.sent_head if t > engaged_at)
    head_arrived = sum(1 for t, _s in seen.poses if t > engaged_at)
    latency = pose_latencies(steps, got, seen)
    errors = intent_errors(steps, got, seen)
    p50, p95 = np.percentile(errors, [50, 95])
    print(f"continent, data channel: {len(holds)} holds in {steps[-1].t:.0f} s (and {len(stalls) - len(holds)} "
          f"while the client itself was silent); head poses arrived "
          f"{head_arrived}/{head_sent} ({head_arrived / max(head_sent, 1):.0%}); channel frames sent {sender.sent}, "
          f"replaced before sending {sender.replaced}, head poses handed to the WebSocket while it stalled "
          f"{sender.failovers}; pose-to-command p50 {np.percentile(latency, 50) * 1e3:.0f} "
          f"p99 {np.percentile(latency, 99) * 1e3:.0f} ms; head error against intent p50 {p50:.2f} p95 {p95:.2f} deg")
    assert holds == [], holds
    _check_no_jump(seen, TeleopSettings())
    assert errors.size > 30 * 30
    assert p50 < 10.0, (p50, p95)
    assert errors[-1] < 1.0, errors[-20:]
