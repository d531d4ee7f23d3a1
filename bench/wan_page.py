"""The operator page (Debian's Chromium, the headset emulated by IWER) across an emulated WAN: its own poses
sender, the browser's SCTP, on the poses data channel, or the WebSocket path with #camera=jpeg.

The server runs in the emulator's server namespace (as bench/wan.py's); Chromium runs in the client namespace and
loads the page from the server's address (`--unsafely-treat-insecure-origin-as-secure`: WebXR wants a secure
context), enters VR, takes control, and sweeps the head +-34 degrees at 0.25 Hz for `--seconds`. An observer
beside the server records the watchdog's events and the head poses as the bus gets them. Printed: holds, the XR
frame rate, head poses arriving per second and the longest silence between them, the page's channel counts (sent,
replaced before sending) and the camera frames it showed.

    python bench/wan_page.py --profile continent --mode webrtc --seconds 60
    python bench/wan_page.py --profile continent --mode jpeg --seconds 60

Needs root and /dev/net/tun, Chromium and IWER (`npm ci`).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT)]

from netem import Emulator, available, cleanup_leftovers, load_profiles  # noqa: E402
from testbed.pages import operator_in_namespace  # noqa: E402
from testbed.wan_support import Observer, serve  # noqa: E402

SWEEP = """(() => { const t0 = performance.now(); setInterval(() => {
  const a = 0.6 * Math.sin((performance.now() - t0) / 1000 * 2 * Math.PI * 0.25);
  xrDevice.quaternion.set(0, Math.sin(a / 2), 0, Math.cos(a / 2)); }, 10); })()"""
WAIT_MS = 60_000


def drive(host: str, mode: str, seconds: float) -> dict:
    """In the client namespace: the page, engaged, sweeping its head for `seconds`."""
    from playwright.sync_api import sync_playwright

    origin = f"http://{host}"
    out: dict = {}
    with sync_playwright() as p, operator_in_namespace(p, origin, mode, {"width": 960, "height": 600}, WAIT_MS) \
            as (page, errors):
        page.get_by_role("button", name="Enter VR").click()
        page.wait_for_function("window.operator.state.xr !== null && window.operator.state.frameCount > 10",
                               timeout=WAIT_MS)
        if mode == "webrtc":
            page.wait_for_function("window.operator.poses.open", timeout=WAIT_MS)
        page.evaluate("xrDevice.controllers.right.updateButtonValue('trigger', 1)")
        time.sleep(0.3)
        page.evaluate("xrDevice.controllers.right.updateButtonValue('trigger', 0)")
        page.wait_for_function("document.getElementById('hud-control')?.textContent.startsWith('YOU HAVE CONTROL')",
                               timeout=WAIT_MS)
        out["engaged"] = time.monotonic()
        frames0 = page.evaluate("window.operator.state.frameCount")
        page.evaluate(SWEEP)
        time.sleep(seconds)
        out["end"] = time.monotonic()
        out["xr_fps"] = round((page.evaluate("window.operator.state.frameCount") - frames0) / seconds, 1)
        out["channel"] = page.evaluate("window.operator.poses.stats()")
        out["camera"] = page.evaluate("window.operator.camera.stats()")
        out["page_errors"] = errors
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--profile", default="continent", choices=list(load_profiles()))
    parser.add_argument("--mode", default="webrtc", choices=["webrtc", "jpeg"],
                        help="webrtc: poses on the data channel once engaged; jpeg: no peer connection, rosbridge")
    parser.add_argument("--seconds", type=float, default=60.0)
    args = parser.parse_args()
    why = available()
    if why:
        print(f"bench/wan_page.py: {why}", file=sys.stderr)
        return 2
    cleanup_leftovers()
    with Emulator(args.profile) as net:
        url = serve(net, "--camera-fps", "30")
        observer = Observer(net, url, poses=True)
        out = net.run_in("client", drive, url.split("//", 1)[1].rstrip("/"), args.mode, args.seconds)
        seen = observer.stop()
    engaged, end = out.pop("engaged"), out.pop("end")
    holds = [e for t, e in seen.events if e["kind"] == "watchdog_stalled" and engaged < t < end]
    arrivals = np.array([t for t, _stamp in seen.poses if engaged + 1.0 < t < end])
    gaps = np.diff(arrivals)
    out.update(profile=args.profile, mode=args.mode, holds=len(holds),
               holds_per_min=round(len(holds) / ((end - engaged) / 60.0), 2),
               head_arrivals_per_s=round(len(arrivals) / max(end - engaged - 1.0, 1e-9), 1),
               head_silence_ms={"p99": round(float(np.percentile(gaps, 99)) * 1e3, 1) if gaps.size else None,
                                "max": round(float(gaps.max()) * 1e3, 1) if gaps.size else None})
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
