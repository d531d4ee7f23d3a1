"""Explicit control across the emulated WAN: the classroom session replayed through each network profile.

For each profile of netem/profiles.yaml, the server (`vr-teleop serve --backend sim --insecure`) runs in the
emulator's server namespace and `vr-teleop replay`'s client plays `vr-teleop synth classroom` (seed 0) from the
client namespace over the WebSocket path; an observer beside the server (no impairment) records the head commands,
the head poses as the bus gets them, and the watchdog's events. Reported per profile:
- watchdog holds per minute of the session (stalled events while the operator streams);
- head tracking error against the operator's intent, p50/p95 (degrees; the intent is the same mapping computed
  offline at the moments the poses were sent, so filter and caps are in it and the network is what shows), and
  `vr-teleop replay`'s own tracking_error_deg (p99; it pairs commands with poses, which a WAN's holds upset);
- pose-to-command latency p50/p99 (ms: the operator sending a head pose to the server stepping on it);
- the data-channel path (issue 20/21, WebRTC) and video fps: columns left for them ("-" until they exist).
`lan` is the baseline: the last columns are ratios against it, from the same run.

    python bench/wan.py --quick            # the first 60 s of the session, every profile
    python bench/wan.py --profiles lan continent

Needs root and /dev/net/tun (network namespaces, TUN devices).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from netem import Emulator, available, cleanup_leftovers, load_profiles  # noqa: E402
from vr_teleop_server.tools.replay import load_steps, report  # noqa: E402
from vr_teleop_server.tools.synth import build, write  # noqa: E402
from wan_support import Observer, intent_errors, pose_latencies, replay_in, serve  # noqa: E402


def run_profile(name: str, steps, camera_fps: float) -> dict:
    with Emulator(name) as net:
        url = serve(net, "--camera-fps", str(camera_fps))
        observer = Observer(net, url, poses=True)
        got, elapsed = replay_in(net, steps, url)
        seen = observer.stop()
        link = net.stats()
    last_sent = got.sent_head[-1][0]
    engaged = [t for t, e in seen.events if e["kind"] == "engage"]
    start = engaged[0] if engaged else got.started
    holds = [t for t, e in seen.events if e["kind"] == "watchdog_stalled" and start <= t <= last_sent]
    thresholds = [e["detail"]["threshold_s"] for _t, e in seen.events
                  if isinstance(e["detail"], dict) and e["detail"].get("threshold_s") is not None]
    errors = intent_errors(steps, got, seen)
    latency = pose_latencies(steps, got, seen) * 1e3
    minutes = max(last_sent - start, 1e-9) / 60.0
    r = report(steps, got, elapsed, 1.0)

    def pct(a: np.ndarray, q: float) -> float | None:
        return round(float(np.percentile(a, q)), 2) if a.size else None

    return {"profile": name, "session_s": round(steps[-1].t, 1), "holds": len(holds),
            "holds_per_min": round(len(holds) / minutes, 2),
            "threshold_s": [min(thresholds), max(thresholds)] if thresholds else None,
            "tracking_deg": {"p50": pct(errors, 50), "p95": pct(errors, 95), "n": int(errors.size)},
            "replay_tracking_error_deg_p99": r["tracking_error_deg"]["p99"],
            "latency_ms": {"p50": pct(latency, 50), "p99": pct(latency, 99), "n": int(latency.size)},
            "forwarder_late_ms": link.get("late_ms"),
            "link": {d: link["stats"][d] for d in ("up", "down")},
            "datachannel": None, "video_fps": None}


def table(rows: list[dict]) -> str:
    base = next((r for r in rows if r["profile"] == "lan"), None)
    head = ("| profile | holds/min | tracking p50 / p95 (deg) | latency p50 / p99 (ms) | data channel: holds/min, "
            "tracking, latency | video fps | tracking p95 vs lan | latency p50 vs lan |")
    lines = [head, "|" + "---|" * 8]
    for r in rows:
        t, lat = r["tracking_deg"], r["latency_ms"]
        vs_t = vs_l = "-"
        if base and base["tracking_deg"]["p95"] and t["p95"] is not None:
            vs_t = f"x{t['p95'] / base['tracking_deg']['p95']:.2f}"
        if base and base["latency_ms"]["p50"] and lat["p50"] is not None:
            vs_l = f"x{lat['p50'] / base['latency_ms']['p50']:.1f}"
        lines.append(f"| {r['profile']} | {r['holds_per_min']} | {t['p50']} / {t['p95']} | {lat['p50']} / "
                     f"{lat['p99']} | - (issue 20) | - (issue 20) | {vs_t} | {vs_l} |")
    return "\n".join(lines)


def main() -> int:
    profiles = list(load_profiles())
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="the first 60 s of the session instead of 5 minutes")
    parser.add_argument("--profiles", nargs="+", default=profiles, choices=profiles)
    parser.add_argument("--camera-fps", type=float, default=5.0, help="the stand-in's camera rate (nobody watches "
                        "it here; video belongs to the WebRTC path)")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args()
    why = available()
    if why:
        print(f"bench/wan.py: {why}", file=sys.stderr)
        return 2
    cleanup_leftovers()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "classroom.mcap"
        write(build("classroom", seed=0), path)
        steps, _ = load_steps(path)
    if args.quick:
        steps = [s for s in steps if s.t < 60.0]
    rows = []
    for name in args.profiles:
        row = run_profile(name, steps, args.camera_fps)
        rows.append(row)
        print(f"{name}: {json.dumps(row)}", flush=True)
    print()
    print(f"WebSocket path, {'first 60 s of ' if args.quick else ''}the classroom session, per profile:")
    print(table(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
