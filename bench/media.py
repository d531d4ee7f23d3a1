"""WebRTC media against the JPEG topic, side by side in one run, on loopback (issue 20).

Figures:
- glass to glass: the stand-in's render time (frame stamp) to the frame shown in Chromium: the dashboard's camera
  panel, WebRTC (requestVideoFrameCallback's expected display time, render time from the telemetry's RTP mapping)
  against the JPEG topic (the image decoded), p50/p95, at 640x480 and 1280x720, with the codec --codec names
  (default H.264: what the page asks for on a Quest); beside it, where a WebRTC frame's time goes (the page's
  getStats: jitter buffer, assembly, decode) and the server's render to send for both paths;
- bandwidth per path at 30 fps (WebRTC: the server's bytes sent to one peer; JSON: bytes on the WebSocket);
- server CPU per delivered frame per path (the CPU time of the server process and its video encoder process
  over frames delivered; a second row adds the stand-in's render process, which since issue 29 makes the JPEG only
  for the JPEG path);
- frames per second with 1 and 5 WebRTC viewers (aiortc peers in another process, pinned to other cores than the
  server's when the machine has 4 or more; they count packets without decoding, except the first, which decodes
  to check the picture);
- on a 1 Mbit/s bottleneck (LinkShaper, a drop-tail queue on the server's side) with the head sweeping: fps and
  the encoder's bitrate;
- speech text in to first audio sample (RMS above the floor) out at an aiortc peer, p50;
- pose round trip p99 with 5 WebRTC viewers against none (the control stream must not suffer: within 1.2x),
  over `--rounds` alternating rounds (the machine's load drifts; more rounds, steadier figures); beside it, the
  share of a core the server's loop thread uses meanwhile, with 5 viewers against none (the peers' own work runs
  on the media loop's thread since issue 29, so the loop's share should hardly move; less noisy than a p99).

Servers run as subprocesses (`vr-teleop serve --backend sim`), as in bench/suite.py. Control traffic (offers, head
commands, speech, telemetry) goes through the package's client (testbed/media_client.py's Rosbridge over
vr_teleop_server.client); the JSON camera path subscribes by hand and reads the raw frames, since their bytes on
the WebSocket are the figure; the pose round trip is bench/roundtrip.py's raw-wire measure.

    MUJOCO_GL=egl PYTHONPATH=. python bench/media.py [--seconds S] [--rounds N] [--only NAME...] [--codec h264|vp8]
    quick look at the control stream: --only control --seconds 5 --rounds 1
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import fractions
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path[:0] = [str(HERE), str(ROOT)]

import roundtrip  # noqa: E402
from suite import Row  # noqa: E402
from testbed.media_client import LinkShaper, MediaPeer, Rosbridge  # noqa: E402
from testbed.processes import serve, stop  # noqa: E402
from vr_teleop_server.core.scheduling import SHORT_SLICE_S, short_slice, slice_of  # noqa: E402

CAMERA = "/camera/color/image_raw/compressed"
VIDEO_TIME_BASE = fractions.Fraction(1, 90000)


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


# ---- glass to glass in Chromium --------------------------------------------------------------------------------
# Where a WebRTC frame's time goes, from the page's getStats (inbound-rtp video, means per frame): the jitter
# buffer (first packet received to the frame leaving it for the decoder), the assembly (first to last packet of a
# frame), the decode, and reception to decoded in all; and the server's render to send (telemetry's
# camera_frame_age, the mean over each 0.5 s; for the JPEG topic, render to the frame written to the WebSocket).
STATS = """async () => {
  const stats = await window.dashboard.camera.pc.getStats();
  let out = null;
  stats.forEach((s) => {
    if (s.type !== "inbound-rtp" || s.kind !== "video") return;
    const per = (total, n) => (n ? 1000 * total / n : NaN);
    out = {codec: stats.get(s.codecId)?.mimeType ?? "", decoder: s.decoderImplementation ?? "",
           jitter_buffer: per(s.jitterBufferDelay, s.jitterBufferEmittedCount),
           assembly: per(s.totalAssemblyTime, s.framesAssembledFromMultiplePackets),
           decode: per(s.totalDecodeTime, s.framesDecoded),
           processing: per(s.totalProcessingDelay, s.framesDecoded),
           decoded: s.framesDecoded, dropped: s.framesDropped ?? 0};
  });
  return out;
}"""
TELEMETRY = """() => {
  window.benchAges = {webrtc: [], json: [], targets: []};
  window.dashboard.ros.subscribe("/vr_teleop/telemetry", "vr_teleop_msgs/Telemetry", (msg) => {
    for (const c of msg.clients || []) {
      if (c.camera_frame_age >= 0) window.benchAges[c.webrtc ? "webrtc" : "json"].push(c.camera_frame_age);
      if (c.webrtc && c.rtc_target_bitrate > 0) window.benchAges.targets.push(c.rtc_target_bitrate);
    }
  });
}"""


def glass_rows(size: str, seconds: float, codec: str = "h264") -> list[Row]:
    """Both paths side by side in one Chromium, the WebRTC page asking for `codec` (#codec=..., as a Quest's page
    asks for H.264: webrtc.js chooseVideoCodec), with where a WebRTC frame's time goes beside."""
    from playwright.sync_api import sync_playwright

    server = serve("--backend", "sim", "--camera-size", size, "--bystander-interval", "0")
    port = server.url.rsplit(":", 1)[1]
    results = {}
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=shutil.which("chromium"), args=["--no-sandbox"])
            pages = {}
            for mode in ("webrtc", "jpeg"):  # side by side: both watch at once, under the same load
                pages[mode] = page = browser.new_page()
                page.goto(f"http://127.0.0.1:{port}/#camera={mode}&codec={codec}")
            for page in pages.values():
                page.wait_for_function("window.dashboard.camera.ages.length >= 10", timeout=60_000)
            pages["webrtc"].evaluate(TELEMETRY)
            before = pages["webrtc"].evaluate(STATS)
            for page in pages.values():
                page.evaluate("['ages', 'decodedAges', 'paintedAges'].forEach((k) => window.dashboard.camera[k].length = 0)")
            time.sleep(seconds)
            after = pages["webrtc"].evaluate(STATS)
            server_ages = pages["webrtc"].evaluate("window.benchAges")
            for mode, page in pages.items():
                ages = page.evaluate("[window.dashboard.camera.ages, window.dashboard.camera.decodedAges, "
                                     "window.dashboard.camera.paintedAges]")
                results[mode] = ([[1000 * a for a in kind] for kind in ages],
                                 page.evaluate("window.dashboard.camera.path"),
                                 page.evaluate("window.dashboard.camera.codec"))
                page.close()
            browser.close()
    finally:
        stop(server)
    ((rtc, rtc_decoded, rtc_painted), rtc_path, got), ((jpg, jpg_decoded, jpg_painted), _, _) = \
        results["webrtc"], results["jpeg"]
    assert rtc_path == "WebRTC", f"the dashboard fell back to {rtc_path}"
    want = {"h264": "H264", "vp8": "VP8"}[codec]
    assert got == want and after["codec"].lower() == f"video/{want.lower()}", (got, after)
    name = {"H264": "H.264", "VP8": "VP8"}[want]
    rows = [Row(f"glass to glass {size}, WebRTC {name}: p50", pct(rtc, 50), pct(jpg, 50), "JPEG topic p50", "ms"),
            Row(f"glass to glass {size}, WebRTC {name}: p95", pct(rtc, 95), pct(jpg, 95), "JPEG topic p95", "ms"),
            Row(f"frames shown in {seconds:g} s {size}, WebRTC {name}", len(rtc), len(jpg), "JPEG topic", "frames",
                "higher"),
            # like for like: both paths at the same point (see STATS and the dashboard's decodedAges)
            Row(f"  render to decoded {size}, WebRTC {name}: p50", pct(rtc_decoded, 50), pct(jpg_decoded, 50),
                "JPEG topic p50", "ms"),
            Row(f"  render to decoded {size}, WebRTC {name}: p95", pct(rtc_decoded, 95), pct(jpg_decoded, 95),
                "JPEG topic p95", "ms"),
            Row(f"  render to compositor {size}, WebRTC {name}: p50", pct(rtc_painted, 50), pct(jpg_painted, 50),
                "JPEG topic p50", "ms"),
            Row(f"  render to compositor {size}, WebRTC {name}: p95", pct(rtc_painted, 95), pct(jpg_painted, 95),
                "JPEG topic p95", "ms")]
    d = {k: after[k] for k in ("decoded", "dropped")}
    d = {k: d[k] - before[k] for k in d}
    print(f"  {size} {name}: decoder {after['decoder'] or '?'}; page per frame (whole run): jitter buffer "
          f"{after['jitter_buffer']:.1f} ms, assembly {after['assembly']:.1f} ms, decode {after['decode']:.1f} ms, "
          f"reception to decoded {after['processing']:.1f} ms; {d['decoded']} decoded, {d['dropped']} dropped in "
          f"{seconds:g} s", file=sys.stderr)
    targets = server_ages.pop("targets")
    if targets:  # the encoder is rebuilt (a keyframe) when its target moves by more than 15%
        print(f"  encoder target {min(targets) / 1e6:.2f} to {max(targets) / 1e6:.2f} Mbit/s during the run",
              file=sys.stderr)
    sent = {k: [1000 * a for a in v] for k, v in server_ages.items()}
    mean = {k: float(np.mean(v)) if v else float("nan") for k, v in sent.items()}
    rows.append(Row(f"server render to send {size}, WebRTC {name} (mean)", mean["webrtc"], mean["json"],
                    "JPEG topic", "ms"))
    return rows


