"""The shared video encoders in a process of their own, at a lower CPU priority than the server.

Why a process: in the server's process the encoding thread shares the GIL with the asyncio loop that carries the
operator's poses. At a lower priority it is preempted (by the render process, by other work) while it holds the
GIL between two C calls, and the loop then waits on a starved thread; at the same priority it competes with the
loop for the CPU. In its own process, at nice `NICE`, it shares no GIL with the loop and the kernel gives the loop
the CPU first; a crash in libvpx or x264 ends the process, not the server. The server's side of a frame is a
frame number sent and a few kilobytes of VP8 or H.264 read back, in the hub's thread (blocked in a socket read,
GIL released, while the worker encodes): the worker reads the frame's pixels from the stand-in's frame ring
(worker_process/frame_ring.py, shared memory, mapped here), so a frame is compressed once. A camera whose frames
come as JPEG (a real robot's topic) sends the JPEG instead, which the worker decodes.

The worker answers requests over a socket pair (the `worker_process` package: started with subprocess, it exits
when its socket closes, so it cannot outlive the server), one at a time: the frame (its number in the ring, or a
JPEG), its presentation time and, per codec, whether to make a keyframe and the target bitrate; the answer is,
per codec, the encoded frame or why it failed (that codec's encoder is then rebuilt). It loads this file alone, not the `vr_teleop_server` package: it
needs only PyAV, OpenCV and NumPy, and starts in a fraction of a second.
"""

from __future__ import annotations

import fractions
import os
from pathlib import Path
from typing import Any

from worker_process import WorkerDied, WorkerProcess, accept, answer
from worker_process.face_blur import Regions, blur_regions
from worker_process.frame_ring import FrameRing

NICE = 10  # added to the worker's niceness: the server's loop wins a core over the encoder
VIDEO_CLOCK_RATE = 90000
REOPEN_RATIO = 0.15  # an encoder is rebuilt at a new target bitrate (a keyframe) only when it moves more than this
REOPEN_INTERVAL_S = 1.0  # and at most this often, in the video's own seconds (its frames' pts)
GOP_S = 10  # a keyframe at least this often (seconds) without being asked: a viewer that lost one recovers
ROOT = Path(__file__).resolve().parents[2]  # the directory that holds `worker_process`
BOOT = ("import importlib.util, sys; sys.path.insert(0, sys.argv[1]); "
        "spec = importlib.util.spec_from_file_location('vr_teleop_encoder', sys.argv[2]); "
        "module = importlib.util.module_from_spec(spec); spec.loader.exec_module(module); "
        "module.serve(int(sys.argv[3]))")

# One codec's answer: (bitstream, keyframe, bitrate) when it encoded, the error's text when it failed.
Encoded = tuple[bytes, bool, int] | str


class EncoderProcessError(WorkerDied):
    """The encoder process died, hung, could not start, or failed a frame as a whole."""


class EncoderProcess(WorkerProcess):
    """Parent side. Not thread-safe: the hub's encoding thread makes every call."""

    NAME = "the video encoder process"
    START_TIMEOUT_S = 30.0  # importing PyAV and OpenCV on a loaded machine
    REPLY_TIMEOUT_S = 10.0  # a frame takes milliseconds: a worker silent this long is hung
    Died = EncoderProcessError

    def __init__(self, fps: float, *, nice: int = NICE, ring: FrameRing | None = None) -> None:
        """`ring`: the frame ring that `encode`'s frame numbers refer to (this process maps its own copy)."""
        self.ring = ring
        fd = None if ring is None else ring.dup()
        if ring is not None and fd is None:
            raise EncoderProcessError(f"{self.NAME}: the camera's frame ring is closed")
        try:
            spec = None if fd is None else (fd, ring.width, ring.height, ring.slots)
            super().__init__(BOOT, [str(ROOT), __file__], nice, (float(fps), spec),
                             pass_fds=() if fd is None else (fd,))
        finally:
            if fd is not None:
                os.close(fd)

    def encode(self, frame: bytes | int, pts: int, jobs: dict[str, tuple[bool, int]],
               blur: Regions | None = None) -> dict[str, Encoded]:
        """Encode a frame (its seq in the ring, or a JPEG, decoded once) with each codec in `jobs` ({codec:
        (keyframe, bitrate)}), its `blur` regions blurred first (serve --blur-faces): per codec the encoded frame
        (none when the encoder held it back) or the error's text; nothing at all when the ring's slot already holds
        a newer frame (this one is lost)."""
        return self.call((frame, pts, jobs, blur))

    def failed(self, why: str) -> Exception:
        """A frame the worker could not handle at all: the hub starts another worker (as when one dies)."""
        return EncoderProcessError(f"{self.NAME} (pid {self.pid}) failed: {why}")


