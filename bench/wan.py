"""Explicit control across the emulated WAN: the classroom session replayed through each network profile.

For each profile of netem/profiles.yaml, the server (`vr-teleop serve --backend sim --insecure`) runs in the
emulator's server namespace and `vr-teleop replay`'s client plays `vr-teleop synth classroom` (seed 0) from the
client namespace, twice: over the WebSocket path, then with the operator's streams on the poses data channel
(issue 21: poses go over the WebSocket until engage succeeds, as the channel requires). On both runs the replay
client has an aiortc peer connection, negotiated over its own rosbridge connection, that receives the camera as
WebRTC video (so both carry the same load); on the second its poses channel carries the operator's streams. An
observer beside the server (no impairment) records the head commands, the head poses as the bus gets them, and the
watchdog's events. Reported per profile and path:
- watchdog holds per minute of the session (stalled events while the operator streams);
- head tracking error against the operator's intent, p50/p95 (degrees; the intent is the same mapping computed
  offline at the moments the poses were sent, so filter and caps are in it and the network is what shows), and
  `vr-teleop replay`'s own tracking_error_deg (p99; it pairs commands with poses, which a WAN's holds upset);
- the same error less the link's delay, p50/p95: the command at t against the intent at t - T, T the profile's
  fixed one-way delay (client to server; 0.5 ms on lan, 75 ms on continent), the measure of time-delayed
  teleoperation (x_robot(t) - x_operator(t - T)): no transport removes T, and what is left is what the transport
  adds (jitter, queueing, losses, holds, bursts); `bench/wan_floor.py` gives the least each measure can be on each
  profile with a perfect transport;
- pose-to-command latency p50/p99 (ms: the operator sending a head pose to the server stepping on it);
- on the data channel: the share of head poses sent after engaging that reached the bus (the sender keeps only the
  newest pose per topic while the channel is busy, so a congested channel sends fewer, fresher poses), and the
  video frames per second the peer received (counted by their last RTP packet, not decoded).
`lan` is the baseline: the last columns are ratios against it (each path against its own lan run), same run.

With `--via` the same runs go through the real world's edges (issue 30; netem/edges.py): the replay client behind a
home NAT, the server behind the school's symmetric NAT with its WebSocket port forwarded, and the media and poses
channel through coturn in the relay namespace (the delay profile is the link between home and the internet, so a
relayed path crosses it once). `turn-udp`: the school lets UDP out and every TURN leg is UDP; `turn-tls`: the
school blocks UDP (TCP out to 80 and 443 only) and the server's leg is TURN over TLS on 443, the client's TURN/UDP.
Each via's rows are against lan through the same via. `--poses binary`: the data channel's sender packs what is
pending into one binary pose frame per send (client_protocol/pose_frame.py) instead of a JSON frame per topic.

    python bench/wan.py --quick            # the first 60 s of the session, every profile
    python bench/wan.py --profiles lan continent
    python bench/wan.py --quick --profiles lan continent --paths datachannel --via direct turn-udp turn-tls

Needs root and /dev/net/tun (network namespaces, TUN devices).
"""

from __future__ import annotations

import argparse
import ipaddress
import json
import secrets
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT)]

from client_protocol.names import ENGAGE_SERVICE  # noqa: E402
from netem import EDGES, Emulator, available, cleanup_leftovers, edges_available, load_profiles  # noqa: E402
from testbed.media_client import ChannelRoad  # noqa: E402
from testbed.sessions import classroom_steps  # noqa: E402
from testbed.wan_support import Observer, intent_errors, pose_latencies, replay_in, serve  # noqa: E402
from vr_teleop_server.core.certs import make_certificate  # noqa: E402
from vr_teleop_server.tools.replay import report  # noqa: E402


VIAS = ("direct", "turn-udp", "turn-tls")


