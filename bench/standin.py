"""Stand-in figures: physics real-time factor and step cost, camera render and JPEG times, achieved fps.

Runs the stand-in with the camera streaming while the head sweeps, then prints one line per figure. Then the
robot API from asyncio (SimRobot): each call's time from the loop, the loop's worst pause while a gesture plays,
the gesture recorder's achieved rate, a recorded sweep's replay lag and peak speed at x2 against the cap, and how
long closing the stand-in takes. Then the same through the server: `vr-teleop serve` in its own process, one
rosbridge client subscribed to the camera and the joint states, reporting the fps that subscriber actually
receives, the frames' age on arrival, the joint-state rate (30 Hz asked), the server process's CPU time per frame
delivered, and how long the server takes to stop on SIGINT. `--quick` runs 3 s instead of 10.
The tests assert order and design bounds on these (tests/test_backend_sim.py, test_gestures.py,
test_luxai_standin.py, test_cli_serve.py, test_sim_standin.py); the speeds are measured here.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import testbed  # noqa: E402,F401 (first: it sets MUJOCO_GL before MuJoCo is imported)
from sim import StandIn  # noqa: E402
from testbed import processes  # noqa: E402


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
    import asyncio

    asyncio.run(robot_api())
    return served(seconds, args.width, args.height, args.fps)


async def robot_api() -> None:
    """SimRobot from the event loop: call times, loop pauses, recorder rate, replay lag and peak speed, close."""
    import asyncio
    import math

    import numpy as np

    from robot_models import load_qtrobot
    from vr_teleop_server.robot.backends.sim import SimRobot
    from vr_teleop_server.robot.gestures import GestureRecorder
    from vr_teleop_server.robot.interface import Gesture, Waypoint

    model = load_qtrobot()
    robot = await SimRobot.create(model)
    try:
        calls = {"set_part_targets": lambda: robot.set_part_targets("head", [5.0, 5.0]),
                 "joint_state": robot.joint_state, "motor_status": robot.motor_status,
                 "show_emotion": lambda: robot.show_emotion("happy"), "latest_frame": robot.latest_frame}
        for name, call in calls.items():
            times = []
            for _ in range(200):
                t0 = time.perf_counter()
                call()
                times.append((time.perf_counter() - t0) * 1e3)
            print(f"robot call from the loop, {name}: median {statistics.median(times):.3f} ms, "
                  f"p95 {_p95(times):.3f} ms, max {max(times):.2f} ms")

        gesture = Gesture("nod", tuple(Waypoint(t, {"HeadYaw": 20.0 * math.sin(math.pi * t / 0.8)})
                                       for t in np.arange(0.0, 0.85, 0.05)))
        gaps: list[float] = []

        async def ticker() -> None:
            last = time.monotonic()
            while True:
                await asyncio.sleep(0.01)
                now = time.monotonic()
                gaps.append(now - last)
                last = now

        tick = asyncio.create_task(ticker())
        t0 = time.monotonic()
        await robot.play_gesture(gesture)
        elapsed = time.monotonic() - t0
        tick.cancel()
        print(f"gesture of {gesture.duration_s:.2f} s played in {elapsed:.2f} s; the loop's worst pause meanwhile "
              f"{max(gaps) * 1e3:.0f} ms (10 ms sleeps)")

        # Record a 4 s head sweep at the recorder's rate, then replay it at x1 (lag) and x2 (peak speed).
        rec = GestureRecorder(model)
        rec.start(["head"], name="sweep")
        t0 = time.monotonic()
        while (t := time.monotonic() - t0) < 4.4:
            robot.set_joint_targets({"HeadYaw": 35.0 * math.sin(2 * math.pi * min(t, 4.0) / 4.0)})
            rec.sample(robot.joint_state())
            await asyncio.sleep(rec.period_s)
        recorded = rec.stop()
        print(f"gesture recorder: {len(recorded.waypoints) / recorded.duration_s:.1f} Hz achieved "
              f"({1 / rec.period_s:g} Hz asked)")
        rt = np.array([wp.time_s for wp in recorded.waypoints])
        ry = np.array([wp.targets["HeadYaw"] for wp in recorded.waypoints])
        for speed in (1.0, 2.0):
            robot.home()
            await asyncio.sleep(1.5)
            samples = []
            stop = asyncio.Event()

            async def poll() -> None:
                while not stop.is_set():
                    samples.append(robot.standin.joint_state())
                    await asyncio.sleep(0.02)

            poller = asyncio.create_task(poll())
            start = time.monotonic()
            await robot.play_gesture(recorded, speed=speed)
            stop.set()
            await poller
            t = np.array([s.stamp_monotonic - start for s in samples]) * speed
            yaw = np.array([s.position("HeadYaw") for s in samples])
            if speed == 1.0:
                inside = t <= recorded.duration_s
                ref = np.interp(t[inside], rt, ry)
                delays = np.arange(0.0, 1.0, 0.005)
                errors = [np.sqrt(np.mean((np.interp(t[inside] + d, t, yaw) - ref) ** 2)) for d in delays]
                print(f"replay at x1 lags the recording by {delays[int(np.argmin(errors))] * 1e3:.0f} ms "
                      f"(shape RMS {min(errors):.2f} deg once removed)")
            else:
                peak = max(abs(s.velocities[s.names.index("HeadYaw")]) for s in samples)
                print(f"replay at x2: peak yaw speed {peak:.1f} deg/s against a "
                      f"{model.joint('HeadYaw').max_velocity:g} deg/s cap")
    finally:
        t0 = time.monotonic()
        robot.close()
        print(f"closing the stand-in: {(time.monotonic() - t0) * 1e3:.0f} ms")


def served(seconds: float, width: int, height: int, fps: float) -> int:
    """The camera as one rosbridge subscriber of a real server sees it."""
    import asyncio
    import json
    import signal

    import psutil
    from websockets.asyncio.client import connect

    proc = processes.serve("--camera-size", f"{width}x{height}", "--camera-fps", str(fps), log_level="warning")
    port = proc.port
    server = psutil.Process(proc.pid)

    states: list[float] = []

    async def run() -> tuple[list[float], list[float], float]:
        arrivals, ages = [], []
        async with connect(f"ws://127.0.0.1:{port}", max_size=None, compression=None) as ws:
            await ws.send(json.dumps({"op": "subscribe", "topic": "/camera/color/image_raw/compressed",
                                      "type": "sensor_msgs/CompressedImage"}))
            await ws.send(json.dumps({"op": "subscribe", "topic": "/qt_robot/joints/state",
                                      "type": "sensor_msgs/JointState"}))
            await ws.send(json.dumps({"op": "advertise", "topic": "/qt_robot/head_position/command",
                                      "type": "std_msgs/Float64MultiArray"}))
            await asyncio.wait_for(ws.recv(), 10)  # the first frame pays for warm-up
            cpu0 = sum(server.cpu_times()[:2])
            t0 = time.monotonic()
            next_command = t0
            while time.monotonic() - t0 < seconds:
                if time.monotonic() >= next_command:
                    yaw = 40.0 if (time.monotonic() - t0) % 4.0 < 2.0 else -40.0
                    await ws.send(json.dumps({"op": "publish", "topic": "/qt_robot/head_position/command",
                                              "msg": {"data": [yaw, 5.0]}}))
                    next_command += 0.05
                try:
                    frame = json.loads(await asyncio.wait_for(ws.recv(), 0.05))
                except TimeoutError:
                    continue
                if frame.get("topic") == "/qt_robot/joints/state":
                    states.append(time.monotonic())
                if frame.get("topic") == "/camera/color/image_raw/compressed":
                    stamp = frame["msg"]["header"]["stamp"]
                    arrivals.append(time.monotonic())
                    ages.append((time.time() - (stamp["secs"] + stamp["nsecs"] * 1e-9)) * 1000)
            return arrivals, ages, sum(server.cpu_times()[:2]) - cpu0

    stopped_s = float("nan")
    try:
        arrivals, ages, cpu = asyncio.run(run())
    finally:
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        if proc.wait(30) == 0:
            stopped_s = time.monotonic() - t0
    if len(arrivals) < 2:
        print("through the server: no camera frames arrived", file=sys.stderr)
        return 1
    received_fps = (len(arrivals) - 1) / (arrivals[-1] - arrivals[0])
    print(f"through the server, one subscriber: {received_fps:.1f} fps received, frame age on arrival median "
          f"{statistics.median(ages):.1f} ms, p95 {_p95(ages):.1f} ms")
    if len(states) > 1:
        print(f"joint states received: {(len(states) - 1) / (states[-1] - states[0]):.1f} Hz (30 Hz asked)")
    print(f"server stop on SIGINT: {stopped_s * 1e3:.0f} ms to exit 0")
    print(f"server CPU per frame delivered: {1000 * cpu / len(arrivals):.1f} ms "
          f"({100 * cpu / seconds:.0f}% of one core over {seconds:g} s, physics and rendering included)")
    return 0


def _p95(values: list[float]) -> float:
    return sorted(values)[max(0, int(round(0.95 * len(values))) - 1)]


if __name__ == "__main__":
    sys.exit(main())
