"""Bystanders' faces in the head camera's frames, published on /perception/faces while anyone listens.

The detector is OpenCV's frontal-face Haar cascade, which ships inside the opencv-python wheels (cv2.data), so
nothing is downloaded. Faces across a classroom are small (30-60 px at 640x480), below what the cascade finds
reliably at its native 24 px window, so frames are searched at twice their size; boxes are reported in the
frame's own pixels. Detection runs only while /perception/faces has subscribers: the camera is rendered (or
relayed) only then.

Detection takes the frames the camera makes anyway, the newest when it is ready for one, in a worker thread of its
own at the lowest CPU priority (nice 19, below the stand-in's renderer at 10), and rests at least as long as its
last search took: on a busy 2-core machine it runs at whatever rate is left over and never costs a client a frame
(bench/autonomy.py --camera measures the camera's rate with it running).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from client_protocol import names

from ..core.bus import Bus

from ..core.tasks import cancel_and_wait
from ..robot.interface import Robot

log = logging.getLogger(__name__)

CASCADE = "haarcascade_frontalface_default.xml"
DETECT_NICE = 19  # the detection thread's niceness: the loop, the renderer and the encoders come first


def _lowest_priority() -> None:
    """In the detection thread: lower its own priority (Linux gives each thread its own niceness)."""
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), DETECT_NICE)
    except (OSError, AttributeError) as exc:  # not Linux, or not allowed: detection runs at the server's priority
        log.info("face detection runs at normal priority (%s)", exc)


@dataclass(frozen=True)
class FaceBox:
    x: int
    y: int
    width: int
    height: int
    confidence: float


class FaceDetector:
    name = f"opencv-haar:{CASCADE.removesuffix('.xml')}"

    def __init__(self, *, upscale: float = 2.0, min_size_px: int = 20, min_neighbors: int = 3,
                 min_confidence: float = 1.5) -> None:
        path = cv2.data.haarcascades + CASCADE
        self._cascade = cv2.CascadeClassifier(path)
        if self._cascade.empty():
            raise RuntimeError(f"OpenCV's face cascade could not be loaded from {path}")
        self._clahe = cv2.createCLAHE(clipLimit=2.0, tileGridSize=(8, 8))
        self.upscale = upscale
        self.min_size_px = min_size_px
        self.min_neighbors = min_neighbors
        self.min_confidence = min_confidence

    def detect(self, gray: np.ndarray) -> list[FaceBox]:
        """Faces in a grayscale image, in its pixels, with the cascade's final-stage score as confidence."""
        # The cascade was trained mostly on light-skinned faces and reads light/dark differences, which are faint
        # on dark skin: on the stand-in it missed the darker-skinned child at every pose it found a lighter-skinned
        # one. Local contrast equalisation (CLAHE) recovers them; the extra false positives it brings score low
        # (below 1 where real faces score 2.5-8), hence the confidence floor.
        gray = self._clahe.apply(gray)
        k = self.upscale
        big = cv2.resize(gray, None, fx=k, fy=k, interpolation=cv2.INTER_LINEAR) if k != 1 else gray
        side = int(self.min_size_px * k)
        boxes, _levels, scores = self._cascade.detectMultiScale3(
            big, scaleFactor=1.05, minNeighbors=self.min_neighbors, minSize=(side, side), outputRejectLevels=True)
        found = sorted((FaceBox(int(round(x / k)), int(round(y / k)), int(round(w / k)), int(round(h / k)),
                                float(score))
                        for (x, y, w, h), score in zip(boxes, np.ravel(scores)) if score >= self.min_confidence),
                       key=lambda f: -f.confidence)
        kept: list[FaceBox] = []
        for f in found:  # one box per face: the cascade can also answer at a second scale around the same face
            cx, cy = f.x + f.width / 2, f.y + f.height / 2
            if not any(g.x <= cx <= g.x + g.width and g.y <= cy <= g.y + g.height for g in kept):
                kept.append(f)
        return kept

    def detect_jpeg(self, jpeg: bytes) -> tuple[list[FaceBox], tuple[int, int]] | None:
        gray = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
        if gray is None:
            return None
        return self.detect(gray), (gray.shape[1], gray.shape[0])


class FacePublisher:
    """Searches the newest camera frame at up to `rate_hz` while /perception/faces is watched."""

    def __init__(self, bus: Bus, robot: Robot, *, rate_hz: float = 5.0, detector: FaceDetector | None = None) -> None:
        self.bus = bus
        self.robot = robot
        self.detector = detector or FaceDetector()
        self._period = 1.0 / rate_hz
        self._task: asyncio.Task[None] | None = None
        self._executor = ThreadPoolExecutor(1, thread_name_prefix="faces", initializer=_lowest_priority)
        self.searched = 0  # frames searched (tests, the bench)

    def start(self) -> None:
        topic = self.bus.declare_topic(names.FACES_TOPIC, "vr_teleop_msgs/Faces", persistent=True)
        topic.on_subscriber_count = self._on_watchers

    async def stop(self) -> None:
        task, self._task = self._task, None
        await cancel_and_wait(task)
        self._executor.shutdown(wait=False, cancel_futures=True)

    def _on_watchers(self, count: int) -> None:
        if count and self._task is None:
            self._task = asyncio.ensure_future(self._loop())
        elif not count and self._task is not None:
            self._task.cancel()  # its finally gives the camera back
            self._task = None

    async def _loop(self) -> None:
        loop = asyncio.get_running_loop()
        async with contextlib.aclosing(self.robot.live_frames()) as frames:
            async for frame in frames:
                began = loop.time()
                try:
                    found = await loop.run_in_executor(self._executor, self.detector.detect_jpeg, frame.jpeg)
                    self.searched += 1
                except Exception:  # a bad frame must not end detection
                    log.exception("face detection failed on frame %d", frame.seq)
                    found = None
                if found is not None:
                    faces, (width, height) = found
                    secs = int(frame.stamp_wall)
                    self.bus.publish(names.FACES_TOPIC, {
                        "header": {"seq": frame.seq % 2**32, "frame_id": names.CAMERA_FRAME_ID,
                                   "stamp": {"secs": secs, "nsecs": int((frame.stamp_wall - secs) * 1e9)}},
                        "frame_seq": frame.seq % 2**32, "image_width": width, "image_height": height,
                        "detector": self.detector.name,
                        "faces": [{"x": f.x, "y": f.y, "width": f.width, "height": f.height,
                                   "confidence": f.confidence} for f in faces]})
                # at most rate_hz, and resting as long as the search took (half a core at most, on any machine)
                age = loop.time() - frame.stamp_monotonic  # stamps are on the loop's clock
                await asyncio.sleep(max(0.0, self._period - age, loop.time() - began))