# ---- the worker ----------------------------------------------------------------------------------------------
def serve(fd: int) -> None:
    """Worker entry point: answer requests until the socket closes."""
    conn, (fps, ring) = accept(fd)
    try:
        worker = _Worker(fps, ring)
    except Exception as exc:
        conn.send((False, f"the encoders did not load ({type(exc).__name__}: {exc})"))
        return
    answer(conn, lambda request: worker.encode(*request))


class _Worker:
    def __init__(self, fps: float, ring: tuple | None) -> None:
        import av
        import cv2
        import numpy as np

        self.av, self.cv2, self.np = av, cv2, np
        self.time_base = fractions.Fraction(1, VIDEO_CLOCK_RATE)
        self.fps = fps
        self.encoders: dict[str, _Encoder] = {}
        self.ring = None if ring is None else FrameRing.attach(ring)

    def i420(self, image: Any, code: int) -> Any:
        h, w = image.shape[:2]
        w2, h2 = w - w % 2, h - h % 2  # I420 needs even sizes
        return self.cv2.cvtColor(self.np.ascontiguousarray(image[:h2, :w2]), code)

    def encode(self, frame: bytes | int, pts: int, jobs: dict[str, tuple[bool, int]],
               blur: Regions | None = None) -> dict[str, Encoded]:
        """The frame to I420 once (from the ring's RGB, or a JPEG), blurred first where `blur` says, then each
        codec's encoder once."""
        cv2 = self.cv2
        if isinstance(frame, int):
            if self.ring is None:
                raise ValueError("a frame number was sent, but this encoder process has no frame ring")
            yuv = self.ring.read(frame, lambda rgb: self.i420(
                rgb if blur is None else blur_regions(rgb.copy(), blur), cv2.COLOR_RGB2YUV_I420))
            if yuv is None:  # overwritten by a newer frame, which the hub sends next
                return {}
        else:
            bgr = cv2.imdecode(self.np.frombuffer(frame, self.np.uint8), cv2.IMREAD_COLOR)
            if bgr is None:  # this frame is lost; the encoders and the next frames are not
                return {codec: f"a camera frame of {len(frame)} bytes is not a JPEG; not encoded" for codec in jobs}
            yuv = self.i420(bgr if blur is None else blur_regions(bgr, blur), cv2.COLOR_BGR2YUV_I420)
        out: dict[str, Encoded] = {}
        for codec, (keyframe, bitrate) in jobs.items():
            encoder = self.encoders.get(codec)
            if encoder is None:
                encoder = self.encoders[codec] = _Encoder(self.av, codec, self.fps)
            image = self.av.VideoFrame.from_ndarray(yuv, format="yuv420p")
            image.pts, image.time_base = pts, self.time_base
            try:
                data, key = encoder.encode(image, keyframe, bitrate)
            except Exception as exc:
                encoder.context = None  # rebuilt (a keyframe) on the next frame
                out[codec] = f"{codec} encoding failed ({type(exc).__name__}: {exc}); the encoder is rebuilt"
                continue
            if data:
                out[codec] = (data, key, encoder.bitrate)
        return out


