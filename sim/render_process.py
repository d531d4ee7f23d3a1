"""The stand-in's renderer in a process of its own, at a lower CPU priority than the server.

Why a process: on a 2-core machine without a GPU, Mesa's llvmpipe renders the head camera (by default with every
core it finds; the worker asks it for one, see `serve`), and the JPEG encoding and the face drawing come on top.
In the server's process that work competes with the asyncio loop that carries the operator's poses; lowering the
render thread's priority there would let it be preempted while it holds the GIL (the loop then waits on a starved
thread). In its own process, at nice `RenderProcess.NICE` (its llvmpipe threads inherit it), the kernel gives the
server's threads the CPU first and the two share no GIL. bench/media.py's control rows measure the effect.

The worker is a request/reply server over a socket pair (the `worker_process` package: started with
subprocess, it exits when its socket closes, so it cannot outlive the server): the stand-in's render thread sends
the joint state and asks for a camera frame, a snapshot (RGB) or a face (drawn and uploaded as the screen's
texture); the worker answers each in order. A camera frame is drawn straight into a slot of the stand-in's frame
ring (worker_process/frame_ring.py: shared memory, read there by the video encoder process), and compressed to
JPEG here only when asked (someone watches the JPEG topic or records it): once per frame, never on the server's
event loop. It holds no state the server needs: if it dies, the camera closes and
the robot goes on (see StandIn).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from worker_process import WorkerDied, WorkerProcess, accept, answer
from worker_process.frame_ring import FrameRing

ROOT = Path(__file__).resolve().parent.parent  # the directory that holds the `sim` package
BOOT = "import sys; sys.path.insert(0, sys.argv[1]); from sim.render_process import serve; serve(int(sys.argv[2]))"


class RenderProcessError(WorkerDied):
    """The render process died, hung or could not start."""


class RenderProcess(WorkerProcess):
    """Parent side. Not thread-safe: one thread (the stand-in's render thread) makes every call."""

    NAME = "the stand-in's render process"
    NICE = 10  # added to the worker's niceness: the server's loop and physics threads win the CPU
    START_TIMEOUT_S = 60.0  # importing MuJoCo and creating a GL context, on a loaded machine
    REPLY_TIMEOUT_S = 30.0  # a frame takes milliseconds: a worker silent this long is hung
    Died = RenderProcessError

    def __init__(self, model: Any, width: int, height: int, *, nice: int = NICE, ring: FrameRing | None = None) -> None:
        """`ring`: where camera frames go (of width x height; it must stay open while this process starts)."""
        spec = None if ring is None else ring.spec()
        super().__init__(BOOT, [str(ROOT)], nice, (model, int(width), int(height), spec),
                         pass_fds=() if ring is None else (ring.fd,))

    def frame(self, state: tuple, quality: int | None, seq: int = 0) -> tuple[bytes, int, int, float, float]:
        """The head camera at the given joint state, drawn into the ring's slot for frame `seq` (when there is a
        ring and seq > 0), and as a JPEG when `quality` is given (b"" otherwise): (jpeg, width, height,
        render_ms, encode_ms)."""
        return self.call(("frame", state, quality, seq))

    def snapshot(self, state: tuple, camera: str, width: int, height: int) -> np.ndarray:
        return self.call(("snapshot", state, camera, width, height))

    def face(self, emotion: str, talking_phase: float | None, voice_level: float | None) -> np.ndarray:
        """Draw the face, make it the screen's texture; returns the image drawn (RGB)."""
        return self.call(("face", emotion, talking_phase, voice_level))


# ---- the worker ----------------------------------------------------------------------------------------------
def serve(fd: int) -> None:
    """Worker entry point: answer requests until the socket closes."""
    conn, (model, width, height, ring) = accept(fd)  # the niceness first: llvmpipe's threads inherit it
    # Mesa's llvmpipe renders with a thread per core by default, and its threads wait for each other: on 2 cores
    # that takes both at every frame, and the loop's poses wait whatever their priority. In this one thread the
    # render leaves a core free (bench/media.py's control rows, 6 rounds pooled: pose round trip p99 with 5
    # viewers 1.22x of none, against 1.77x with a thread per core).
    # A GPU driver ignores it; a value set by the user is kept.
    os.environ.setdefault("LP_NUM_THREADS", "0")
    try:
        worker = _Worker(model, width, height, ring)
    except Exception as exc:
        conn.send((False, f"the renderer did not start ({exc!r}); MuJoCo needs MUJOCO_GL=egl (or osmesa) and a "
                          "working libEGL on a headless machine"))
        return
    try:
        answer(conn, lambda request: worker.handle(*request))
    finally:
        worker.close()


class _Worker:
    def __init__(self, model: Any, width: int, height: int, ring: tuple | None) -> None:
        import mujoco

        from robot_models.mjcf import FACE_TEXTURE

        self.mujoco = mujoco
        self.model = m = model
        self.data = mujoco.MjData(m)
        self.width, self.height = width, height
        self.tex_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TEXTURE, FACE_TEXTURE)
        self.tex_w, self.tex_h = int(m.tex_width[self.tex_id]), int(m.tex_height[self.tex_id])
        start = int(m.tex_adr[self.tex_id])
        self.tex_slice = slice(start, start + self.tex_w * self.tex_h * int(m.tex_nchannel[self.tex_id]))
        self.renderers: dict[tuple[int, int], Any] = {}
        self.renderer(width, height)
        self.ring = None if ring is None else FrameRing.attach(ring)

    def renderer(self, w: int, h: int) -> Any:
        r = self.renderers.get((w, h))
        if r is None:
            r = self.renderers[(w, h)] = self.mujoco.Renderer(self.model, h, w)
            self.mujoco.mjr_uploadTexture(self.model, r._mjr_context, self.tex_id)
        return r

    def handle(self, kind: str, *args: Any) -> Any:
        return getattr(self, f"do_{kind}")(*args)

    def set_state(self, state: tuple) -> None:
        qpos, qvel, t = state
        self.data.qpos[:] = qpos
        self.data.qvel[:] = qvel
        self.data.time = t
        self.mujoco.mj_forward(self.model, self.data)

    def do_frame(self, state: tuple, quality: int | None, seq: int) -> tuple[bytes, int, int, float, float]:
        import cv2

        from robot_models.mjcf import HEAD_CAMERA

        self.set_state(state)
        r = self.renderer(self.width, self.height)
        c0 = time.perf_counter()
        r.update_scene(self.data, camera=HEAD_CAMERA)
        if self.ring is not None and seq > 0:
            rgb = r.render(out=self.ring.begin(seq))  # straight into shared memory: no copy
            self.ring.commit(seq)
        else:
            rgb = r.render()
        c1 = time.perf_counter()
        jpeg = b""
        if quality is not None:
            ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
            if not ok:
                raise RuntimeError("JPEG encoding of a camera frame failed")
            jpeg = buf.tobytes()
        c2 = time.perf_counter()
        return jpeg, rgb.shape[1], rgb.shape[0], (c1 - c0) * 1e3, (c2 - c1) * 1e3

    def do_snapshot(self, state: tuple, camera: str, width: int, height: int) -> np.ndarray:
        self.set_state(state)
        r = self.renderer(width, height)
        r.update_scene(self.data, camera=camera)
        return r.render().copy()

    def do_face(self, emotion: str, talking_phase: float | None, voice_level: float | None) -> np.ndarray:
        from .face import draw_face

        face = draw_face(emotion, self.tex_w, self.tex_h, talking_phase=talking_phase, voice_level=voice_level)
        self.model.tex_data[self.tex_slice] = face.reshape(-1)
        for r in self.renderers.values():
            self.mujoco.mjr_uploadTexture(self.model, r._mjr_context, self.tex_id)
        return face

    def close(self) -> None:
        for r in self.renderers.values():
            r.close()
        if self.ring is not None:
            self.ring.close()