# ---- bandwidth and server CPU per delivered frame -----------------------------------------------------------------
async def sweep_head(url: str, stop_at: float) -> None:
    """The operator looks around: the picture changes, as it does while teleoperating."""
    ros = await Rosbridge.open(url)
    yaw = 40.0
    while time.monotonic() < stop_at:
        yaw = -yaw
        await ros.publish("/qt_robot/head_position/command", "std_msgs/Float64MultiArray", {"data": [yaw, 0.0]})
        await asyncio.sleep(1.5)
    await ros.publish("/qt_robot/head_position/command", "std_msgs/Float64MultiArray", {"data": [0.0, 0.0]})
    await ros.close()


async def json_path(url: str, seconds: float) -> tuple[int, int]:
    from websockets.asyncio.client import connect

    ws = await connect(url, compression=None, max_size=None)
    await ws.send(json.dumps({"op": "subscribe", "topic": CAMERA, "type": "sensor_msgs/CompressedImage",
                              "queue_length": 1}))
    warm_until = time.monotonic() + 3
    while time.monotonic() < warm_until:
        await ws.recv()
    frames = size = 0
    stop_at = time.monotonic() + seconds
    sweeper = asyncio.ensure_future(sweep_head(url, stop_at))
    while time.monotonic() < stop_at:
        frame = await ws.recv()
        frames += 1
        size += len(frame)
    await sweeper
    await ws.close()
    return frames, size


