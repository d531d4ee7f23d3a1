"""The stand-in's render thread: it decides what to draw and when (the face texture, the head camera only while
someone watches, snapshots), and the render process (render_process.py) draws it.

Camera frames go into the frame ring's shared memory, and as JPEG only while a JPEG consumer watches. The thread
sends the render process the scene's state, copied from the physics under its lock held only for the copy, and
waits for the picture. If that process dies the camera closes (frame waiters and camera-closed listeners are told,
snapshots fail with the reason) while the physics goes on. On a simulated clock the clock asks for each frame
(request_frame, at camera_fps in simulated time) and waits until it is drawn.
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future

import mujoco
import numpy as np

from robot_models.types import CameraFrame, CapturePose
from simclock import Clock
from worker_process.frame_ring import FrameRing

from .expression import Expression
from .physics import Physics
from .render_process import RenderProcess, RenderProcessError

log = logging.getLogger(__name__)

SceneState = tuple[np.ndarray, np.ndarray, float]  # qpos, qvel, simulated time
Stamps = tuple[float, float, float]  # the clock's monotonic and wall time, simulated time


class Camera:
    # The render process holds nothing to save: closing, it gets this long to exit, then is killed. At nice +10 on a
    # busy machine its orderly exit took 4.5 s or more (0.5 s idle), which outlasted the 5 s close() used to wait.
    RENDER_EXIT_S = 1.0

    def __init__(self, physics: Physics, model: mujoco.MjModel, clock: Clock, stop: threading.Event, *,
                 width: int, height: int, fps: float, jpeg_quality: int, render_nice: int,
                 initial_emotion: str) -> None:
        self.physics = physics
        self.model = model
        self.clock = clock
        self.stop = stop
        self.width, self.height, self.fps, self.jpeg_quality = width, height, fps, jpeg_quality
        self.render_nice = render_nice
        # Render-side state, guarded by cond's lock.
        self.cond = threading.Condition()
        self.face = Expression(self.cond, clock.monotonic, initial_emotion)
        self.subscribers = 0
        self.jpeg_subscribers = 0  # of the subscribers, those that want JPEG (the others read the ring)
        # Viewer changes counted, and the last count the render thread decided on: once it has seen the last change
        # with nobody watching, no camera frame is in flight (wait_stopped).
        self._viewer_changes = 0
        self._viewer_changes_seen = 0
        self._snapshots: collections.deque[tuple[str, int, int, Future]] = collections.deque()
        self._frame_requests: collections.deque[tuple[SceneState, Stamps, Future]] = \
            collections.deque()  # simulated clock: frames the clock asks for, drawn by the render thread
        self.next_frame_at = 0.0  # simulated clock: when the next frame is due
        self.frame: CameraFrame | None = None
        self.frame_cond = threading.Condition()
        self._frame_listeners: list[Callable[[CameraFrame], None]] = []
        self._closed_listeners: list[Callable[[], None]] = []
        self._seq = 0
        self.error: BaseException | None = None
        self.renderer: RenderProcess | None = None
        # Raw frames in shared memory for the video encoder; released when the renderer stops (closed or dead).
        self.ring = FrameRing.create(width, height)
        self.ready = threading.Event()
        self.thread = threading.Thread(target=self._loop, name="standin-render", daemon=True)

    def start(self) -> bool:
        """Starts the render thread and its process; False if the renderer did not start."""
        self.thread.start()
        return self.ready.wait(RenderProcess.START_TIMEOUT_S + 5) and self.error is None

    def wake(self) -> None:
        with self.cond:
            self.cond.notify_all()
        with self.frame_cond:
            self.frame_cond.notify_all()

    # ---- viewers and listeners -----------------------------------------------------------------------------------
    def add_viewer(self, jpeg: bool) -> None:
        with self.cond:
            self.subscribers += 1
            self.jpeg_subscribers += bool(jpeg)
            self._viewer_changes += 1
            self.cond.notify_all()

    def remove_viewer(self, jpeg: bool) -> None:
        with self.cond:
            self.subscribers = max(0, self.subscribers - 1)
            if jpeg:
                self.jpeg_subscribers = max(0, self.jpeg_subscribers - 1)
            self._viewer_changes += 1
            self.cond.notify_all()

    def wait_stopped(self, timeout: float) -> bool:
        """Blocks until nobody watches and the render thread has acknowledged it: the frame it was drawing, if
        any, has been handed out, and no other comes until a viewer is added. False on timeout."""
        with self.cond:
            return self.cond.wait_for(lambda: self.subscribers == 0 and (
                self._viewer_changes_seen == self._viewer_changes or self.error is not None
                or self.stop.is_set()), timeout)

    def add_frame_listener(self, callback: Callable[[CameraFrame], None]) -> None:
        with self.frame_cond:
            self._frame_listeners = [*self._frame_listeners, callback]

    def remove_frame_listener(self, callback: Callable[[CameraFrame], None]) -> None:
        with self.frame_cond:
            self._frame_listeners = [c for c in self._frame_listeners if c is not callback]

    def add_closed_listener(self, callback: Callable[[], None]) -> None:
        with self.frame_cond:
            self._closed_listeners = [*self._closed_listeners, callback]

    def wait_frame(self, after_seq: int, timeout: float) -> CameraFrame | None:
        deadline = time.monotonic() + timeout
        with self.frame_cond:
            while self.frame is None or self.frame.seq <= after_seq:
                left = deadline - time.monotonic()
                if left <= 0 or self.stop.is_set() or self.error is not None:
                    return None
                self.frame_cond.wait(left)
            return self.frame

    def snapshot(self, camera: str, width: int, height: int, timeout: float) -> np.ndarray:
        fut: Future = Future()
        with self.cond:
            if self.stop.is_set():
                raise RuntimeError("the stand-in is closed")
            if self.error is not None:
                raise RuntimeError(f"the stand-in's renderer died: {self.error}")
            self._snapshots.append((camera, width, height, fut))
            self.cond.notify_all()
        return fut.result(timeout)

    # ---- on a simulated clock (simclock) -------------------------------------------------------------------------
    def next_due(self) -> float:
        return self.next_frame_at if self.subscribers > 0 and self.error is None else math.inf

    def request_frame(self, t: float) -> None:
        """The clock's loop thread, at simulated time t: draw the frame due by now, if one is, and wait for it."""
        if self.subscribers <= 0 or self.error is not None:
            self.next_frame_at = max(self.next_frame_at, t)
            return
        if t < self.next_frame_at:
            return
        self.next_frame_at = t + 1.0 / self.fps
        state = self.physics.scene_state()
        fut: Future = Future()
        with self.cond:
            self._frame_requests.append((state, (self.clock.monotonic(), self.clock.time(), state[2]), fut))
            self.cond.notify_all()
        try:
            fut.result(RenderProcess.START_TIMEOUT_S + 30)
        except Exception as exc:  # the renderer died: the camera closes, the physics goes on
            log.error("a simulated-time camera frame failed: %s", exc)

    # ---- the render thread ---------------------------------------------------------------------------------------
    def _state(self) -> tuple[SceneState, Stamps]:
        with self.physics.lock:
            state = self.physics.data.qpos.copy(), self.physics.data.qvel.copy(), float(self.physics.data.time)
            stamps = (self.clock.monotonic(), self.clock.time(), state[2])
        return state, stamps

    def _loop(self) -> None:
        period = 1.0 / self.fps
        next_frame = 0.0
        next_face_tick = 0.0
        drawn_talking = False
        renderer: RenderProcess | None = None
        face = self.face
        simulated = self.clock.simulated
        try:
            renderer = self.renderer = RenderProcess(self.model, self.width, self.height, nice=self.render_nice,
                                                     ring=self.ring, reuse_unchanged=simulated)
            self.ready.set()
            while not self.stop.is_set():
                with self.cond:
                    now = self.clock.monotonic()
                    voice = face.voice_at(now)
                    talking = now < face.talking_until or face.emotion == "talking" or voice is not None
                    face_due = (face.applied < face.version or (talking and now >= next_face_tick)
                                or (drawn_talking and not talking))  # speech ended: back to the still face
                    camera_due = self.subscribers > 0 and now >= next_frame and not simulated
                    requests = list(self._frame_requests)
                    self._frame_requests.clear()
                    if not requests and self._viewer_changes_seen != self._viewer_changes:
                        # the acknowledgement wait_stopped waits for: the last frame decided on is handed out
                        self._viewer_changes_seen = self._viewer_changes
                        self.cond.notify_all()
                    if not (face_due or camera_due or self._snapshots or requests):
                        waits = [next_face_tick - now if talking else 1.0]
                        if self.subscribers > 0:
                            waits.append(next_frame - now)
                        if now < face.talking_until:
                            waits.append(face.talking_until - now)
                        self.cond.wait(max(0.0005, min(waits if not simulated else [0.05])))
                        continue
                    emotion, version = face.emotion, face.version
                    snapshots = list(self._snapshots)
                    self._snapshots.clear()
                if face_due:
                    image = renderer.face(emotion, now if talking else None, voice)
                    drawn_talking = talking
                    next_face_tick = now + 1.0 / face.ANIMATION_HZ
                    face.drawn(image, version, voice)
                for camera, w, h, fut in snapshots:
                    try:
                        fut.set_result(renderer.snapshot(self._state()[0], camera, w, h))
                    except RenderProcessError as exc:
                        fut.set_exception(RuntimeError(f"the stand-in's renderer died: {exc}"))
                        raise
                    except Exception as exc:  # the caller gets the error, the renderer lives on
                        fut.set_exception(exc)
                for i, (state, stamps, fut) in enumerate(requests):
                    try:
                        self._draw(renderer, state, stamps)
                    except BaseException as exc:
                        for *_, waiting in requests[i:]:
                            waiting.set_exception(RuntimeError(f"the stand-in's renderer died: {exc}"))
                        raise
                    fut.set_result(None)
                if camera_due:
                    next_frame = max(next_frame + period, now) if next_frame else now + period
                    self._draw(renderer, *self._state())
        except RenderProcessError as exc:
            self.error = exc
            if self.ready.is_set() and not self.stop.is_set():  # the camera closes, the robot goes on
                log.error("%s; the head camera is closed (the robot keeps holding and moving as commanded)", exc)
        except BaseException as exc:
            self.error = exc
            log.exception("stand-in render thread died")
        finally:
            self._closed(renderer)

    def _closed(self, renderer: RenderProcess | None) -> None:
        self.ready.set()
        with self.cond:
            for *_, fut in [*self._snapshots, *self._frame_requests]:
                fut.set_exception(RuntimeError("the stand-in is closed" if self.stop.is_set() else
                                               f"the stand-in's renderer died: {self.error}"))
            self._snapshots.clear()
            self._frame_requests.clear()
            self.cond.notify_all()
        with self.frame_cond:
            self.frame_cond.notify_all()
            closed_listeners = self._closed_listeners
        if renderer is not None:
            renderer.close(self.RENDER_EXIT_S)
        self.ring.close()
        for callback in closed_listeners:
            try:
                callback()
            except Exception:
                log.exception("a camera-closed listener failed")

    def _draw(self, renderer: RenderProcess, state: SceneState, stamps: Stamps) -> None:
        t_mono, t_wall, sim_time = stamps
        seq = self._seq + 1
        quality = self.jpeg_quality if self.jpeg_subscribers > 0 else None
        try:
            jpeg, width, height, render_ms, encode_ms = renderer.frame(state, quality, seq)
        except RenderProcessError:
            raise
        except RuntimeError as exc:
            log.error("a camera frame failed: %s", exc)
            return
        self._seq = seq
        pose = CapturePose(*self.physics.head_pose(state[0]))  # exactly the pose drawn
        frame = CameraFrame(jpeg, width, height, seq, t_mono, t_wall, sim_time, render_ms, encode_ms, ring=self.ring,
                            pose=pose)
        with self.frame_cond:
            self.frame = frame
            self.frame_cond.notify_all()
            listeners = self._frame_listeners
        for callback in listeners:
            try:
                callback(frame)
            except Exception:
                log.exception("a camera frame listener failed")