def run_profile(name: str, steps, camera_fps: float, channel: bool = False, via: str = "direct",
                poses: str = "json") -> dict:
    # both paths receive the camera and the robot's audio: the same load on both
    road = ChannelRoad(video=True, carry=channel, audio=True, turn="" if via == "direct" else "udp",
                       compact=poses == "binary")
    edges = {} if via == "direct" else {
        "client_edge": "home",
        "server_edge": EDGES["school"] if via == "turn-tls" else EDGES["school"].replace(block_udp=False)}
    with Emulator(name, **edges) as net, tempfile.TemporaryDirectory() as work:
        extra, env = [], None
        if via != "direct":
            secret = secrets.token_hex(16)
            cert = make_certificate(Path(work), [], [ipaddress.ip_address(net.relay_ip)])
            net.start_relay(secret, cert.certfile, cert.keyfile, Path(work))
            first, second = (f"turns:{net.relay_ip}:443?transport=tcp", f"turn:{net.relay_ip}:3478?transport=udp")
            if via == "turn-udp":
                first, second = second, first
            extra = ["--turn-url", first, "--turn-url", second, "--turn-secret", secret]
            env = {"SSL_CERT_FILE": str(cert.certfile)}  # the server trusts the relay's self-signed certificate
        url = serve(net, "--camera-fps", str(camera_fps), *extra, env=env)
        observer = Observer(net, url, poses=True)
        public = url.replace(net.server_ip, net.public_ip)  # through the school's forwarded port
        got, elapsed = replay_in(net, steps, public, road=road)
        seen = observer.stop()
        link = net.stats()
    last_sent = got.sent_head[-1][0]
    engaged = [t for t, e in seen.events if e["kind"] == "engage"]
    start = engaged[0] if engaged else got.started
    holds = [t for t, e in seen.events if e["kind"] == "watchdog_stalled" and start <= t <= last_sent]
    thresholds = [e["detail"]["threshold_s"] for _t, e in seen.events
                  if isinstance(e["detail"], dict) and e["detail"].get("threshold_s") is not None]
    errors = intent_errors(steps, got, seen)
    delay_s = load_profiles()[name].up.delay_ms / 1e3  # the link's fixed one-way delay, client to server
    errors_less_delay = intent_errors(steps, got, seen, delay_s=delay_s)
    latency = pose_latencies(steps, got, seen) * 1e3
    minutes = max(last_sent - start, 1e-9) / 60.0
    r = report(steps, got, elapsed, 1.0)

    def pct(a: np.ndarray, q: float) -> float | None:
        return round(float(np.percentile(a, q)), 2) if a.size else None

    glass = glass_to_glass_ms(road, seen.render_times)
    extra = {"video_fps": round(road.video_fps, 1) if road.video_fps is not None else None,
             "glass_to_glass_ms": {"p50": pct(glass, 50), "p95": pct(glass, 95), "n": int(glass.size)},
             "audio": audio_gaps(road)}
    if channel:
        head_sent = sum(1 for t, _i in got.sent_head if t > start)
        head_arrived = sum(1 for t, _s in seen.poses if t > start)
        extra = {"by_channel": got.by_road, "channel_sent": road.sender.sent, "channel_head_sent": road.sender.head_sent,
                 "server_channel": seen.channel, "channel_replaced": road.sender.replaced,
                 "head_failovers": road.sender.failovers,
                 "head_arrival": round(head_arrived / max(head_sent, 1), 3), **extra}
    # the engage calls' answers: a session that never engaged says why here
    engage_answers = [(ok, values) for i, (topic, _t, _a) in got.calls.items() if topic == ENGAGE_SERVICE
                      for ok, values, _rt in [got.responses.get(i, (False, "no answer", 0.0))]]
    extra["engage"] = [ok if ok else str(values)[:300] for ok, values in engage_answers]
    return {"profile": name, "via": via, "poses": poses, "path": "datachannel" if channel else "websocket", **extra,
            "session_s": round(steps[-1].t, 1), "holds": len(holds),
            "holds_per_min": round(len(holds) / minutes, 2),
            "threshold_s": [min(thresholds), max(thresholds)] if thresholds else None,
            "tracking_deg": {"p50": pct(errors, 50), "p95": pct(errors, 95), "n": int(errors.size)},
            "tracking_less_delay_deg": {"p50": pct(errors_less_delay, 50), "p95": pct(errors_less_delay, 95),
                                        "delay_ms": delay_s * 1e3, "n": int(errors_less_delay.size)},
            "replay_tracking_error_deg_p99": r["tracking_error_deg"]["p99"],
            "latency_ms": {"p50": pct(latency, 50), "p99": pct(latency, 99), "n": int(latency.size)},
            "forwarder_late_ms": link.get("late_ms"),
            "link": {d: link["stats"][d] for d in ("up", "down")}}


def glass_to_glass_ms(road: ChannelRoad, render_times: dict[int, float]) -> np.ndarray:
    """Render (the stand-in's, by the telemetry's RTP mapping) to the frame's last packet at the viewer in the
    client namespace, ms: one machine, one wall clock. The viewer does not decode (a browser adds its jitter
    buffer and decode, about 10 ms on loopback: bench/media.py)."""
    arrivals = road.peer.video_arrivals if road.peer is not None else []
    return np.array([1e3 * (t - render_times[rtp]) for t, rtp in arrivals if rtp in render_times])


def audio_gaps(road: ChannelRoad, gap_s: float = 0.1) -> dict:
    """The robot's audio at the viewer: 20 ms Opus frames received against the time they span, and silences of
    the stream (no frame for `gap_s` or more) per minute with the longest."""
    times = np.array([t for t, _samples in road.peer.audio_frames]) if road.peer is not None else np.zeros(0)
    if times.size < 2:
        return {"frames": int(times.size), "received": None, "gaps_per_min": None, "longest_gap_ms": None}
    span = times[-1] - times[0]
    intervals = np.diff(times)
    return {"frames": int(times.size), "received": round(float(times.size * 0.02 / span), 3),
            "gaps_per_min": round(float(np.sum(intervals >= gap_s)) / (span / 60.0), 2),
            "longest_gap_ms": round(float(intervals.max()) * 1e3, 1)}