async def webrtc_path(url: str, seconds: float) -> tuple[int, int]:
    ros = await Rosbridge.open(url)
    peer = MediaPeer(audio=False)
    peer.keep_frames = 1
    await peer.negotiate(ros)
    await peer.wait_video(10, 60)
    await asyncio.sleep(3)
    count, size = peer.video_count, peer.video_bytes
    stop_at = time.monotonic() + seconds
    await sweep_head(url, stop_at)
    frames, size = peer.video_count - count, peer.video_bytes - size
    await peer.close()
    await ros.close()
    return frames, size


def server_cpu(proc: psutil.Process, render: bool = False) -> float:
    """CPU seconds of the server process and of its video encoder process (media/encoder_process.py), and with
    `render` of the stand-in's render process too (which draws for both paths and makes the JPEG for one)."""
    total = sum(proc.cpu_times()[:2])
    for child in proc.children():
        with contextlib.suppress(psutil.Error):
            line = " ".join(child.cmdline())
            if "encoder_process" in line or (render and "render_process" in line):
                total += sum(child.cpu_times()[:2])
    return total


def bandwidth_rows(seconds: float) -> list[Row]:
    server = serve("--backend", "sim", "--bystander-interval", "0")
    proc = psutil.Process(server.pid)
    out = {}
    try:
        for name, fn in (("webrtc", webrtc_path), ("json", json_path)):
            cpu0, all0 = server_cpu(proc), server_cpu(proc, render=True)
            frames, size = asyncio.run(fn(server.url, seconds))
            out[name] = (frames, size, server_cpu(proc) - cpu0, server_cpu(proc, render=True) - all0)
    finally:
        stop(server)
    (rf, rs, rc, ra), (jf, js, jc, ja) = out["webrtc"], out["json"]
    return [Row("bandwidth 640x480 30 fps, head sweeping, WebRTC (VP8)", 8 * rs / seconds / 1e6, 8 * js / seconds / 1e6,
                "JPEG topic", "Mbit/s"),
            Row("server CPU per delivered frame, WebRTC", 1000 * rc / max(1, rf), 1000 * jc / max(1, jf),
                "JPEG topic", "ms"),
            Row("server CPU per delivered frame with the render process, WebRTC", 1000 * ra / max(1, rf),
                1000 * ja / max(1, jf), "JPEG topic", "ms"),
            Row("frames delivered a second, WebRTC", rf / seconds, jf / seconds, "JPEG topic", "fps", "higher")]


