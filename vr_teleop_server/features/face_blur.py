"""`serve --blur-faces`: every face the detector finds is blurred in what is recorded and in what spectators see; the
operator and the supervisor (who must see the pupils) get the camera as it is.

One detector: the blur takes the boxes FacePublisher publishes on /perception/faces (the detector attention already
uses, at up to 5 Hz, at the lowest CPU priority), by subscribing to that topic itself while blurred frames are being
made and for LEASE_S after the last: when autonomy is off, the subscription is what makes detection run.

Which regions a frame gets (`plan`): the boxes of every detection of the last HOLD_S, so that a face one search
missed stays blurred from the searches before it; each grown by a margin (worker_process/face_blur.py, the pixels);
and the whole frame when no detection is that recent (detection has not run yet, or the machine is too busy for
it): a face is never shown for want of a search.

Where blurred frames are made:
- the recording (recording/recorder.py): each kept camera frame is blurred before it is written, and beside it, on
  /vr_teleop/face_blur, a FaceBlur note says what was done to it: whether a search of that very frame had ended
  (`detected`), which frame the newest detection searched and how long before, the regions blurred, or
  `whole_frame`. Every detection is recorded too, on /perception/faces;
- the camera topic for spectators: a spectator's subscription to the camera topic is served from the blurred
  camera topic (CAMERA_BLURRED_TOPIC), which this feature publishes while anyone subscribes to it, each camera frame
  blurred in a thread of its own (core/access.py decides who sees faces);
- WebRTC video for spectators: a second video hub (media/video.py) whose encoder process blurs each frame's plan.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from client_protocol import names
from simclock import WALL, Clock
from worker_process.face_blur import MARGIN, WHOLE_FRAME, Regions, blur_regions

from ..core.bus import Bus, Published
from ..core.tasks import cancel_and_wait
from ..robot.interface import Robot

log = logging.getLogger(__name__)

HOLD_S = 1.0  # a detection's boxes are blurred for this long; a frame with no detection this recent is blurred whole
LEASE_S = 3.0  # detection keeps running this long after the last blurred frame
JPEG_QUALITY = 80  # the stand-in's own
BLUR_NODE = "/vr_teleop_server/face_blur"  # the owner of the blur's subscription to the faces


@dataclass(frozen=True)
class BlurPlan:
    """What is blurred in one camera frame, and why."""

    frame_seq: int
    faces: tuple[tuple[int, int, int, int, float], ...] | None  # the held detections' boxes and scores; None: whole
    detection_seq: int  # the frame the newest detection searched (0: none yet)
    detection_age: float  # seconds since that detection came (-1: none)

    @property
    def regions(self) -> Regions:
        """What the pixels' blur_regions takes: the boxes (it adds the margin), or WHOLE_FRAME."""
        return WHOLE_FRAME if self.faces is None else tuple(face[:4] for face in self.faces)

    @property
    def detected(self) -> bool:
        """A search of this very frame had ended when the frame was blurred: its boxes are exact, not held."""
        return self.detection_seq == self.frame_seq

    def note(self, header: dict[str, Any]) -> dict[str, Any]:
        """The vr_teleop_msgs/FaceBlur message recorded beside the blurred frame (`header`: the frame's)."""
        return {"header": header, "frame_seq": self.frame_seq % 2**32, "detected": self.detected,
                "detection_seq": self.detection_seq % 2**32, "detection_age": round(self.detection_age, 3),
                "whole_frame": self.faces is None, "margin": MARGIN,
                "faces": [{"x": x, "y": y, "width": w, "height": h, "confidence": c}
                          for x, y, w, h, c in self.faces or ()]}


