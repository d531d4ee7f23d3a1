"""Explicit control's cost: the per-frame mapping alone, and pose-in to joint-command-out over the WebSocket.

Mapping (in process, microseconds). One frame = what the server does for one 90 Hz headset sample: parse and
convert the head and both controller PoseStamped dicts (Unity frame), two Joy messages, then step(). The operator
moves continuously with a little tracking jitter (so the IK cache seldom helps) and both grips held. Scenarios:
  front  hands sweep in front of the body (the common case);
  sides  hands sweep out towards a T-pose, where many targets lie beyond the arm's limits and the IK falls
         back to a bounded Levenberg-Marquardt search;
  mixed  half of each.
Each frame runs through today's TeleopMapper and through the step as it was before issue 28, taken from git at
BASELINE_COMMIT (same poses, the two interleaved frame by frame, their commands compared as they go; see
reference_mapper: a clone without that commit, a shallow one, stops with the fix).
Costs are this thread's CPU time (time.thread_time_ns), so that the scheduler's pauses on a busy machine, which
land on whichever implementation happens to run, stay out of the ratio; wall-clock percentiles are printed too.
The targets: now/reference <= 0.25 at p50 and p99, and one operator at 90 Hz under 5% of a core (process CPU
time over the frames' span of operator time).

Over the wire (milliseconds). `vr-teleop serve --backend sim` runs as its own process; one client engages, then
publishes head poses at 90 Hz and times each until the head command it causes arrives on
/qt_robot/head_position/command. The baseline is a bare websockets echo server (bench/relay.py --echo) sent the
same pose in the same tick: the ratio is what parsing, validation, mapping and re-publishing add. The poses are
rosbridge frames written once and sent as they are to both (the raw wire is what is measured); the engage answer is
read by the package client's refusal rule (vr_teleop_server.client.outcome).
`--quick` runs 2,000 mapping frames and 5 s over the wire instead of 20,000 and 20 s.
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import io
import json
import math
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from client_protocol.names import ENGAGE_SERVICE  # noqa: E402
from robot_models import load_qtrobot  # noqa: E402
from testbed.processes import free_port, serve, start, stop  # noqa: E402
from vr_teleop_server.client import outcome  # noqa: E402
from vr_teleop_server.teleop import TeleopMapper  # noqa: E402

RATE = 90.0
# The last commit whose vr_teleop_server/teleop/ is the step before issue 28 (its parent of 5dbce16 made the plain-
# float step): the baseline this bench divides by, never to be fixed or sped up.
BASELINE_COMMIT = "377e5c021e157f2de2abd326406038672b53b691"
# The baseline's only changes, imports: the IK it called lived in robot_models then (it comes along, as
# kinematics.py, on today's robot model), and the settings model is today's (read once, on no frame's path).
BASELINE_IMPORTS = {
    "mapper.py": {"from robot_models import RobotModel, arm_ik, load_qtrobot":
                  "from robot_models import RobotModel, load_qtrobot\n\nfrom .kinematics import arm_ik",
                  "from .settings import TeleopSettings": "from vr_teleop_server.teleop.settings import TeleopSettings"},
    "kinematics.py": {"from .qtrobot import": "from robot_models.qtrobot import"},
}


def reference_mapper(workdir: Path) -> type:
    """TeleopMapper as it was at BASELINE_COMMIT, materialised from this clone's history into `workdir` as the
    package teleop_reference and imported from there."""
    if subprocess.run(["git", "-C", str(ROOT), "cat-file", "-e", f"{BASELINE_COMMIT}^{{commit}}"],
                      capture_output=True).returncode != 0:
        shallow = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--is-shallow-repository"],
                                 capture_output=True, text=True).stdout.strip() == "true"
        raise SystemExit(f"bench/teleop.py compares against the teleop step at commit {BASELINE_COMMIT[:7]}, which "
                         f"this {'shallow clone' if shallow else 'checkout'} does not have: "
                         f"{'`git fetch --unshallow`' if shallow else 'run it from a clone of the repository'}")
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", BASELINE_COMMIT,
                              "vr_teleop_server/teleop", "robot_models/kinematics.py"],
                             capture_output=True, check=True).stdout
    tree = workdir / "tree"
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        tar.extractall(tree, filter="data")
    package = workdir / "teleop_reference"
    (tree / "vr_teleop_server" / "teleop").rename(package)
    (tree / "robot_models" / "kinematics.py").rename(package / "kinematics.py")
    (package / "settings.py").unlink()
    (package / "__init__.py").write_text(f'"""The teleop step at {BASELINE_COMMIT[:7]}."""\n'
                                         "from .mapper import TeleopMapper\n")
    for name, imports in BASELINE_IMPORTS.items():
        text = (package / name).read_text()
        for was, now in imports.items():
            if was not in text:
                raise RuntimeError(f"{BASELINE_COMMIT[:7]}'s {name} has no line {was!r}")
            text = text.replace(was, now)
        (package / name).write_text(text)
    sys.path.insert(0, str(workdir))
    from teleop_reference import TeleopMapper as reference  # made just above

    return reference


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


def frames_of(scenario: str, frames: int, seed: int = 0) -> list[tuple[float, dict, dict, dict]]:
    """The operator's poses, made once so that both implementations map the very same messages."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(frames):
        t = (i + 1) / RATE
        yaw = 50 * math.sin(2 * math.pi * 0.2 * t)
        pitch = 15 * math.sin(2 * math.pi * 0.13 * t)
        q = (Rotation.from_rotvec([0, math.radians(yaw), 0]) * Rotation.from_rotvec([math.radians(pitch), 0, 0])).as_quat()
        out.append((t, pose_msg([0.0, 1.2, 0.0], q.tolist()),
                    pose_msg(hand_path("left", t, scenario, rng), [0.0, 0.0, 0.0, 1.0]),
                    pose_msg(hand_path("right", t, scenario, rng), [0.0, 0.0, 0.0, 1.0])))
    return out


