"""Replay speed and latency: the synthesised 5-minute classroom session replayed headless against
`vr-teleop serve --backend sim` (its own process) at several speeds.

Reports, per requested speed: the speed-up achieved (session length / replay time), pose-to-command latency
p50/p99/max, the tracking error against the offline mapping, and errors. `--quick` replays the 15 s look-around
session instead.
"""

from __future__ import annotations

import argparse
import asyncio
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from vr_teleop_server import synth  # noqa: E402
from vr_teleop_server.replay import load_steps, report, run_replay  # noqa: E402


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--speeds", default="5,10", help="comma-separated replay speeds (default %(default)s)")
    args = parser.parse_args(argv)
    name = "look-around" if args.quick else "classroom"
    speeds = [float(s) for s in args.speeds.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"{name}.mcap"
        synth.write(synth.build(name), path)
        steps, _client = load_steps(path)
        port = free_port()
        proc = subprocess.Popen([sys.executable, "-m", "vr_teleop_server.cli", "serve", "--port", str(port),
                                 "--log-level", "error", "--gesture-dir", str(Path(tmp) / "g"), "--audio-dir",
                                 str(Path(tmp) / "a")], stdout=subprocess.PIPE, text=True, cwd=ROOT)
        proc.stdout.readline()
        try:
            print(f"replay of the synthesised {name} session ({steps[-1].t:.0f} s, {len(steps)} messages) against "
                  f"serve --backend sim, camera subscribed")
            for speed in speeds:
                got, elapsed = asyncio.run(run_replay(steps, f"ws://127.0.0.1:{port}", speed, progress=False))
                r = report(steps, got, elapsed, speed)
                lat, err = r["latency_ms"], r["tracking_error_deg"]
                print(f"  speed {speed:4g}x: achieved {r['speed_achieved']:5.2f}x ({r['replay_s']:6.1f} s) | latency "
                      f"p50 {lat['p50']} ms p99 {lat['p99']} ms max {lat['max']} ms (n={lat['n']}) | tracking max "
                      f"{err['max']} deg | camera {r['camera']['fps']} fps | errors {r['errors']['count']}")
        finally:
            proc.terminate()
            proc.wait(10)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