class FaceBlur:
    """Blur plans from the newest detections, blurred JPEG frames, and the blurred camera topic."""

    def __init__(self, bus: Bus, robot: Robot, clock: Clock = WALL, hold_s: float = HOLD_S) -> None:
        self.bus = bus
        self.robot = robot
        self.clock = clock
        self.hold_s = hold_s
        self._detections: deque[tuple[float, int, tuple[tuple[int, int, int, int, float], ...]]] = deque()
        self._faces_token: int | None = None
        self._wanted_at = -1e18
        self._lease: asyncio.TimerHandle | None = None
        self._pump_task: asyncio.Task[None] | None = None
        self._executor = ThreadPoolExecutor(1, thread_name_prefix="face-blur")
        self.blurred = 0  # frames blurred as JPEG (tests)

    def start(self) -> None:
        self.bus.declare_topic(names.FACES_TOPIC, "vr_teleop_msgs/Faces", persistent=True)
        topic = self.bus.declare_topic(names.CAMERA_BLURRED_TOPIC, "sensor_msgs/CompressedImage", persistent=True,
                                       queue_bound=1)
        topic.on_subscriber_count = self._on_watchers

    async def stop(self) -> None:
        task, self._pump_task = self._pump_task, None
        await cancel_and_wait(task)
        self._stop_detection()
        self._executor.shutdown(wait=False, cancel_futures=True)

    # ---- detections ---------------------------------------------------------------------------------------------
    def plan(self, frame_seq: int) -> BlurPlan:
        """On the loop: what to blur in the camera frame `frame_seq`, taken now; keeps detection running."""
        self._want()
        now = self.clock.monotonic()
        while self._detections and now - self._detections[0][0] > self.hold_s:
            self._detections.popleft()
        if not self._detections:
            return BlurPlan(frame_seq, None, 0, -1.0)
        at, seq, _ = self._detections[-1]
        faces = tuple(face for _, _, found in self._detections for face in found)
        return BlurPlan(frame_seq, faces, seq, now - at)

    def _on_faces(self, published: Published) -> None:
        msg = published.data
        found = tuple((f["x"], f["y"], f["width"], f["height"], f["confidence"]) for f in msg["faces"])
        self._detections.append((self.clock.monotonic(), msg["frame_seq"], found))

    def _want(self) -> None:
        loop = asyncio.get_running_loop()
        self._wanted_at = loop.time()
        if self._faces_token is None:
            self._faces_token = self.bus.subscribe(BLUR_NODE, names.FACES_TOPIC, "vr_teleop_msgs/Faces",
                                                   self._on_faces)
            self._lease = loop.call_later(LEASE_S, self._check_lease)

    def _check_lease(self) -> None:
        loop = asyncio.get_running_loop()
        left = self._wanted_at + LEASE_S - loop.time()
        if left > 0:
            self._lease = loop.call_later(left, self._check_lease)
        else:
            self._stop_detection()

    def _stop_detection(self) -> None:
        if self._lease is not None:
            self._lease.cancel()
            self._lease = None
        if self._faces_token is not None:
            self.bus.unsubscribe(names.FACES_TOPIC, self._faces_token)
            self._faces_token = None
        self._detections.clear()  # the next run's frames trust none of this run's boxes

    # ---- blurred frames -----------------------------------------------------------------------------------------
    async def blur_jpeg(self, jpeg: bytes, plan: BlurPlan) -> bytes | None:
        """The frame with the plan's regions blurred, in the blur's thread; None for a frame that is not a JPEG."""
        return await asyncio.get_running_loop().run_in_executor(self._executor, _blur_jpeg, jpeg, plan.regions)

    def _on_watchers(self, count: int) -> None:
        if count and self._pump_task is None:
            self._pump_task = asyncio.ensure_future(self._pump())
        elif not count and self._pump_task is not None:
            self._pump_task.cancel()  # its live_frames() gives the camera back
            self._pump_task = None

    async def _pump(self) -> None:
        """The blurred camera topic: each camera frame blurred, with the frame's own header."""
        async with contextlib.aclosing(self.robot.live_frames()) as frames:
            async for frame in frames:
                try:
                    jpeg = await self.blur_jpeg(frame.jpeg, self.plan(frame.seq))
                except Exception:  # a frame that fails is not sent, and the next ones are
                    log.exception("blurring camera frame %d failed", frame.seq)
                    continue
                if jpeg is None:
                    continue
                self.blurred += 1
                secs = int(frame.stamp_wall)
                self.bus.publish(names.CAMERA_BLURRED_TOPIC, {
                    "header": {"seq": frame.seq % 2**32, "frame_id": names.CAMERA_FRAME_ID,
                               "stamp": {"secs": secs, "nsecs": int((frame.stamp_wall - secs) * 1e9)}},
                    "format": "jpeg", "data": jpeg})


def _blur_jpeg(jpeg: bytes, regions: Regions) -> bytes | None:
    bgr = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    if bgr is None:
        return None
    ok, out = cv2.imencode(".jpg", blur_regions(bgr, regions), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    return out.tobytes() if ok else None
