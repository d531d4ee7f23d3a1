"""Replaying the 5-minute classroom session: the speed-up achieved and pose-to-command latency.

`vr-teleop synth classroom` (seed 0) is replayed by the same code as `vr-teleop replay` against
`vr-teleop serve --backend sim` running as its own process, camera subscribed as a headset would be. The baseline
is the first BASE_S seconds of the same session replayed in real time in the same run: the latency ratio is what
replaying S times faster costs. `--quick` replays the first 60 s instead of the whole session.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

from vr_teleop_server.tools.replay import load_steps, report, run_replay
from vr_teleop_server.tools.synth import build, write

ROOT = Path(__file__).resolve().parent.parent
EXE = str(Path(sys.executable).with_name("vr-teleop"))
BASE_S = 20.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def replay(steps, url: str, speed: float) -> dict:
    got, elapsed = asyncio.run(run_replay(steps, url, speed, camera=True, progress=False))
    return report(steps, got, elapsed, speed)


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
    parser.add_argument("--speed", type=float, nargs="+", default=[5.0, 10.0, 20.0])
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "classroom.mcap"
        write(build("classroom", seed=0), path)
        steps, _ = load_steps(path)
        if args.quick:
            steps = [s for s in steps if s.t < 60.0]
        port = free_port()
        server = subprocess.Popen([EXE, "serve", "--backend", "sim", "--port", str(port), "--gesture-dir",
                                   str(Path(tmp) / "gestures"), "--audio-dir", str(Path(tmp) / "audio"),
                                   "--log-level", "warning"], cwd=ROOT,
                                  stdout=subprocess.PIPE, text=True, env={**os.environ, "MUJOCO_GL": "egl"})
        try:
            if "listening" not in server.stdout.readline():
                print("bench/replay.py: the server did not start", file=sys.stderr)
                return 1
            url = f"ws://127.0.0.1:{port}"
            base = replay([s for s in steps if s.t < BASE_S], url, 1.0)
            print(line(f"first {BASE_S:g} s at x1", base))
            for speed in args.speed:
                r = replay(steps, url, speed)
                print(line(f"{'first 60 s' if args.quick else 'classroom'} at x{speed:g}", r))
                if base["latency_ms"]["p50"] and r["latency_ms"]["p50"]:
                    print(f"{'':<22} latency vs. real time: p50 x{r['latency_ms']['p50'] / base['latency_ms']['p50']:.2f}, "
                          f"p99 x{r['latency_ms']['p99'] / base['latency_ms']['p99']:.2f}")
        finally:
            server.terminate()
            server.wait(10)
    return 0


if __name__ == "__main__":
    sys.exit(main())
