"""Stand-in figures: physics real-time factor and step cost, camera render and JPEG times, achieved fps.

Runs the stand-in with the camera streaming while the head sweeps, then prints one line per figure.
`--quick` runs 3 s instead of 10.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import threading
import time

os.environ.setdefault("MUJOCO_GL", "egl")

from sim import StandIn  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="3 s instead of 10 s")
    parser.add_argument("--seconds", type=float, default=None)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--antialias", type=int, default=0, help="MSAA samples (0 = off)")
    parser.add_argument("--quality", type=int, default=80, help="JPEG quality")
    args = parser.parse_args(argv)
    seconds = args.seconds or (3.0 if args.quick else 10.0)

    with StandIn(camera_width=args.width, camera_height=args.height, camera_fps=args.fps,
                 jpeg_quality=args.quality, antialias=args.antialias) as s:
        frames = []
        done = threading.Event()

        def collect() -> None:
            seq = 0
            while not done.is_set():
                f = s.wait_frame(seq, timeout=0.5)
                if f is not None:
                    frames.append(f)
                    seq = f.seq

        collector = threading.Thread(target=collect, daemon=True)
        s.start_camera()
        collector.start()
        t0 = time.monotonic()
        cpu0 = time.process_time()
        while time.monotonic() - t0 < seconds:
            phase = (time.monotonic() - t0) % 4.0
            s.set_targets({"HeadYaw": 40.0 if phase < 2.0 else -40.0})
            time.sleep(0.05)
        cpu = time.process_time() - cpu0
        wall = time.monotonic() - t0
        s.stop_camera()
        done.set()
        collector.join()
        stats = s.physics_stats()

    frames = frames[1:]  # the first frame pays for warm-up
    if len(frames) < 2:
        print("no camera frames were produced", file=sys.stderr)
        return 1
    fps = (len(frames) - 1) / (frames[-1].stamp_monotonic - frames[0].stamp_monotonic)
    render = [f.render_ms for f in frames]
    encode = [f.encode_ms for f in frames]
    kb = [len(f.jpeg) / 1024 for f in frames]
    load = os.getloadavg()[0]
    print(f"machine: {os.cpu_count()} cores, load average {load:.2f}; MUJOCO_GL={os.environ['MUJOCO_GL']}")
    print(f"camera: {args.width}x{args.height} at {args.fps:g} fps requested, antialias {args.antialias}, "
          f"JPEG quality {args.quality}, {wall:.1f} s")
    print(f"physics real-time factor: {stats.realtime_factor:.3f} (lag {stats.lag_s * 1e3:.1f} ms, "
          f"{stats.resyncs} resyncs, {stats.step_us:.0f} us per step incl. servo update)")
    print(f"render per frame: median {statistics.median(render):.1f} ms, p95 {_p95(render):.1f} ms")
    print(f"JPEG encode per frame: median {statistics.median(encode):.1f} ms, p95 {_p95(encode):.1f} ms, "
          f"median size {statistics.median(kb):.0f} KiB")
    print(f"achieved camera fps: {fps:.1f}")
    print(f"process CPU: {100 * cpu / wall:.0f}% of one core")
    return 0


def _p95(values: list[float]) -> float:
    return sorted(values)[max(0, int(round(0.95 * len(values))) - 1)]


if __name__ == "__main__":
    sys.exit(main())