# ---- the encoders' settings, one at a time ------------------------------------------------------------------------
def encoder_rows(rounds: int) -> list[Row]:
    """In this process, one thread, as in the encoder process: CPU per 1280x720 frame of the stand-in's camera while
    the head sweeps, for each setting against the one chosen (media/encoder_process.py's encoder_options), and the
    frames an encoder holds back before its first output (lookahead: each one is a frame period of delay). Also the
    frame's way into the encoder: RGB from the frame ring against the JPEG it took before issue 29 (made in the
    render process, decoded in the encoder process)."""
    import av
    import cv2

    from sim import StandIn
    from vr_teleop_server.media.encoder_process import encoder_options, open_encoder

    standin = StandIn(camera_width=1280, camera_height=720)
    try:
        frames = []
        for k in range(30):
            standin.set_targets({"HeadYaw": -30 + 2 * k, "HeadPitch": -5 + k % 7})
            time.sleep(0.1)  # the head moves on: each frame differs from the last
            frames.append(standin.snapshot(width=1280, height=720))
    finally:
        standin.close()
    yuv = [cv2.cvtColor(f, cv2.COLOR_RGB2YUV_I420) for f in frames]
    rate = 2_000_000

    def run(codec: str, options: dict[str, str], threads: int = 1) -> tuple[float, int]:
        ctx = open_encoder(av, codec, 1280, 720, rate, 30.0, options, threads)
        cpu, held, out = 0.0, None, 0
        for i in range(rounds * len(yuv)):
            image = av.VideoFrame.from_ndarray(yuv[i % len(yuv)], format="yuv420p")
            image.pts = i
            t0 = time.thread_time()
            out += len(ctx.encode(image))
            cpu += time.thread_time() - t0
            if held is None and out:
                held = i
        return 1000 * cpu / (rounds * len(yuv)), held if held is not None else rounds * len(yuv)

    vp8, h264 = encoder_options("VP8", rate), encoder_options("H264", rate)
    base_vp8, held_vp8 = run("VP8", vp8)
    base_h264, held_h264 = run("H264", h264)
    rows = [Row("encoder 1280x720 VP8 (chosen): CPU per frame", base_vp8, 1000 / 30, "a frame period", "ms"),
            Row("encoder 1280x720 H.264 (chosen): CPU per frame", base_h264, 1000 / 30, "a frame period", "ms")]
    for name, codec, options, threads, base in (
            ("VP8 cpu-used 16", "VP8", {**vp8, "cpu-used": "16"}, 1, base_vp8),
            ("VP8 cpu-used 4", "VP8", {**vp8, "cpu-used": "4"}, 1, base_vp8),
            ("VP8 2 threads", "VP8", vp8, 2, base_vp8),
            ("H.264 preset veryfast", "H264", {**h264, "preset": "veryfast"}, 1, base_h264)):
        rows.append(Row(f"encoder 1280x720 {name}: CPU per frame", run(codec, options, threads)[0], base,
                        "the chosen settings", "ms"))
    without = {k: v for k, v in h264.items() if k != "tune"}
    rows += [Row("encoder 1280x720 VP8 (chosen): frames held before the first out", float(held_vp8), None, "-",
                 "frames"),
             Row("encoder 1280x720 H.264 (chosen): frames held before the first out", float(held_h264), None, "-",
                 "frames"),
             Row("encoder 1280x720 H.264 without zerolatency: frames held", float(run("H264", without)[1]),
                 float(held_h264), "zerolatency", "frames"),
             Row("encoder 1280x720 VP8 lag-in-frames 16: frames held", float(run("VP8", {**vp8,
                 "lag-in-frames": "16"})[1]), float(held_vp8), "lag-in-frames 0", "frames")]
    # The frame's way in: the ring's RGB to I420 against JPEG made (render process) and decoded (encoder process).
    t0 = time.thread_time()
    for f in frames:
        cv2.cvtColor(f, cv2.COLOR_RGB2YUV_I420)
    ring_ms = 1000 * (time.thread_time() - t0) / len(frames)
    t0 = time.thread_time()
    for f in frames:
        ok, data = cv2.imencode(".jpg", cv2.cvtColor(f, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 80])
        cv2.cvtColor(cv2.imdecode(data, cv2.IMREAD_COLOR), cv2.COLOR_BGR2YUV_I420)
    jpeg_ms = 1000 * (time.thread_time() - t0) / len(frames)
    return rows + [Row("1280x720 frame into the encoder: ring RGB to I420", ring_ms, jpeg_ms,
                       "JPEG made, decoded, to I420 (before)", "ms")]