def _ratio(row: dict | None, base: dict | None, key: str, q: str, digits: int) -> str:
    if not row or not base or not base[key][q] or row[key][q] is None:
        return "-"
    return f"x{row[key][q] / base[key][q]:.{digits}f}"


def table(rows: list[dict]) -> str:
    """One line per profile: the WebSocket path, then the data channel (each ratio against its own path on lan)."""
    ws = {_label(r): r for r in rows if r["path"] == "websocket"}
    dc = {_label(r): r for r in rows if r["path"] == "datachannel"}
    head = ("| profile | holds/min | tracking p50 / p95 (deg) | latency p50 / p99 (ms) | data channel: holds/min, "
            "tracking, latency | head poses arrived (DC) | video fps (WS / DC) | tracking p95 vs lan (WS / DC) | "
            "latency p50 vs lan (WS / DC) | glass to glass p50 / p95 (ms, WS / DC) | audio gaps/min, received "
            "(WS / DC) | tracking less the link's delay p50 / p95 (deg, WS / DC) | the same p95 vs lan (WS / DC) |")
    lines = [head, "|" + "---|" * 13]
    for name in dict.fromkeys([*ws, *dc]):
        w, d = ws.get(name), dc.get(name)
        via = (w or d)["via"]
        base = "lan" if via == "direct" else f"lan via {via}"
        cells = [name]
        if w:
            t, lat = w["tracking_deg"], w["latency_ms"]
            cells += [str(w["holds_per_min"]), f"{t['p50']} / {t['p95']}", f"{lat['p50']} / {lat['p99']}"]
        else:
            cells += ["-", "-", "-"]
        if d:
            t, lat = d["tracking_deg"], d["latency_ms"]
            cells += [f"{d['holds_per_min']}/min, {t['p50']} / {t['p95']} deg, {lat['p50']} / {lat['p99']} ms",
                      f"{d['head_arrival']:.0%}"]
        else:
            cells += ["-", "-"]
        cells.append(f"{w['video_fps'] if w else '-'} / {d['video_fps'] if d else '-'}")
        cells += [f"{_ratio(w, ws.get(base), 'tracking_deg', 'p95', 2)} / "
                  f"{_ratio(d, dc.get(base), 'tracking_deg', 'p95', 2)}",
                  f"{_ratio(w, ws.get(base), 'latency_ms', 'p50', 1)} / "
                  f"{_ratio(d, dc.get(base), 'latency_ms', 'p50', 1)}",
                  " / ".join(_media(r, "glass") for r in (w, d)), " / ".join(_media(r, "audio") for r in (w, d)),
                  " / ".join(f"{r['tracking_less_delay_deg']['p50']}-{r['tracking_less_delay_deg']['p95']}"
                             if r else "-" for r in (w, d)),
                  f"{_ratio(w, ws.get(base), 'tracking_less_delay_deg', 'p95', 2)} / "
                  f"{_ratio(d, dc.get(base), 'tracking_less_delay_deg', 'p95', 2)}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _label(row: dict) -> str:
    return row["profile"] if row.get("via", "direct") == "direct" else f"{row['profile']} via {row['via']}"


def _media(row: dict | None, what: str) -> str:
    if not row:
        return "-"
    if what == "glass":
        g = row["glass_to_glass_ms"]
        return f"{g['p50']}-{g['p95']}" if g["n"] else "-"
    a = row["audio"]
    return f"{a['gaps_per_min']}, {a['received']:.0%}" if a["received"] is not None else "-"


def main() -> int:
    profiles = list(load_profiles())
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="the first 60 s of the session instead of 5 minutes")
    parser.add_argument("--profiles", nargs="+", default=profiles, choices=profiles)
    parser.add_argument("--camera-fps", type=float, default=30.0, help="the stand-in's camera rate (rendered only "
                        "while watched: on the data-channel run, whose peer receives it as video)")
    parser.add_argument("--paths", nargs="+", default=["websocket", "datachannel"],
                        choices=["websocket", "datachannel"], help="which roads the poses take (each its own run)")
    parser.add_argument("--via", nargs="+", default=["direct"], choices=VIAS,
                        help="direct: the plain link; turn-udp, turn-tls: home and school NATs and the TURN relay "
                             "(module docstring)")
    parser.add_argument("--poses", default="json", choices=["json", "binary"],
                        help="on the data channel: JSON publish frames, or one binary pose frame per send "
                             "(client_protocol/pose_frame.py)")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args()
    why = available() if args.via == ["direct"] else edges_available()
    if why:
        print(f"bench/wan.py: {why}", file=sys.stderr)
        return 2
    cleanup_leftovers()
    steps = classroom_steps(60.0 if args.quick else None)
    rows = []
    for via in args.via:
        for name in args.profiles:
            for path in args.paths:
                row = run_profile(name, steps, args.camera_fps, channel=path == "datachannel", via=via,
                                  poses=args.poses)
                rows.append(row)
                print(f"{name} {via} {path}: {json.dumps(row)}", flush=True)
    print()
    print(f"{'First 60 s of the' if args.quick else 'The'} classroom session, per profile, WebSocket path and data "
          "channel (DC):")
    print(table(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