def engaged(mapper_class: type) -> Any:
    mapper = mapper_class(load_qtrobot())
    mapper.on_head_pose(pose_msg([0.0, 1.2, 0.0], [0.0, 0.0, 0.0, 1.0]), 0.0)
    mapper.engage(0.0)
    return mapper


def one_frame(mapper: Any, t: float, head: dict, left: dict, right: dict) -> tuple[float, float, float, Any]:
    """(frame us of wall time, frame us of this thread's CPU time, step() us of CPU, output): what the server does
    for one 90 Hz headset sample. CPU time leaves out the time the scheduler gave other processes, which on a
    busy machine puts millisecond spikes into the wall-clock tail of whichever implementation it happens to hit."""
    w0 = time.perf_counter_ns()
    t0 = time.thread_time_ns()
    mapper.on_head_pose(head, t)
    mapper.on_controller_pose("left", left, t)
    mapper.on_controller_pose("right", right, t)
    mapper.on_joy("left", [0.0, 0.0, 0.0, 1.0], [0, 0, 0, 0], t)
    mapper.on_joy("right", [0.0, 0.0, 0.0, 1.0], [0, 0, 0, 0], t)
    t1 = time.thread_time_ns()
    out = mapper.step(t)
    t2 = time.thread_time_ns()
    w2 = time.perf_counter_ns()
    return (w2 - w0) / 1e3, (t2 - t0) / 1e3, (t2 - t1) / 1e3, out


def run(reference: type, scenario: str, frames: int, seed: int = 0) -> dict[str, dict[str, np.ndarray] | float]:
    """Both implementations over the same poses, frame by frame in alternating order (neither always goes first
    on a busy machine); their commands are compared as they go."""
    poses = frames_of(scenario, frames, seed)
    mappers = {"reference": engaged(reference), "now": engaged(TeleopMapper)}
    times = {k: {"wall": np.empty(frames), "cpu": np.empty(frames), "step": np.empty(frames)} for k in mappers}
    worst = 0.0
    gc.collect()
    for i, frame in enumerate(poses):
        outs = {}
        for k in (("reference", "now") if i % 2 else ("now", "reference")):
            times[k]["wall"][i], times[k]["cpu"][i], times[k]["step"][i], outs[k] = one_frame(mappers[k], *frame)
        a, b = outs["reference"], outs["now"]
        if a.commands.keys() != b.commands.keys():
            raise RuntimeError(f"frame {i}: parts moved differ: {sorted(a.commands)} against {sorted(b.commands)}")
        for part in a.commands:
            worst = max(worst, max(abs(x - y) for x, y in zip(a.commands[part], b.commands[part])))
        if i == 10 and not all(b.arms_following.values()):
            raise RuntimeError("benchmark set-up error: the arms are not following")
    return {**times, "worst_deg": worst}


def cpu_per_operator(reference: type, frames: int) -> tuple[float, float]:
    """(process CPU seconds per second of operator at 90 Hz, as a fraction of one core) for each implementation:
    the mixed scenario's frames fed back to back, CPU time by the process clock (not wall time)."""
    poses = frames_of("mixed", frames, 1)
    out = []
    for cls in (reference, TeleopMapper):
        mapper = engaged(cls)
        gc.collect()
        c0 = time.process_time()
        for frame in poses:
            one_frame(mapper, *frame)
        out.append((time.process_time() - c0) / (frames / RATE))
    return out[0], out[1]


def head_frame(seq: int) -> str:
    t = seq / RATE
    q = Rotation.from_rotvec([0, math.radians(40 * math.sin(2 * math.pi * 0.25 * t)), 0]).as_quat().tolist()
    return json.dumps({"op": "publish", "topic": "/vr/head/pose", "msg": pose_msg([0.0, 1.6, 0.0], q)})


async def engage_over_wire(ws: Any) -> None:
    await ws.send(json.dumps({"op": "subscribe", "topic": "/qt_robot/head_position/command",
                              "type": "std_msgs/Float64MultiArray"}))
    for seq in range(20):  # fresh head poses, then engage
        await ws.send(head_frame(seq))
        await asyncio.sleep(1 / RATE)
    await ws.send(json.dumps({"op": "call_service", "id": "engage", "service": ENGAGE_SERVICE, "args": {"data": True}}))
    while True:
        reply = json.loads(await asyncio.wait_for(ws.recv(), 10))
        if reply.get("id") == "engage":
            outcome(reply, ENGAGE_SERVICE)  # the package client's refusal rule: raises unless engaged
            return