# ---- the floor: each path's unavoidable work per frame ---------------------------------------------------------
def floor_rows(rounds: int, bitrate: int = 4_000_000) -> list[Row]:
    """What a perfect pipeline would still spend on a frame, in this process, one thread, on the stand-in's camera
    frames while the head moves: WebRTC's RGB to I420, encode (media/encoder_process.py's settings), RTP
    packetisation (aiortc's) and decode (FFmpeg, as Chromium's software decoders; a Quest decodes H.264 in
    hardware); the JPEG topic's encode (the render process's quality), base64 (rosbridge's JSON) and decode.
    Everything else on glass to glass (the hops between processes and threads, waiting for a core, the jitter
    buffer, the browser's compositing) is what an implementation adds above this floor. `bitrate`: the encoders'
    target (the peers' estimate reaches the 4 Mbit/s cap on loopback within seconds)."""
    import base64

    import av
    import cv2
    from aiortc.codecs.h264 import H264Encoder
    from aiortc.codecs.vpx import Vp8Encoder

    from sim import StandIn
    from vr_teleop_server.media.encoder_process import encoder_options, open_encoder

    sizes = {"640x480": (640, 480), "1280x720": (1280, 720)}
    standin = StandIn(camera_width=1280, camera_height=720)
    try:
        frames = {size: [] for size in sizes}
        for k in range(30):
            standin.set_targets({"HeadYaw": -30 + 2 * k, "HeadPitch": -5 + k % 7})
            time.sleep(0.1)
            for size, (w, h) in sizes.items():
                frames[size].append(standin.snapshot(width=w, height=h))
    finally:
        standin.close()

    def per_frame(fn, items) -> float:
        t0 = time.thread_time()
        for _ in range(rounds):
            for item in items:
                fn(item)
        return 1000 * (time.thread_time() - t0) / (rounds * len(items))

    rows = []
    for size, (w, h) in sizes.items():
        rgb = frames[size]
        i420 = per_frame(lambda f: cv2.cvtColor(f, cv2.COLOR_RGB2YUV_I420), rgb)
        yuv = [cv2.cvtColor(f, cv2.COLOR_RGB2YUV_I420) for f in rgb]
        jpegs = [cv2.imencode(".jpg", cv2.cvtColor(f, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 80])[1]
                 for f in rgb]
        jpeg = (per_frame(lambda f: cv2.imencode(".jpg", cv2.cvtColor(f, cv2.COLOR_RGB2BGR),
                                                 [cv2.IMWRITE_JPEG_QUALITY, 80]), rgb)
                + per_frame(lambda j: base64.b64decode(base64.b64encode(j.tobytes())), jpegs)
                + per_frame(lambda j: cv2.imdecode(j, cv2.IMREAD_COLOR), jpegs))
        for codec, packer, decoder_name in (("H264", H264Encoder, "h264"), ("VP8", Vp8Encoder, "vp8")):
            ctx = open_encoder(av, codec, w, h, bitrate, 30.0, encoder_options(codec, bitrate))
            packets, encode_ms = [], 0.0
            for _ in range(rounds):
                for i, y in enumerate(yuv):
                    image = av.VideoFrame.from_ndarray(y, format="yuv420p")
                    image.pts = len(packets)
                    t0 = time.thread_time()
                    out = ctx.encode(image)
                    encode_ms += 1000 * (time.thread_time() - t0)
                    packets.append(b"".join(bytes(p) for p in out))
            encode_ms /= len(packets)
            pack = packer()

            def packetize(data: bytes, pack=pack) -> None:
                packet = av.Packet(data)
                packet.pts, packet.time_base = 0, VIDEO_TIME_BASE
                pack.pack(packet)

            pack_ms = per_frame(packetize, packets)
            decoder = av.CodecContext.create(decoder_name, "r")
            decoder.thread_count = 1
            decode_ms = per_frame(lambda d: decoder.decode(av.Packet(d)), packets)
            kbytes = float(np.mean([len(p) for p in packets])) / 1000
            name = {"H264": "H.264", "VP8": "VP8"}[codec]
            rows.append(Row(f"floor {size} {name}: I420 {i420:.1f} + enc {encode_ms:.1f} + RTP {pack_ms:.2f} + dec "
                            f"{decode_ms:.1f}", i420 + encode_ms + pack_ms + decode_ms, jpeg,
                            "JPEG enc + base64 + dec", "ms"))
            print(f"  floor {size} {name}: {kbytes:.1f} kB a frame at {bitrate / 1e6:g} Mbit/s", file=sys.stderr)
    return rows