class _Encoder:
    """One codec's encoder, rebuilt when the frame size changes or the target bitrate moves enough."""

    def __init__(self, av: Any, codec: str, fps: float) -> None:
        self.av = av
        self.codec = codec
        self.fps = fps
        self.context: Any = None
        self.bitrate = 0
        self.opened_at = -1e9

    def encode(self, image: Any, keyframe: bool, bitrate: int) -> tuple[bytes, bool]:
        now = float(image.pts * image.time_base)  # the frame's time: what the viewer sees is rebuilt that seldom
        if self.context is not None and (image.width != self.context.width or image.height != self.context.height
                                         or (abs(bitrate - self.bitrate) > REOPEN_RATIO * self.bitrate
                                             and now - self.opened_at >= REOPEN_INTERVAL_S)):
            self.context = None
        if self.context is None:
            self.bitrate = bitrate
            self.opened_at = now
            self.context = self._open(image.width, image.height, bitrate)
            keyframe = True
        picture = self.av.video.frame.PictureType
        image.pict_type = picture.I if keyframe else picture.NONE
        data = b"".join(bytes(p) for p in self.context.encode(image))
        return data, keyframe

    def _open(self, width: int, height: int, bitrate: int) -> Any:
        return open_encoder(self.av, self.codec, width, height, bitrate, self.fps)


def encoder_options(codec: str, bitrate: int) -> dict[str, str]:
    """Each codec's settings for interaction: real time, no lookahead (a frame out for each frame in), rate
    control that undershoots rather than builds a burst. bench/media.py's encoder rows measure them."""
    if codec == "VP8":
        # cpu-used 8: at 1280x720 16 (libvpx's fastest) saved a tenth of the CPU per frame here and 4 cost 38% more
        # (bench/media.py --only encoder); realtime means no lookahead whatever lag-in-frames says.
        return {"deadline": "realtime", "cpu-used": "8", "lag-in-frames": "0", "static-thresh": "1",
                "undershoot-pct": "100", "overshoot-pct": "15", "bufsize": str(bitrate),
                "minrate": str(bitrate // 4), "maxrate": str(bitrate), "partitions": "0",
                "noise-sensitivity": "0", "error-resilient": "1"}
    if codec == "H264":  # zerolatency: no B-frames, no lookahead, no frame threads
        return {"preset": "ultrafast", "tune": "zerolatency", "level": "31",
                "maxrate": str(bitrate), "bufsize": str(bitrate)}
    raise ValueError(f"no encoder for {codec}")


def open_encoder(av: Any, codec: str, width: int, height: int, bitrate: int, fps: float,
                 options: dict[str, str] | None = None, threads: int = 1) -> Any:
    """A PyAV encoder context for `codec` with `encoder_options` (or the `options` given: the bench's variants)."""
    rate = max(1, round(fps))
    opts = encoder_options(codec, bitrate) if options is None else options
    ctx = av.CodecContext.create({"VP8": "libvpx", "H264": "libx264"}[codec], "w")
    ctx.options = opts
    if codec == "VP8":
        ctx.qmin, ctx.qmax = 4, 56
    else:
        ctx.profile = "Baseline"
    ctx.width, ctx.height = width, height
    ctx.pix_fmt = "yuv420p"
    ctx.bit_rate = bitrate
    ctx.framerate = fractions.Fraction(rate, 1)
    ctx.time_base = fractions.Fraction(1, rate)
    ctx.gop_size = GOP_S * rate  # a keyframe at this interval at least; PLI and joining peers ask for more
    # One thread: libvpx with two threads cost ten times the CPU per frame on a loaded 2-core machine (34 ms
    # against 3.6 ms at 640x480, its threads spin on each other); x264 gains nothing from a second either.
    ctx.thread_count = threads
    return ctx
