"""Explicit control's cost: the per-frame mapping alone, and pose-in to joint-command-out over the WebSocket.

Mapping (in process, microseconds). One frame = what the server does for one 90 Hz headset sample: parse and
convert the head and both controller PoseStamped dicts (Unity frame), two Joy messages, then step(). The operator
moves continuously with a little tracking jitter (so the IK cache seldom helps) and both grips held. Scenarios:
  front  hands sweep in front of the body (the common case);
  sides  hands sweep out towards a T-pose, where many targets lie beyond the arm's limits and the IK falls
         back to a bounded Levenberg-Marquardt search;
  mixed  half of each.

Over the wire (milliseconds). `vr-teleop serve --backend sim` runs as its own process; one client engages, then
publishes head poses at 90 Hz and times each until the head command it causes arrives on
/qt_robot/head_position/command. The baseline is a bare websockets echo server (bench/relay.py --echo) timed
the same way in the same run: the ratio is what parsing, validation, mapping and re-publishing add.
`--quick` runs 2,000 mapping frames and 5 s over the wire instead of 20,000 and 20 s.
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import json
import math
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from robot_models import load_qtrobot
from vr_teleop_server.teleop import TeleopMapper

RATE = 90.0
ROOT = Path(__file__).resolve().parent.parent


def pose_msg(pos, quat) -> dict:
    return {"header": {"frame_id": "unity_left_handed", "stamp": {"sec": 0, "nanosec": 0}},
            "pose": {"position": {"x": pos[0], "y": pos[1], "z": pos[2]},
                     "orientation": {"x": quat[0], "y": quat[1], "z": quat[2], "w": quat[3]}}}


def hand_path(side: str, t: float, scenario: str, rng: np.random.Generator) -> list[float]:
    """Unity (x right, y up, z forward) controller position for a seated operator whose eyes are at y=1.2."""
    sign = -1.0 if side == "left" else 1.0
    shoulder = np.array([sign * 0.19, 1.0, -0.08])
    phase = 2 * math.pi * 0.25 * t
    if scenario == "mixed":
        scenario = "front" if int(t / 5.0) % 2 == 0 else "sides"
    if scenario == "front":  # both hands ahead of the body, drifting in parallel
        d = np.array([0.15 * math.sin(phase), 0.2 * math.sin(0.7 * phase), 0.45 + 0.1 * math.cos(phase)])
    else:  # straight arms swinging between forward (a=0) and out to the side (a=1)
        a = 0.5 + 0.5 * math.sin(phase)
        d = 0.58 * np.array([sign * a, 0.1 * math.sin(1.3 * phase), math.sqrt(max(0.0, 1 - a * a))])
    return list(shoulder + d + rng.normal(0, 0.0005, 3))


def run(scenario: str, frames: int, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    mapper = TeleopMapper(load_qtrobot())
    head_q = [0.0, 0.0, 0.0, 1.0]
    mapper.on_head_pose(pose_msg([0.0, 1.2, 0.0], head_q), 0.0)
    mapper.engage(0.0)
    total = np.empty(frames)
    step = np.empty(frames)
    gc.collect()
    for i in range(frames):
        t = (i + 1) / RATE
        yaw = 50 * math.sin(2 * math.pi * 0.2 * t)
        pitch = 15 * math.sin(2 * math.pi * 0.13 * t)
        q = (Rotation.from_rotvec([0, math.radians(yaw), 0]) * Rotation.from_rotvec([math.radians(pitch), 0, 0])).as_quat()
        head = pose_msg([0.0, 1.2, 0.0], q.tolist())
        left = pose_msg(hand_path("left", t, scenario, rng), [0.0, 0.0, 0.0, 1.0])
        right = pose_msg(hand_path("right", t, scenario, rng), [0.0, 0.0, 0.0, 1.0])
        t0 = time.perf_counter_ns()
        mapper.on_head_pose(head, t)
        mapper.on_controller_pose("left", left, t)
        mapper.on_controller_pose("right", right, t)
        mapper.on_joy("left", [0.0, 0.0, 0.0, 1.0], [0, 0, 0, 0], t)
        mapper.on_joy("right", [0.0, 0.0, 0.0, 1.0], [0, 0, 0, 0], t)
        t1 = time.perf_counter_ns()
        out = mapper.step(t)
        t2 = time.perf_counter_ns()
        total[i] = (t2 - t0) / 1e3
        step[i] = (t2 - t1) / 1e3
        if i == 10 and not all(out.arms_following.values()):
            raise RuntimeError("benchmark set-up error: the arms are not following")
    return {"total": total, "step": step}


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def start(cmd: list[str]) -> subprocess.Popen:
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, cwd=ROOT)
    line = proc.stdout.readline()  # "... listening on ..."
    if "listening" not in line:
        proc.kill()
        raise RuntimeError(f"{cmd[2:4]} did not start: {line!r}")
    return proc


def stop(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        proc.kill()


def head_frame(seq: int) -> str:
    t = seq / RATE
    q = Rotation.from_rotvec([0, math.radians(40 * math.sin(2 * math.pi * 0.25 * t)), 0]).as_quat().tolist()
    return json.dumps({"op": "publish", "topic": "/vr/head/pose", "msg": pose_msg([0.0, 1.6, 0.0], q)})


async def wire_latency(url: str, ours: bool, duration: float) -> np.ndarray:
    """Milliseconds from each head pose sent to the joint command (ours) or the echo (baseline) it causes."""
    from websockets.asyncio.client import connect

    async with connect(url, compression=None, max_size=None) as ws:
        if ours:
            await ws.send(json.dumps({"op": "subscribe", "topic": "/qt_robot/head_position/command",
                                      "type": "std_msgs/Float64MultiArray"}))
            for seq in range(20):  # fresh head poses, then engage
                await ws.send(head_frame(seq))
                await asyncio.sleep(1 / RATE)
            await ws.send(json.dumps({"op": "call_service", "id": "engage", "service": "/vr_teleop/control/engage",
                                      "args": {"data": True}}))
            while True:
                reply = json.loads(await asyncio.wait_for(ws.recv(), 10))
                if reply.get("id") == "engage":
                    if not reply.get("result"):
                        raise RuntimeError(f"engage failed: {reply}")
                    break
        samples = []
        seq = 100
        loop = asyncio.get_running_loop()
        next_at = loop.time()
        end = next_at + duration
        while loop.time() < end:
            frame = head_frame(seq)
            sent = time.perf_counter()
            await ws.send(frame)
            while True:  # ours also sends teleop noise (none subscribed here), so skip anything that is not it
                got = await asyncio.wait_for(ws.recv(), 5)
                if not ours or '"/qt_robot/head_position/command"' in got:
                    break
            samples.append((time.perf_counter() - sent) * 1e3)
            seq += 1
            next_at += 1 / RATE
            await asyncio.sleep(max(0.0, next_at - loop.time()))
        return np.array(samples[int(RATE):])  # the first second warms up (ramp, caches)


def wire(duration: float) -> None:
    ours_port, echo_port = free_port(), free_port()
    ours = start([sys.executable, "-m", "vr_teleop_server.cli", "serve", "--port", str(ours_port), "--backend",
                  "sim", "--log-level", "error"])
    echo = start([sys.executable, str(ROOT / "bench" / "relay.py"), "--echo", "--port", str(echo_port)])
    try:
        base = asyncio.run(wire_latency(f"ws://127.0.0.1:{echo_port}", False, duration))
        lat = asyncio.run(wire_latency(f"ws://127.0.0.1:{ours_port}", True, duration))
    finally:
        stop(ours)
        stop(echo)
    print(f"pose in -> head command out over the WebSocket at {RATE:g} Hz, {duration:g} s, server with the "
          f"MuJoCo stand-in (n={lat.size})")
    for name, q in (("p50", 50), ("p99", 99)):
        a, b = np.percentile(lat, q), np.percentile(base, q)
        print(f"  {name}  {a:6.2f} ms   bare echo {b:6.2f} ms   ratio {a / b:5.2f}x")
    print(f"  max  {lat.max():6.2f} ms   bare echo {base.max():6.2f} ms")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=20_000)
    parser.add_argument("--duration", type=float, default=20.0, help="seconds of 90 Hz poses over the wire")
    parser.add_argument("--quick", action="store_true", help="2,000 frames per scenario, 5 s over the wire")
    parser.add_argument("--scenario", choices=["front", "sides", "mixed", "all"], default="all")
    parser.add_argument("--skip-wire", action="store_true", help="only the in-process mapping cost")
    args = parser.parse_args(argv)
    frames = 2_000 if args.quick else args.frames
    scenarios = ["front", "sides", "mixed"] if args.scenario == "all" else [args.scenario]
    budget = 1e6 / RATE
    print(f"teleop mapping, {frames} frames at {RATE:g} Hz per scenario (budget {budget:.0f} us per frame)")
    for sc in scenarios:
        r = run(sc, frames)
        tot, st = r["total"], r["step"]
        p50, p99, mx = np.percentile(tot, 50), np.percentile(tot, 99), tot.max()
        print(f"  {sc:6s} frame p50 {p50:7.0f} us  p99 {p99:7.0f} us  max {mx:7.0f} us | step() p50 "
              f"{np.percentile(st, 50):6.0f} p99 {np.percentile(st, 99):7.0f} us | mean CPU at 90 Hz "
              f"{100 * tot.mean() / budget:4.1f}%")
    if not args.skip_wire:
        wire(5.0 if args.quick else args.duration)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
