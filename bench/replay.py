"""Replaying the 5-minute classroom session: the speed-up achieved and pose-to-command latency.

`vr-teleop synth classroom` (seed 0) is replayed by the same code as `vr-teleop replay` against
`vr-teleop serve --backend sim` running as its own process, camera subscribed as a headset would be. The baseline
is the first BASE_S seconds of the same session replayed in real time in the same run: the latency ratio is what
replaying S times faster costs. `--quick` replays the first 60 s instead of the whole session.

`--speed max` replays as `vr-teleop replay --speed max` does without a server: an in-process server on the
stand-in and a simulated clock (camera off unless `--camera`). Its line says how fast it was served on the wall
clock, and per CPU second of this process (the figure a busy machine moves least), and its head tracking against
the real-time baseline's over the same first BASE_S seconds (the issue's bound: within 0.1 degree).
"""

from __future__ import annotations

import argparse
import asyncio
import math
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from testbed.processes import serve, stop  # noqa: E402
from testbed.sessions import classroom_steps  # noqa: E402
from vr_teleop_server.cli.replay import speed as parse_speed  # noqa: E402
from vr_teleop_server.tools.replay import report, run_replay, run_simulated  # noqa: E402

BASE_S = 20.0


def cpu_seconds() -> float:
    """CPU seconds of this process and its ended children (the stand-in's render process)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def replay(steps, url: str, speed: float) -> dict:
    got, elapsed = asyncio.run(run_replay(steps, url, speed, camera=True, progress=False))
    return report(steps, got, elapsed, speed)


def simulated(steps, camera: bool) -> tuple[dict, float]:
    """The report of a simulated replay, and the CPU seconds it took this process (all its threads)."""
    cpu = cpu_seconds()
    got, elapsed = run_simulated(steps, camera=camera, progress=False)
    cpu = cpu_seconds() - cpu
    return report(steps, got, elapsed, math.inf), cpu


def line(name: str, r: dict) -> str:
    lat = r["latency_ms"]
    return (f"{name:<22} session {r['session_s']:6.1f} s sent in {r['replay_s']:6.1f} s = x{r['speed_achieved']:<5} "
            f"served in {r['served_s']} s = x{r['speed_served']}; "
            f"latency p50 {lat['p50']} ms, p99 {lat['p99']} ms, max {lat['max']} ms (n {lat['n']}, "
            f"{lat['pairing']}); head tracking mean {r['tracking_error_deg']['by_part']['head']['mean']} deg; "
            f"camera {r['camera']['fps']} fps; errors {r['errors']['count']}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--speed", type=parse_speed, nargs="+", default=[5.0, 10.0, 20.0], metavar="S|max")
    parser.add_argument("--camera", action="store_true", help="render the camera at --speed max too")
    args = parser.parse_args()
    steps = classroom_steps(60.0 if args.quick else None)
    with tempfile.TemporaryDirectory() as tmp:
        # the session as it was, as the simulated replay's own server runs it: teleoperated, no simulated pupils
        # (with the defaults, this server's attention and pupils kept a core busy through the whole bench, the
        # --speed max run included: x7.1 against x13 without them)
        server = serve("--backend", "sim", "--autonomy", "teleoperated", "--bystander-interval", "0",
                       "--gesture-dir", str(Path(tmp) / "gestures"), "--audio-dir", str(Path(tmp) / "audio"),
                       log_level="warning")
        try:
            url = server.url
            base = replay([s for s in steps if s.t < BASE_S], url, 1.0)
            print(line(f"first {BASE_S:g} s at x1", base))
            for speed in args.speed:
                if math.isinf(speed):
                    continue
                r = replay(steps, url, speed)
                print(line(f"{'first 60 s' if args.quick else 'classroom'} at x{speed:g}", r))
                if base["latency_ms"]["p50"] and r["latency_ms"]["p50"]:
                    print(f"{'':<22} latency vs. real time: p50 x{r['latency_ms']['p50'] / base['latency_ms']['p50']:.2f}, "
                          f"p99 x{r['latency_ms']['p99'] / base['latency_ms']['p99']:.2f}")
        finally:
            stop(server)
        # after the real-time server has stopped: its physics and camera kept a core busy through the simulated
        # run (x13.9 against x27 alone, load 3 to 5, 2026-11-29)
        if any(math.isinf(speed) for speed in args.speed):
            head = [s for s in steps if s.t < BASE_S]
            short, _cpu = simulated(head, camera=args.camera)
            r, cpu = simulated(steps, camera=args.camera)
            print(line(f"{'first 60 s' if args.quick else 'classroom'} at max", r))
            real_head = base["tracking_error_deg"]["by_part"]["head"]["mean"]
            sim_head = short["tracking_error_deg"]["by_part"]["head"]["mean"]
            print(f"{'':<22} simulated clock, camera {'on' if args.camera else 'off'}: served x"
                  f"{r['speed_served']} on the wall clock, x{r['session_s'] / cpu:.1f} per CPU second "
                  f"({cpu:.1f} s); first {BASE_S:g} s head tracking mean {sim_head} deg against "
                  f"{real_head} deg at x1 (difference {abs(sim_head - real_head):.3f} deg)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
