"""The QTrobot v3 backend (`--backend luxai`) against the fake v3 hub of the tests (testbed/luxai_hub.py), in one process.

Figures, over `--rounds` alternating rounds (the machine's load drifts):
- the cost of one joint command on the caller's thread (the event loop): LuxaiRobot.set_joint_targets (clamp, the
  SDK's JointCommandFrame, its stream writer: msgpack and a ZeroMQ send) against clamp_command alone, as a ratio;
- command delivery: set_joint_targets to the frame arriving at the hub, p50 and p95 in ms, over ZeroMQ and, where
  Debian's mosquitto is installed, through it on loopback (MQTT against ZeroMQ, as a ratio).

    PYTHONPATH=. python bench/qtrobot_v3.py [--rounds N] [--commands N]
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from testbed.luxai_hub import FakeQtrobotV3  # noqa: E402
from testbed.processes import free_port  # noqa: E402
from vr_teleop_server.robot.backends.luxai import LuxaiRobot  # noqa: E402
from vr_teleop_server.robot.interface import clamp_command  # noqa: E402


def call_cost(robot: LuxaiRobot, n: int) -> tuple[float, float]:
    """(seconds per set_joint_targets, seconds per clamp_command), measured back to back."""
    command = {"HeadYaw": 10.0, "HeadPitch": 5.0}
    t = time.perf_counter()
    for _ in range(n):
        clamp_command(robot.model, command)
    base = (time.perf_counter() - t) / n
    t = time.perf_counter()
    for i in range(n):
        robot.set_joint_targets({"HeadYaw": 10.0 + (i % 2), "HeadPitch": 5.0})
    return (time.perf_counter() - t) / n, base


def delivery(robot: LuxaiRobot, hub: FakeQtrobotV3, n: int) -> list[float]:
    """Milliseconds from set_joint_targets to the hub's reader, one command at a time (20 ms apart)."""
    start = len(hub.commands)
    sent = {}
    for i in range(n):
        target = round(-10.0 + 20.0 * i / n, 3)
        sent[target] = time.monotonic()
        robot.set_joint_targets({"HeadPitch": target})
        time.sleep(0.02)
    deadline = time.monotonic() + 5
    while len(hub.commands) - start < n and time.monotonic() < deadline:
        time.sleep(0.05)
    arrivals = {c.get("HeadPitch", {}).get("position"): t
                for c, t in zip(hub.commands[start:], hub.command_times[start:])}
    return [1000 * (arrivals[t] - sent[t]) for t in sent if t in arrivals]


def start_mosquitto(tmp: Path) -> tuple[subprocess.Popen, int] | None:
    binary = shutil.which("mosquitto") or ("/usr/sbin/mosquitto" if Path("/usr/sbin/mosquitto").exists() else None)
    if binary is None:
        return None
    port = free_port()
    config = tmp / "mosquitto.conf"
    config.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n")
    proc = subprocess.Popen([binary, "-c", str(config)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(0.5)
    return proc, port


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--commands", type=int, default=2000, help="calls per round for the cost")
    args = parser.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="bench-luxai-"))
    broker = start_mosquitto(tmp)
    zmq_hub = FakeQtrobotV3(camera=False).start()
    zmq_robot = LuxaiRobot(f"tcp://127.0.0.1:{zmq_hub.hub_port}", camera_url=f"tcp://127.0.0.1:{free_port()}")
    zmq_robot.connect()
    mqtt_hub = mqtt_robot = None
    if broker is not None:
        url = f"mqtt://127.0.0.1:{broker[1]}"
        mqtt_hub = FakeQtrobotV3(broker=url, zmq=False, camera=False).start()
        mqtt_robot = LuxaiRobot(url, robot_id=mqtt_hub.robot_id)
        mqtt_robot.connect()
    try:
        time.sleep(0.5)
        ratios, costs, zmq_ms, mqtt_ms = [], [], [], []
        for _ in range(args.rounds):
            cost, base = call_cost(zmq_robot, args.commands)
            costs.append(cost)
            ratios.append(cost / base)
            zmq_ms += delivery(zmq_robot, zmq_hub, 100)
            if mqtt_robot is not None:
                mqtt_ms += delivery(mqtt_robot, mqtt_hub, 100)
        print(f"set_joint_targets on the caller's thread: {1e6 * statistics.median(costs):.0f} us a command, "
              f"{statistics.median(ratios):.1f}x clamp_command alone (median of {args.rounds} rounds)")

        def pct(values: list[float], q: float) -> float:
            return sorted(values)[min(len(values) - 1, int(q * len(values)))]

        print(f"delivery over ZeroMQ: p50 {pct(zmq_ms, 0.5):.2f} ms, p95 {pct(zmq_ms, 0.95):.2f} ms "
              f"({len(zmq_ms)} commands)")
        if mqtt_ms:
            print(f"delivery through mosquitto: p50 {pct(mqtt_ms, 0.5):.2f} ms, p95 {pct(mqtt_ms, 0.95):.2f} ms "
                  f"({len(mqtt_ms)} commands); p50 {pct(mqtt_ms, 0.5) / pct(zmq_ms, 0.5):.1f}x ZeroMQ's")
        else:
            print("delivery through mosquitto: skipped (mosquitto is not installed)")
    finally:
        for robot in (zmq_robot, mqtt_robot):
            if robot is not None:
                robot.close()
        for hub in (zmq_hub, mqtt_hub):
            if hub is not None:
                hub.stop()
        if broker is not None:
            broker[0].terminate()
            broker[0].wait(10)
    return 0


if __name__ == "__main__":
    sys.exit(main())