async def round_trip(ws: Any, frame: str, ours: bool) -> float:
    """Milliseconds from sending `frame` to the head command it causes (ours) or its echo (the baseline)."""
    sent = time.perf_counter()
    await ws.send(frame)
    while True:  # ours also sends teleop noise (none subscribed here), so skip anything that is not it
        got = await asyncio.wait_for(ws.recv(), 5)
        if not ours or '"/qt_robot/head_position/command"' in got:
            return (time.perf_counter() - sent) * 1e3


async def wire_latency(ours_url: str, echo_url: str, duration: float) -> tuple[np.ndarray, np.ndarray]:
    """Each 90 Hz tick sends the same head pose to both servers, one after the other, the order alternating:
    both see the same moments of a busy machine, and neither always goes first."""
    from websockets.asyncio.client import connect

    async with connect(ours_url, compression=None, max_size=None) as ours, \
            connect(echo_url, compression=None, max_size=None) as echo:
        await engage_over_wire(ours)
        samples: dict[bool, list[float]] = {True: [], False: []}
        seq = 100
        loop = asyncio.get_running_loop()
        next_at = loop.time()
        end = next_at + duration
        while loop.time() < end:
            frame = head_frame(seq)
            for is_ours in ((True, False) if seq % 2 else (False, True)):
                samples[is_ours].append(await round_trip(ours if is_ours else echo, frame, is_ours))
            seq += 1
            next_at += 1 / RATE
            await asyncio.sleep(max(0.0, next_at - loop.time()))
        # the first second warms up (ramp, caches); on a machine so loaded that a short run got fewer ticks than
        # that, its first half (rather than an empty sample and an IndexError)
        warm = min(int(RATE), len(samples[True]) // 2)
        return np.array(samples[True][warm:]), np.array(samples[False][warm:])


def wire(duration: float) -> None:
    ours = serve("--backend", "sim")
    echo_port = free_port()
    echo = start([sys.executable, str(ROOT / "bench" / "relay.py"), "--echo", "--port", str(echo_port)])
    try:
        lat, base = asyncio.run(wire_latency(ours.url, f"ws://127.0.0.1:{echo_port}", duration))
    finally:
        stop(ours)
        stop(echo)
    print(f"pose in -> head command out over the WebSocket at {RATE:g} Hz, {duration:g} s, server with the "
          f"MuJoCo stand-in, against a bare echo in the same ticks (n={lat.size})")
    for name, q in (("p50", 50), ("p99", 99)):
        a, b = np.percentile(lat, q), np.percentile(base, q)
        print(f"  {name}  {a:6.2f} ms   bare echo {b:6.2f} ms   ratio {a / b:5.2f}x   (target p99 <= 1.5x)")
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
    with tempfile.TemporaryDirectory(prefix="teleop-baseline-") as workdir:
        reference = reference_mapper(Path(workdir))
        mapping(reference, scenarios, frames, budget)
    if not args.skip_wire:
        wire(5.0 if args.quick else args.duration)
    return 0


def mapping(reference: type, scenarios: list[str], frames: int, budget: float) -> None:
    print(f"teleop mapping, {frames} frames at {RATE:g} Hz per scenario (budget {budget:.0f} us per frame), head and "
          f"both arms following; the reference is the step before issue 28 (git {BASELINE_COMMIT[:7]}), same poses, "
          "frames interleaved")
    for sc in scenarios:
        r = run(reference, sc, frames)
        row = {}
        for k in ("reference", "now"):
            cpu, wall, st = r[k]["cpu"], r[k]["wall"], r[k]["step"]
            row[k] = (np.percentile(cpu, 50), np.percentile(cpu, 99))
            print(f"  {sc:6s} {k:9s} frame CPU p50 {row[k][0]:5.0f} us  p99 {row[k][1]:5.0f} us  max {cpu.max():6.0f} us"
                  f" | step() CPU p50 {np.percentile(st, 50):4.0f} p99 {np.percentile(st, 99):5.0f} us"
                  f" | wall p50 {np.percentile(wall, 50):5.0f} p99 {np.percentile(wall, 99):6.0f} us")
        print(f"  {sc:6s} now/reference  frame CPU p50 {row['now'][0] / row['reference'][0]:5.3f}  "
              f"p99 {row['now'][1] / row['reference'][1]:5.3f}   (target <= 0.25; commands differ by at most "
              f"{r['worst_deg']:.2g} deg)")
    ref_cpu, now_cpu = cpu_per_operator(reference, frames)
    print(f"  CPU per operator at {RATE:g} Hz (process time, mixed): reference {100 * ref_cpu:4.1f}% of a core, "
          f"now {100 * now_cpu:4.2f}% (target < 5%)")


if __name__ == "__main__":
    raise SystemExit(main())
