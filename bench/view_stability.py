"""How still the classroom stays in the headset during a head turn (issue 36): the camera panel hung by each
frame's capture pose against today's placement by the newest joint state, in the same run.

The server (the stand-in) runs in the WAN emulator's server namespace; Debian's Chromium with IWER as a Quest 3
runs the operator page (WebRTC video) in the client namespace, takes control and turns the head with a recorded
motion: yaw A sin(2 pi f t) with A = 30 degrees at 60 deg/s peak (f = 0.32 Hz), pitch still. The page alternates
its placement every two periods (`camera.placement`: "capture", then "newest", ...), so both see the same motion
and the same link. For every XR frame the page renders it logs which camera frame is on the panel (its RTP
timestamp) and the head pose the panel was hung by.

The error of one rendered frame: a still point of the classroom is drawn where the panel's placement puts it, at
its angle from the camera's axis in the frame, i.e. off by the difference between the pose the panel was hung by
and the pose the frame was really taken at; the angle between the two directions is the error. The truth is
joined on the server's side, independently of the page's own matching: an observer in the server namespace reads
the telemetry's RTP timestamp -> render time of every frame sent, and /vr_teleop/camera/capture_pose's render
time -> the pose the stand-in drew (its JPEG pump runs for it: the same load under both placements).

    python bench/view_stability.py                      # lan and continent, 40 s each
    python bench/view_stability.py --profiles continent --seconds 60

Prints per profile p50 and p95 (degrees) for each placement, the frames counted, and p95 capture / p95 newest.
Needs root and /dev/net/tun, Chromium and IWER (`npm ci`).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from client_protocol import names  # noqa: E402
from netem import Emulator, available, cleanup_leftovers, load_profiles  # noqa: E402
from testbed.pages import operator_in_namespace  # noqa: E402
from testbed.processes import environment  # noqa: E402

PORT = 9090
AMPLITUDE_DEG = 30.0
PEAK_DEG_S = 60.0
FREQUENCY = PEAK_DEG_S / (2 * math.pi * AMPLITUDE_DEG)
SWITCH_PERIODS = 2  # periods of the motion per placement before the other takes over
SETTLE_S = 2.0  # after control is taken, before frames count
WAIT_MS = 60_000
MOTION = f"""(() => {{ const t0 = performance.now(), a = {math.radians(AMPLITUDE_DEG)}, f = {FREQUENCY};
  const c = window.operator.camera; c.trace = [];
  setInterval(() => {{
    const t = (performance.now() - t0) / 1000, yaw = a * Math.sin(2 * Math.PI * f * t);
    xrDevice.quaternion.set(0, Math.sin(yaw / 2), 0, Math.cos(yaw / 2));
    c.placement = Math.floor(t * f / {SWITCH_PERIODS}) % 2 ? "newest" : "capture";
  }}, 5); }})()"""


def serve(net: Emulator) -> subprocess.Popen:
    """The server with the stand-in in the server namespace, once it listens."""
    env = environment()
    log = tempfile.NamedTemporaryFile("w+", prefix="view-stability-", suffix=".log", delete=False)
    proc = net.popen("server", [sys.executable, "-m", "vr_teleop_server.cli", "serve", "--host", net.server_ip,
                                "--port", str(PORT), "--insecure", "--backend", "sim", "--log-level", "warning",
                                "--camera-fps", "30", "--autonomy", "teleoperated"],
                     stdout=subprocess.PIPE, stderr=log, text=True, env=env, cwd=ROOT)
    started = threading.Event()

    def wait_line() -> None:
        for line in proc.stdout:
            if "listening on" in line:
                started.set()
                return

    threading.Thread(target=wait_line, daemon=True).start()
    if not started.wait(180):
        log.seek(0)
        raise RuntimeError(f"the server did not start: {log.read()[-2000:]}")
    return proc


class Truth:
    """In the server namespace: every frame's render time by RTP timestamp (the telemetry) and its capture pose by
    render time (the capture-pose topic, beside the JPEG topic it rides with)."""

    def __init__(self, net: Emulator) -> None:
        self.render: dict[int, float] = {}
        self.poses: dict[float, tuple[float, float]] = {}
        self.ready = threading.Event()
        self.stop = threading.Event()
        self.error: BaseException | None = None
        self.thread = net.start_in("server", self._run, f"ws://{net.server_ip}:{PORT}/")
        if not self.ready.wait(60):
            raise RuntimeError(f"the observer could not subscribe: {self.error}")

    def _run(self, url: str) -> None:
        try:
            asyncio.run(self._observe(url))
        except BaseException as exc:
            self.error = exc
            self.ready.set()

    async def _observe(self, url: str) -> None:
        from websockets.asyncio.client import connect

        async with connect(url, max_size=None, compression=None) as ws:
            for i, (topic, type_name, queue) in enumerate((
                    (names.CAPTURE_POSE_TOPIC, "vr_teleop_msgs/CapturePose", 100),
                    (names.CAMERA_TOPIC, "sensor_msgs/CompressedImage", 1),
                    (names.TELEMETRY_TOPIC, "vr_teleop_msgs/Telemetry", 10))):
                await ws.send(json.dumps({"op": "subscribe", "id": f"s{i}", "topic": topic, "type": type_name,
                                          "queue_length": queue}))
            self.ready.set()
            while not self.stop.is_set():
                try:
                    frame = json.loads(await asyncio.wait_for(ws.recv(), 0.5))
                except TimeoutError:
                    continue
                if frame.get("op") != "publish":
                    continue
                msg = frame["msg"]
                if frame["topic"] == names.CAPTURE_POSE_TOPIC:
                    s = msg["header"]["stamp"]
                    self.poses[round(s["secs"] + s["nsecs"] / 1e9, 4)] = (msg["head_yaw"], msg["head_pitch"])
                elif frame["topic"] == names.TELEMETRY_TOPIC:
                    for client in msg["clients"]:
                        self.render.update(zip(client["frame_rtp_timestamps"], client["frame_render_times"]))

    def pose(self, rtp: int) -> tuple[float, float] | None:
        render = self.render.get(rtp)
        return None if render is None else self.poses.get(round(render, 4))

    def close(self) -> None:
        self.stop.set()
        self.thread.join(10)


def drive(origin: str, seconds: float) -> dict:
    """In the client namespace: the page, engaged, turning its head for `seconds`; its placement log."""
    from playwright.sync_api import sync_playwright

    out: dict = {"trace": []}
    with sync_playwright() as p, operator_in_namespace(p, origin, "webrtc", {"width": 960, "height": 600},
                                                       WAIT_MS) as (page, errors):
        page.get_by_role("button", name="Enter VR").click()
        page.wait_for_function("window.operator.state.xr !== null && window.operator.state.frameCount > 10",
                               timeout=WAIT_MS)
        page.wait_for_function("window.operator.camera.path === 'WebRTC' && window.operator.poses.open",
                               timeout=WAIT_MS)
        for value in (1, 0):  # held for a few XR frames, which is when the page reads the buttons
            page.evaluate(f"xrDevice.controllers.right.updateButtonValue('trigger', {value})")
            seen = page.evaluate("window.operator.state.frameCount")
            page.wait_for_function(f"window.operator.state.frameCount > {seen + 2}", timeout=WAIT_MS)
        page.wait_for_function("document.getElementById('hud-control')?.textContent"
                               ".startsWith('YOU HAVE CONTROL')", timeout=WAIT_MS)
        frames0 = page.evaluate("window.operator.state.frameCount")
        page.evaluate(MOTION)
        start = time.monotonic()
        while time.monotonic() - start < seconds:
            time.sleep(min(5.0, seconds - (time.monotonic() - start)))
            out["trace"] += page.evaluate("window.operator.camera.trace.splice(0)")
        out["xr_fps"] = round((page.evaluate("window.operator.state.frameCount") - frames0) / seconds, 1)
        ages = page.evaluate("window.operator.camera.ages.slice(-300)")
        out["frame_age_ms_p50"] = round(float(np.median(ages)) * 1e3, 1) if ages else None
        out["poses_received"] = page.evaluate("window.operator.camera.rtpPoses.received")
        out["page_errors"] = errors
    return out


def angle_deg(yaw_a: float, pitch_a: float, yaw_b: float, pitch_b: float) -> float:
    """The angle between two directions given as (yaw, pitch) in degrees."""
    def unit(yaw: float, pitch: float) -> np.ndarray:
        y, p = math.radians(yaw), math.radians(pitch)
        return np.array([math.cos(p) * math.sin(y), math.sin(p), math.cos(p) * math.cos(y)])
    return math.degrees(math.acos(float(np.clip(unit(yaw_a, pitch_a) @ unit(yaw_b, pitch_b), -1.0, 1.0))))


def measure(profile: str, seconds: float, trace_to: Path | None = None) -> dict:
    cleanup_leftovers()
    with Emulator(profile) as net:
        serve(net)
        truth = Truth(net)
        try:
            out = net.run_in("client", drive, f"http://{net.server_ip}:{PORT}", seconds)
            time.sleep(1.5)  # the telemetry's last report of the frames sent
        finally:
            truth.close()
    trace = out.pop("trace")
    t0 = trace[0]["t"] if trace else 0.0
    errors: dict[str, list[float]] = {"capture": [], "newest": []}
    held = unknown = 0
    samples: list[dict] = []
    for entry in trace:
        if entry["t"] - t0 < SETTLE_S * 1e3 or entry["path"] != "WebRTC" or entry["key"] is None:
            continue
        real = truth.pose(entry["key"])
        if real is None:
            unknown += 1
            continue
        held += entry["by"] == "nearest"
        errors[entry["mode"]].append(angle_deg(entry["yaw"], entry["pitch"], *real))
        if trace_to is not None:
            samples.append({**entry, "real": real, "error": errors[entry["mode"]][-1]})
    if trace_to is not None:
        trace_to.write_text("\n".join(json.dumps(s) for s in samples))
    row: dict = {"profile": profile, "seconds": seconds, **out, "frames_unmatched": unknown,
                 "capture_frames_by_nearest": held}
    for mode, values in errors.items():
        row[mode] = {"n": len(values), **{f"{name}_deg": round(float(np.percentile(values, q)), 3) if values else None
                                           for name, q in (("p50", 50), ("p95", 95), ("p99", 99), ("max", 100))}}
    if errors["capture"] and errors["newest"]:
        row["p95_ratio_capture_to_newest"] = round(row["capture"]["p95_deg"] / max(row["newest"]["p95_deg"], 1e-9),
                                                   3)
    return row


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--profiles", default="lan,continent",
                        help=f"comma-separated, of: {', '.join(load_profiles())}")
    parser.add_argument("--seconds", type=float, default=40.0, help="of head motion per profile")
    parser.add_argument("--trace", type=Path, help="write each profile's rendered frames, joined with the truth, to "
                                                  "TRACE.PROFILE.jsonl")
    args = parser.parse_args()
    why = available()
    if why:
        print(f"bench/view_stability.py: {why}", file=sys.stderr)
        return 2
    for profile in args.profiles.split(","):
        profile = profile.strip()
        row = measure(profile, args.seconds,
                      None if args.trace is None else args.trace.with_suffix(f".{profile}.jsonl"))
        print(json.dumps(row))
        if "p95_ratio_capture_to_newest" in row:
            print(f"{profile}: p95 {row['capture']['p95_deg']} deg with the capture pose, {row['newest']['p95_deg']}"
                  f" deg with the newest joint state: ratio {row['p95_ratio_capture_to_newest']}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