# ---- viewers in another process ---------------------------------------------------------------------------------
async def viewers(url: str, n: int, seconds: float) -> list[float]:
    """n aiortc peers; each one's frames a second over `seconds` after the first frames. They count frames without
    decoding them (on one 2-core machine, five decoders would starve the server being measured), except the first,
    which decodes them and checks that the picture is a picture (not one flat colour)."""
    pairs = []
    for i in range(n):
        ros = await Rosbridge.open(url)
        peer = MediaPeer(audio=False)
        peer.keep_frames = 1
        peer.light = i > 0
        await peer.negotiate(ros)
        pairs.append((ros, peer))
    for _, peer in pairs:
        await peer.wait_video(5, 60)
    counts = [peer.video_count for _, peer in pairs]
    await asyncio.sleep(seconds)
    rates = [(peer.video_count - c) / seconds for (_, peer), c in zip(pairs, counts)]
    picture = pairs[0][1].frames[-1][1].to_ndarray(format="gray")
    if picture.std() < 5:
        raise RuntimeError(f"the decoding viewer's picture is flat (std {picture.std():.1f}): the video is broken")
    for ros, peer in pairs:
        await peer.close()
        await ros.close()
    return rates


def spawn_viewers(url: str, n: int, seconds: float, json_topic: bool = False,
                  server: subprocess.Popen | None = None) -> subprocess.Popen:
    """The viewers in a process of their own (they stand for other machines), pinned apart from `server` when the
    machine has cores to spare for that (4 or more: the last quarter for the viewers)."""
    viewers = subprocess.Popen([sys.executable, __file__, "--viewers", str(n), "--url", url, "--seconds",
                                str(seconds), *(["--json-topic"] if json_topic else [])],
                               stdout=subprocess.PIPE, text=True, cwd=ROOT)
    cores = os.cpu_count() or 1
    if server is not None and cores >= 4:
        theirs = list(range(cores - cores // 4, cores))
        with contextlib.suppress(psutil.Error):
            psutil.Process(viewers.pid).cpu_affinity(theirs)
            for proc in [psutil.Process(server.pid), *psutil.Process(server.pid).children(recursive=True)]:
                proc.cpu_affinity([c for c in range(cores) if c not in theirs])
    return viewers


def viewer_rows(seconds: float) -> list[Row]:
    server = serve("--backend", "sim", "--bystander-interval", "0")
    try:
        one = json.loads(spawn_viewers(server.url, 1, seconds, server=server).communicate()[0].splitlines()[-1])
        five = json.loads(spawn_viewers(server.url, 5, seconds, server=server).communicate()[0].splitlines()[-1])
    finally:
        stop(server)
    return [Row("WebRTC fps, 1 viewer", float(np.mean(one)), 30.0, "30 fps asked", "fps", "higher"),
            Row("WebRTC fps, 5 viewers (each, mean)", float(np.mean(five)), float(np.mean(one)), "1 viewer", "fps",
                "higher"),
            Row("WebRTC fps, 5 viewers (slowest)", float(np.min(five)), float(np.mean(one)), "1 viewer", "fps",
                "higher")]


# ---- a 1 Mbit/s bottleneck ----------------------------------------------------------------------------------------
def congested_rows(seconds: float) -> list[Row]:
    """In-process server (the shaper wraps its peer's transport), head sweeping so that the picture keeps changing."""
    from testbed.server import RunningServer
    from vr_teleop_server.settings import ServerSettings

    server = RunningServer(ServerSettings(port=0, backend="sim", bystander_interval=0))

    async def run() -> tuple[float, float, float, int]:
        ros = await Rosbridge.open(server.url)
        peer = MediaPeer(audio=False)
        peer.keep_frames = 1
        await peer.negotiate(ros)
        await peer.wait_video(5, 60)
        media = server.server.media
        name = server.call(lambda: next(iter(media.peers)))

        async def install() -> LinkShaper:
            return LinkShaper(media.peers[name].pc, 1_000_000)

        shaper = asyncio.run_coroutine_threadsafe(install(), server.loop).result()
        tel = await ros.subscribe("/vr_teleop/telemetry", "vr_teleop_msgs/Telemetry")
        settle_until = time.monotonic() + 5
        start_count, start = None, None
        targets, rates = [], []
        yaw, i = 50.0, 0
        while True:
            if i % 4 == 0:
                yaw = -yaw
                await ros.publish("/qt_robot/head_position/command", "std_msgs/Float64MultiArray",
                                  {"data": [yaw, 0.0]})
            i += 1
            entry = next(c for c in (await tel.get())["clients"] if c["webrtc"])
            now = time.monotonic()
            if now < settle_until:
                continue
            if start is None:
                start_count, start = peer.video_count, now
                continue
            targets.append(entry["rtc_target_bitrate"])
            rates.append(entry["rtc_bitrate"])
            if now - start >= seconds:
                break
        fps = (peer.video_count - start_count) / (time.monotonic() - start)
        dropped = shaper.dropped
        server.loop.call_soon_threadsafe(shaper.close)
        await ros.publish("/qt_robot/head_position/command", "std_msgs/Float64MultiArray", {"data": [0.0, 0.0]})
        await peer.close()
        await ros.close()
        return fps, float(np.median(targets)), float(np.median(rates)), dropped

    try:
        fps, target, rate, dropped = asyncio.run(run())
    finally:
        server.stop()
    return [Row("1 Mbit/s bottleneck, head sweeping: fps received", fps, 20.0, "20 fps wanted", "fps", "higher"),
            Row("1 Mbit/s bottleneck: encoder target (median)", target / 1e6, 1.0, "the link", "Mbit/s"),
            Row("1 Mbit/s bottleneck: sent (median of 0.5 s windows)", rate / 1e6, 1.0, "the link", "Mbit/s"),
            Row("1 Mbit/s bottleneck: packets dropped at the queue", float(dropped), None, "-", "packets")]


# ---- speech to first audio sample ---------------------------------------------------------------------------------
def speech_rows(trials: int) -> list[Row]:
    server = serve("--backend", "sim", "--bystander-interval", "0")

    async def run() -> list[float]:
        ros = await Rosbridge.open(server.url)
        peer = MediaPeer(video=False)
        await peer.negotiate(ros)
        while len(peer.audio_frames) < 50:
            await asyncio.sleep(0.05)
        delays = []
        for k in range(trials):
            peer.audio_frames.clear()
            t0 = time.monotonic()
            await ros.publish("/qt_robot/speech/say", "std_msgs/String", {"data": f"Hello number {k}, welcome."})
            heard = None
            while heard is None and time.monotonic() - t0 < 10:
                for t, samples in list(peer.audio_frames):
                    if np.sqrt(np.mean(samples.astype(np.float32) ** 2)) > 300:
                        heard = t
                        break
                await asyncio.sleep(0.005)
            if heard is not None:
                delays.append(1000 * (heard - t0))
            await asyncio.sleep(3.5)  # let the sentence finish
        await peer.close()
        await ros.close()
        return delays

    try:
        delays = asyncio.run(run())
    finally:
        stop(server)
    return [Row(f"speech text in to first audio at the peer, p50 of {len(delays)}", pct(delays, 50), None, "-", "ms")]


# ---- the control stream beside media -------------------------------------------------------------------------------
async def json_viewer(url: str, seconds: float) -> list[float]:
    """One JSON-topic camera subscriber: the stand-in renders as it does for WebRTC viewers."""
    from websockets.asyncio.client import connect

    ws = await connect(url, compression=None, max_size=None)
    await ws.send(json.dumps({"op": "subscribe", "topic": CAMERA, "type": "sensor_msgs/CompressedImage",
                              "queue_length": 1}))
    frames = 0
    stop_at = time.monotonic() + seconds
    while time.monotonic() < stop_at:
        await ws.recv()
        frames += 1
    await ws.close()
    return [frames / seconds]


def loop_cpu(pid: int) -> float | None:
    """CPU seconds used so far by a process's main thread (the server's event loop), None where /proc has none."""
    try:
        with open(f"/proc/{pid}/task/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime


def with_loop_cpu(pid: int, shares: list[float], run):
    """run()'s result; appends the share of a core the server's loop thread used meanwhile to `shares`."""
    c0, t0 = loop_cpu(pid), time.monotonic()
    result = run()
    c1 = loop_cpu(pid)
    if c0 is not None and c1 is not None:
        shares.append((c1 - c0) / (time.monotonic() - t0))
    return result


def control_rows(seconds: float, rounds: int = 2) -> list[Row]:
    """Alternating rounds, latencies pooled per condition (the machine's load drifts): no viewers; one JSON camera
    subscriber (the stand-in renders, which on 2 cores with software GL costs the control stream as much as any
    media work); five WebRTC viewers; the same five with the server's loop at the kernel's default slice instead of
    the short one it asks for (core/scheduling.py), flipped from here for that stretch. This client, which stands
    for the operator's machine, asks for a short slice too: the figure is the server's delay, not this client
    waiting behind the viewers' process, which stands for other machines and shares these 2 cores only here."""
    short_slice()
    server = serve("--backend", "sim", "--bystander-interval", "0")
    loop_short = slice_of(server.pid) == int(SHORT_SLICE_S * 1e9)
    none: list[float] = []
    camera: list[float] = []
    five: list[float] = []
    five_default: list[float] = []
    rates: list[float] = []
    none_cpu: list[float] = []  # the server's loop thread, share of a core while the poses are measured
    five_cpu: list[float] = []
    try:
        for _ in range(rounds):
            none += with_loop_cpu(server.pid, none_cpu, lambda: asyncio.run(
                roundtrip.latency(server.url, True, seconds, 90.0, samples=True)))
            watcher = spawn_viewers(server.url, 1, seconds + 8, json_topic=True, server=server)
            time.sleep(5)
            camera += asyncio.run(roundtrip.latency(server.url, True, seconds, 90.0, samples=True))
            watcher.communicate()
            watchers = spawn_viewers(server.url, 5, 2 * seconds + 20, server=server)
            time.sleep(15)  # the five negotiate and reach steady video
            five += with_loop_cpu(server.pid, five_cpu, lambda: asyncio.run(
                roundtrip.latency(server.url, True, seconds, 90.0, samples=True)))
            if loop_short:
                short_slice(0, tid=server.pid)
                five_default += asyncio.run(roundtrip.latency(server.url, True, seconds, 90.0, samples=True))
                short_slice(tid=server.pid)
            rates += json.loads(watchers.communicate()[0].splitlines()[-1])
    finally:
        stop(server)
    rows = [Row("pose round trip p50, 5 WebRTC viewers", pct(five, 50), pct(none, 50), "no viewers", "ms"),
            Row("pose round trip p99, 5 WebRTC viewers", pct(five, 99), pct(none, 99), "no viewers (<= 1.2x)",
                "ms"),
            Row("pose round trip p99, 1 JSON camera subscriber", pct(camera, 99), pct(none, 99), "no viewers",
                "ms"),
            Row("pose round trip p99, 5 WebRTC viewers", pct(five, 99), pct(camera, 99),
                "1 JSON camera subscriber", "ms")]
    if five_default:
        rows.append(Row("pose round trip p99, 5 WebRTC viewers, loop at the default slice", pct(five_default, 99),
                        pct(none, 99), "no viewers (short slice)", "ms"))
    else:
        print("bench/media.py: the server's loop has no short slice here (Linux >= 6.12 needed): the rows above "
              "are at the default slice", file=sys.stderr)
    if none_cpu and five_cpu:  # since the media loop (issue 29) the peers' packets are another thread's work
        rows.append(Row("server loop thread CPU, 5 WebRTC viewers", 100 * float(np.mean(five_cpu)),
                        100 * float(np.mean(none_cpu)), "no viewers", "% core"))
    return rows + [Row("(the viewers' fps meanwhile, mean)", float(np.mean(rates)), None, "-", "fps", "higher")]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rounds", type=int, default=2, help="alternating rounds of the control rows")
    parser.add_argument("--only", nargs="+", choices=["glass", "bandwidth", "viewers", "congested", "speech",
                                                       "control", "encoder", "floor"])
    parser.add_argument("--codec", choices=["h264", "vp8"], default="h264",
                        help="the codec the glass rows' WebRTC page asks for (default: H.264, what the page asks "
                             "for on a Quest, whose browser decodes H.264 in hardware)")
    parser.add_argument("--viewers", type=int, help=argparse.SUPPRESS)  # the viewer subprocess
    parser.add_argument("--url", help=argparse.SUPPRESS)
    parser.add_argument("--json-topic", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.viewers:
        run = json_viewer(args.url, args.seconds) if args.json_topic else viewers(args.url, args.viewers, args.seconds)
        print(json.dumps(asyncio.run(run)))
        return 0
    s = args.seconds
    parts = {"glass": lambda: glass_rows("640x480", s, args.codec) + glass_rows("1280x720", s, args.codec),
             "bandwidth": lambda: bandwidth_rows(s), "viewers": lambda: viewer_rows(s),
             "congested": lambda: congested_rows(s), "speech": lambda: speech_rows(5),
             "control": lambda: control_rows(s, args.rounds), "encoder": lambda: encoder_rows(args.rounds),
             "floor": lambda: floor_rows(args.rounds)}
    print(f"machine: {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}")
    print(f"| {'figure':<56} | {'value':>10} | {'baseline':>10} | {'ratio':>7} | {'unit':<8} | baseline is")
    for name in args.only or parts:
        for row in parts[name]():
            print(row.line(), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
